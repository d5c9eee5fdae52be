"""A fast subset of ``bench/bench_faults.py`` (issue 24): representative hostile inputs, one per family of
faults, through ``gazepipe run`` (JSON log, serial executor) or ``gazepipe inspect``, classified by the bench's
own rules.

Every case must end with exit 0, 1 or 2 (or 75), no traceback, no "internal error", within its timeout and
under 1 GB of peak memory; every error must be one clean line (no control bytes) naming the mutated file; a
frame- or time-column mutation (reordered, repeated, absurd or dropped frame numbers) or an absurd coordinate
must not be accepted silently (exit 0 needs a new warning naming the file); a memory bomb must be refused.
The cases are the bench's (same generators, same seed); they run two at a time.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from bench.bench_faults import (
    QUOTA,
    Runner,
    bomb_cases,
    mutation_cases,
    prepare,
    run_cases,
    with_mode,
)

SEED = 24

#: (reader, mutation, mode): the bench's case of that reader and mutation, through that command
PICKED = [
    # C3D: absurd rates and counts, escaped bytes, truncation, not-a-file inputs, absurd coordinates
    ("c3d", "POINT:RATE=1e+30", "inspect"),
    ("c3d", "POINT:RATE=1e+30", "run"),
    ("c3d", "POINT:RATE+header.rate=1e-30", "run"),
    ("c3d", "POINT:RATE+header.rate=nan", "inspect"),
    ("c3d", "param_name(RATE).NUL", "inspect"),
    ("c3d", "POINT:LABELS.escape_sequence", "inspect"),
    ("c3d", "frames_beyond_file(50x)", "inspect"),
    ("c3d", "truncate@1024", "inspect"),
    ("c3d", "coords.inf", "inspect"),
    ("c3d", "special.dir", "run"),
    ("c3d", "special.fifo", "run"),
    ("c3d", "special.dangling", "run"),
    ("c3d", "coords.1e30", "run"),
    # marker text exports: the frame column (no silent corruption), absurd values, a 10^7-character line
    ("vicon_csv", "rows.reversed", "inspect"),
    ("vicon_csv", "rows.reversed", "run"),
    ("vicon_csv", "frame.jump=1000000000000", "inspect"),
    ("vicon_csv", "frame.all=1e18", "inspect"),
    ("vicon_csv", "rows.duplicate", "inspect"),
    ("vicon_csv", "values.inf(xyz)", "inspect"),
    ("vicon_csv", "values.inf(xyz)", "run"),
    ("vicon_csv", "line.huge_row(1e7)", "inspect"),
    ("qtm_tsv", "rows.reversed", "inspect"),
    ("qtm_tsv", "frame.repeat_previous", "inspect"),
    ("qtm_tsv", "rows.dropped_block", "inspect"),
    ("qtm_tsv", "time.reversed_only", "inspect"),
    ("qtm_tsv", "time.jump=inf", "inspect"),
    ("wide_csv", "header.cut", "inspect"),
    # eye and face tracks: cut headers, no Timecode column, reversed or missing frames
    ("openface", "header.cut", "inspect"),
    ("openface", "rows.reversed", "inspect"),
    ("openface", "rows.dropped_block", "run"),
    ("openface", "values.-1e300(one)", "run"),
    ("livelinkface", "header.cut", "inspect"),
    ("livelinkface", "column.drop_first", "run"),
    ("livelinkface", "timecode.reversed_only", "inspect"),
    # session.toml and markerset.toml
    ("session_toml", "nested_arrays(5000).top", "run"),
    ("session_toml", "take_id.300_chars", "run"),
    ("session_toml", "path.escape_relative", "run"),
    ("session_toml", "huge_string.2MB", "run"),
    ("markerset_toml", "nested_arrays(5000).markers", "run"),
    # the head-camera video
    ("video", "missing", "run"),
    ("video", "truncate@50%", "run"),
    ("video", "flip_bytes#3", "run"),
]
#: memory bombs (cheap ones): refused within 10 s under 1 GB
BOMBS = ["header_claims_2140000_frames(small_file)"]


def _key(reader: str, mutation: str, mode: str) -> str:
    return f"{reader}:{mutation}:{mode}"


def _picked(bases: dict[str, Path]) -> list:
    cases = mutation_cases(SEED, bases)
    chosen = []
    for reader, mutation, mode in PICKED:
        found = [c for c in cases if c.reader == reader and c.mutation == mutation]
        assert found, f"the bench has no case {reader} {mutation}"
        same = [c for c in found if c.mode == mode]
        chosen.append(same[0] if same else with_mode(found[0], mode, bases))
    bombs = [b for b in bomb_cases(SEED, bases) if b.mutation in BOMBS and b.mode == "inspect"]
    return chosen + bombs


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory) -> dict:
    runner = Runner(tmp_path_factory.mktemp("faults"))
    cases = _picked(runner.bases)
    results = run_cases(runner, cases, jobs=2, progress=False)
    keys = [_key(*p) for p in PICKED] + [f"bomb:{b}" for b in BOMBS]
    return dict(zip(keys, results, strict=True))


@pytest.mark.parametrize("key", [_key(*p) for p in PICKED] + [f"bomb:{b}" for b in BOMBS])
def test_hostile_input_gives_one_clean_line_naming_the_file(outcomes, key: str) -> None:
    o = outcomes[key]
    detail = "; ".join(f"{kind}: {what}" for kind, what in o.problems)
    assert o.ok, f"{o.case_id} {o.mutation} ({o.mode} {Path(o.file).name}, exit {o.exit}): {detail} " \
                 f"-- first line: {o.first_line}"


def test_the_bench_has_500_cases_across_every_reader() -> None:
    cases = mutation_cases(SEED)
    assert len(cases) >= 500
    assert {c.reader for c in cases} == set(QUOTA)
    frame_cases = [c for c in cases if c.flag and c.mutation.split(".")[0] in ("rows", "frame", "time", "timecode")]
    assert {c.reader for c in frame_cases} == {"vicon_csv", "qtm_tsv", "wide_csv", "openface", "livelinkface"}


def test_the_same_seed_gives_the_same_inputs(tmp_path: Path) -> None:
    bases = Runner(tmp_path / "w").bases

    def digests(folder: Path) -> list[str]:
        out = []
        for case in mutation_cases(SEED, bases)[::7]:
            _, target = prepare(case, bases, folder / case.id)
            data = target.read_bytes() if target.is_file() and not target.is_fifo() else b"<" + \
                str(target.exists()).encode()
            out.append(f"{case.id} {case.mutation} {case.mode} {hashlib.sha256(data).hexdigest()}")
            shutil.rmtree(folder / case.id)
        return out

    assert digests(tmp_path / "a") == digests(tmp_path / "b")
