"""Fuzzing the readers the capture-reader and session-contract fuzz tests do not cover: OpenFace CSV, Live Link
Face CSV, video files, the per-take Parquet tables the engine's loader reads back, and datasets (dataset.json,
_common_metadata, take files) read with ``read_dataset``.

Every case must either read cleanly or raise a :class:`GazepipeError` whose message is one line naming the file
(for a dataset: its folder). Cases run in child processes, one batch per reader, each case bounded by an alarm
and each batch by a timeout, so that a native crash (OpenCV, Arrow) or a hang fails the test instead of killing or
blocking the run.

Count: 120 OpenFace + 120 Live Link Face + 80 video + 120 Parquet + 80 dataset = 520 cases in the main tests, plus
30 non-UTF-8 texts and 40 tables inconsistent with their metadata = 590 here; with the C3D (200), CSV/TSV (150) and TOML (600) cases of
``test_fuzz_capture_readers.py`` and ``test_session_contract.py``, 1540 fuzzed inputs across every reader.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gazepipe.cli.common import load_sessions
from gazepipe.dag import run_pipeline
from gazepipe.io.parquet import write_options
from gazepipe.pipeline.events import EventLog
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.session import DEFAULT_SHIFTS
from tests.helpers import REPO

CORPUS = REPO / "tests" / "data" / "corpus"
CASES = {"openface": 120, "livelinkface": 120, "video": 80, "parquet": 120, "dataset": 80}
CASE_TIMEOUT_S = 15      # per case (an alarm in the child)
BATCH_TIMEOUT_S = 240    # per child process

_CHILD = r"""
import json, signal, sys
from pathlib import Path
import numpy as np
from gazepipe.errors import GazepipeError


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def run(case):
    kind, p = case["kind"], case["path"]
    if kind == "openface":
        from gazepipe.io.openface import read_openface
        e = read_openface(p)
        n = e.time_s.shape[0]
        assert e.gaze_left.shape == e.gaze_right.shape == (n, 3) and e.success.shape == (n,)
    elif kind == "livelinkface":
        from gazepipe.io.livelinkface import read_livelinkface
        f = read_livelinkface(p, rate_hz=case.get("rate_hz"), timecode_fps=60)
        assert np.all(np.diff(f.time_s) > 0)
    elif kind == "video":
        from gazepipe.io.video import probe_video, read_frames
        v = probe_video(p)
        assert v.timestamps_s.shape == (v.n_frames,)
        if v.n_frames:
            ts, frames = read_frames(p, 0, min(3, v.n_frames))
            assert frames.shape[0] == ts.shape[0] >= 1
            if v.n_frames > 12:
                read_frames(p, 10, 12, timestamps_s=v.timestamps_s)
    elif kind == "parquet":
        import gazepipe.dag
        from gazepipe.pipeline.runner import _loader
        from gazepipe.pipeline.state import OutLayout
        from gazepipe.schemas.joints import joints_arrays
        from gazepipe.schemas.markers import table_to_markers

        gazepipe.dag.declare()   # the stages and their parameters

        t = _loader(OutLayout(Path(case["out"])))(case["session"], case["take"], case["table"])
        if case["table"] in ("markers_raw", "markers", "neutral"):
            table_to_markers(t)
        elif case["table"] == "joints":
            joints_arrays(t)
    elif kind == "dataset":
        from gazepipe.io.dataset_files import read_dataset
        read_dataset(p)
    else:
        raise RuntimeError(kind)


signal.signal(signal.SIGALRM, _alarm)
for case in json.loads(Path(sys.argv[1]).read_text()):
    name = case.get("names", case["path"])
    signal.alarm(int(sys.argv[2]))
    try:
        run(case)
        out = "ok"
    except GazepipeError as e:
        s = str(e)
        out = "error" if (name in s and "\n" not in s and "\r" not in s) else "bad-message: " + s[:300]
    except Hang:
        out = "hang"
    except BaseException as e:
        out = "escaped %s: %s" % (type(e).__name__, " ".join(str(e).split())[:300])
    finally:
        signal.alarm(0)
    print(json.dumps([case["path"], out]), flush=True)
"""


# ------------------------------------------------------------------------------------------------ mutations

JUNK = [b"", b"nan", b"NaN", b"inf", b"-inf", b"abc", b"1e308", b"-1e308", b"-1", b"0", b"1", b"2", b"\"", b",",
        b"\x00", b"\xc3\xa9", b"99:99:99:99.9", b"00:00:00:00.000", b"1,2", b" ", b"\t", b"1e-320", b"0x10"]


def _bytes(rng: np.random.Generator, n: int, text: bool) -> bytes:
    return bytes(rng.integers(0, 128 if text else 256, size=n, dtype=np.uint8))


def _mutate_bytes(data: bytes, rng: np.random.Generator, region: tuple[int, int] | None = None,
                  text: bool = False) -> bytes:
    """A byte-level mutation of ``data``: truncation, flips, insertion, deletion, or random bytes (``text``: only
    ASCII bytes, so that a text file stays valid UTF-8)."""
    out = _mutate_raw(data, rng, region, text)
    # a cut through a multi-byte character is not UTF-8 either: drop its remains (those cases are in
    # test_fuzz_non_utf8_text)
    return out.decode("utf-8", "ignore").encode() if text else out


def _mutate_raw(data: bytes, rng: np.random.Generator, region: tuple[int, int] | None, text: bool) -> bytes:
    b = bytearray(data)
    lo, hi = region or (0, len(b))
    op = rng.choice(["truncate", "flip", "insert", "delete", "random", "empty"], p=[.25, .3, .15, .15, .1, .05])
    if op == "truncate":
        return bytes(b[: int(rng.integers(0, len(b)))])
    if op == "random":
        return _bytes(rng, int(rng.integers(1, 4000)), text)
    if op == "empty":
        return b""
    for _ in range(int(rng.integers(1, 9))):
        i = int(rng.integers(lo, max(lo + 1, min(hi, len(b)))))
        if op == "flip" and b:
            b[min(i, len(b) - 1)] = int(rng.integers(0, 128 if text else 256))
        elif op == "insert":
            b[i:i] = _bytes(rng, int(rng.integers(1, 6)), text)
        elif op == "delete":
            del b[i: i + int(rng.integers(1, 40))]
    return bytes(b)


def _mutate_csv(text: bytes, rng: np.random.Generator) -> bytes:
    """A CSV-level mutation: junk in cells, dropped/duplicated/swapped rows, dropped or renamed columns, or a
    byte-level mutation."""
    lines = text.split(b"\n")
    op = rng.choice(["cells", "rows", "columns", "bytes", "header"], p=[.35, .15, .15, .25, .1])
    if op == "bytes":
        return _mutate_bytes(text, rng, text=True)
    sep = b"\t" if b"\t" in lines[0] else b","
    rows = [ln.split(sep) for ln in lines]
    data_rows = [i for i in range(1, len(rows)) if len(rows[i]) > 1]
    if op == "cells" and data_rows:
        for _ in range(int(rng.integers(1, 6))):
            r = rows[int(rng.choice(data_rows))]
            r[int(rng.integers(0, len(r)))] = JUNK[int(rng.integers(0, len(JUNK)))]
    elif op == "rows" and data_rows:
        i, j = (int(x) for x in rng.choice(data_rows, size=2))
        sub = rng.choice(["drop", "dup", "swap", "short"])
        if sub == "drop":
            rows.pop(i)
        elif sub == "dup":
            rows.insert(i, list(rows[i]))
        elif sub == "swap":
            rows[i], rows[j] = rows[j], rows[i]
        else:
            rows[i] = rows[i][: int(rng.integers(0, len(rows[i])))]
    elif op in ("columns", "header"):
        k = int(rng.integers(0, len(rows[0])))
        if op == "columns":
            rows = [r[:k] + r[k + 1:] if len(r) > k else r for r in rows]
        else:
            rows[0][k] = JUNK[int(rng.integers(0, len(JUNK)))] + b"x"
    return b"\n".join(sep.join(r) for r in rows)


def _head(path: Path, n_rows: int) -> bytes:
    return b"\n".join(path.read_bytes().split(b"\n")[: n_rows + 1]) + b"\n"


# ------------------------------------------------------------------------------------------------ fixtures

@pytest.fixture(scope="module")
def pipeline_out(tmp_path_factory) -> tuple[Path, Path]:
    """A small session run to the end in this process: (session folder, output folder)."""
    root = tmp_path_factory.mktemp("fuzz_src")
    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=8.0, shift_targets=DEFAULT_SHIFTS[:1],
                      face_takes=((60.0, 3.0),), neutral_s=4.0, session_id="fz")
    session = generate_session(root / "s", seed=5, config=cfg)
    toml = session / "session.toml"    # every take in the training split, so every dataset has statistics
    toml.write_text(toml.read_text().replace("[[takes]]\n", '[[takes]]\nsplit = "train"\n'))

    out = root / "out"
    summary = run_pipeline(load_sessions((str(session),)), out, executor="serial", log=EventLog("json", quiet=True))
    assert summary.exit_code == 0, [o.error for o in summary.failed]
    return session, out


def _run_batch(cases: list[dict], folder: Path) -> list[tuple[str, str]]:
    spec = folder / "cases.json"
    spec.write_text(json.dumps(cases))
    env = dict(os.environ, PYTHONPATH=str(REPO))
    try:
        r = subprocess.run([sys.executable, "-c", _CHILD, str(spec), str(CASE_TIMEOUT_S)], capture_output=True,
                           env=env, timeout=BATCH_TIMEOUT_S)
    except subprocess.TimeoutExpired as e:
        done = len((e.stdout or b"").decode().splitlines())
        raise AssertionError(f"reader hung on {cases[min(done, len(cases) - 1)]['path']}") from None
    results = [tuple(json.loads(line)) for line in r.stdout.decode().splitlines() if line.startswith("[")]
    if r.returncode != 0:
        crashed = cases[len(results)]["path"] if len(results) < len(cases) else "?"
        raise AssertionError(f"reader process died (code {r.returncode}) on {crashed}: {r.stderr.decode()[-800:]}")
    assert len(results) == len(cases)
    return results


def _assert_clean(results: list[tuple[str, str]], min_ok: int = 1, min_error: int = 1) -> None:
    bad = [(p, out) for p, out in results if out not in ("ok", "error")]
    kinds = sorted({out.split(":")[0] + ":" + out.split(":")[1][:60] for _, out in bad})
    assert not bad, f"{len(bad)} of {len(results)} cases escaped or gave an unclear message: {kinds}; {bad[:4]}"
    # the fuzzing reached both outcomes: unmutated-enough inputs still read, broken ones were refused
    n_ok = sum(out == "ok" for _, out in results)
    assert n_ok >= min_ok and len(results) - n_ok >= min_error, (n_ok, len(results))


def _text_cases(kind: str, bases: list[bytes], n: int, folder: Path, seed: int, **extra) -> list[dict]:
    rng = np.random.default_rng(seed)
    cases = []
    for i in range(n):
        data = _mutate_csv(bases[i % len(bases)], rng) if i >= len(bases) else bases[i]
        p = folder / f"{kind}_{i:03d}.csv"
        p.write_bytes(data)
        cases.append({"kind": kind, "path": str(p), **extra})
    return cases


# ------------------------------------------------------------------------------------------------ tests

def test_fuzz_openface(tmp_path):
    src = CORPUS / "openface" / "pyfeat_OpenFace_Test.csv"
    real = _head(src, 30)
    tight = real.replace(b", ", b",")        # the same file with plain "," separators
    legacy = b"\n".join(b",".join(c for c in line.split(b",") if not c.strip().startswith((b"pose_", b"x_", b"y_")))
                        for line in tight.split(b"\n"))
    cases = _text_cases("openface", [real, tight, legacy], CASES["openface"], tmp_path, seed=1)
    _assert_clean(_run_batch(cases, tmp_path))


def test_fuzz_livelinkface(tmp_path, pipeline_out):
    session, _ = pipeline_out
    real = _head(CORPUS / "livelinkface" / "alex_rom_3_first300.csv", 30)
    synth = _head(sorted((session / "face").glob("*_tracked.csv"))[0], 30)
    cases = _text_cases("livelinkface", [real, synth], CASES["livelinkface"], tmp_path, seed=2, rate_hz=60.0)
    for c in cases[1::3]:
        c["rate_hz"] = None    # the rate estimated from the timecode
    _assert_clean(_run_batch(cases, tmp_path))


def _small_video(path: Path, n: int = 40) -> bytes:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (64, 48))
    assert w.isOpened()
    rng = np.random.default_rng(0)
    for k in range(n):
        img = np.full((48, 64, 3), 40 + 4 * k, np.uint8)
        img[10:20, (k % 50):(k % 50) + 10] = rng.integers(0, 255, size=3, dtype=np.uint8)
        w.write(img)
    w.release()
    return path.read_bytes()


def test_fuzz_video(tmp_path):
    base = _small_video(tmp_path / "base.mp4")
    rng = np.random.default_rng(3)
    cases = []
    for i in range(CASES["video"]):
        if i == 0:
            data = base
        else:
            # half the mutations in the first and last kilobytes, where mp4 keeps its boxes (ftyp, moov)
            region = [None, (0, 1024), (max(0, len(base) - 1024), len(base))][i % 3]
            data = _mutate_bytes(base, rng, region)
        p = tmp_path / f"video_{i:03d}.mp4"
        p.write_bytes(data)
        cases.append({"kind": "video", "path": str(p)})
    _assert_clean(_run_batch(cases, tmp_path))


#: table changes a schema check catches; and changes that keep the schema but break the table's own consistency
SCHEMA_OPS = ("drop", "rename", "cast", "reorder", "empty", "none")
CONSISTENCY_OPS = ("slice", "meta", "meta_json")


def _parquet_variants(table: pa.Table, rng: np.random.Generator, ops: tuple[str, ...] = SCHEMA_OPS) -> pa.Table | None:
    """A schema- or metadata-level change of a valid table (None: leave it to byte mutations)."""
    op = rng.choice(list(ops))
    names = table.column_names
    k = int(rng.integers(0, len(names)))
    md = dict(table.schema.metadata or {})
    if op == "drop":
        return table.drop_columns([names[k]])
    if op == "rename":
        return table.rename_columns([n + "_x" if i == k else n for i, n in enumerate(names)])
    if op == "cast":
        f = table.schema.field(k)
        target = pa.float64() if f.type != pa.float64() else pa.float32()
        try:
            col = table.column(k).cast(target)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            col = pa.array([None] * table.num_rows, target)
        return table.set_column(k, pa.field(f.name, target), col)
    if op == "reorder":
        return table.select(list(reversed(names)))
    if op in ("meta", "meta_json") and md:
        key = list(md)[int(rng.integers(0, len(md)))]
        if op == "meta":
            md[key] = JUNK[int(rng.integers(0, len(JUNK)))]
        else:
            try:
                doc = json.loads(md[key])
            except ValueError:
                doc = None
            if isinstance(doc, dict) and doc:
                sub = list(doc)[int(rng.integers(0, len(doc)))]
                doc[sub] = [None, "x", -1, [], {}, 1e308, ["a"] * 3][int(rng.integers(0, 7))]
                md[key] = json.dumps(doc).encode()
            else:
                md.pop(key)
        return table.replace_schema_metadata(md)
    if op == "empty":
        return table.slice(0, 0)
    if op == "slice" and table.num_rows > 2:
        return table.slice(0, int(rng.integers(1, table.num_rows)))
    return None


def test_fuzz_parquet_tables_read_back(tmp_path, pipeline_out):
    _, out = pipeline_out
    sources = sorted(out.glob("takes/fz/*/*.parquet"))
    names = {p.stem for p in sources}
    assert {"markers_raw", "markers", "joints", "face"} <= names, names
    rng = np.random.default_rng(4)
    fuzz_out = tmp_path / "out"
    cases = []
    for i in range(CASES["parquet"]):
        src = sources[i % len(sources)]
        take = f"c{i:03d}"
        dest = fuzz_out / "takes" / "fz" / take / src.name
        dest.parent.mkdir(parents=True)
        if i < len(sources):
            shutil.copyfile(src, dest)
        else:
            changed = _parquet_variants(pq.read_table(src), rng) if i % 2 else None
            if changed is not None:
                pq.write_table(changed, dest, **write_options(changed.schema))
            else:
                data = src.read_bytes()
                region = [None, (max(0, len(data) - 2048), len(data)), (0, 64)][i % 3]
                dest.write_bytes(_mutate_bytes(data, rng, region))
        cases.append({"kind": "parquet", "path": str(dest), "out": str(fuzz_out), "session": "fz", "take": take,
                      "table": src.stem})
    _assert_clean(_run_batch(cases, tmp_path))


def _mutate_json(text: str, rng: np.random.Generator, only: str | None = None) -> bytes:
    """Delete or replace 1-3 random entries of a JSON document (within its top-level key ``only`` when given)."""
    doc = json.loads(text)
    for _ in range(int(rng.integers(1, 4))):
        node, key = doc, None
        if only == "name":
            _set_or_delete(doc, "name", rng)
            continue
        if only is not None and isinstance(doc.get(only), dict | list) and doc[only]:
            node = doc[only]
        depth = int(rng.integers(1, 4))
        for level in range(depth):  # walk down to a random entry
            keys = list(node) if isinstance(node, dict) else list(range(len(node)))
            if not keys:
                key = None
                break
            key = keys[int(rng.integers(0, len(keys)))]
            child = node[key]
            if level < depth - 1 and isinstance(child, dict | list) and child:
                node, key = child, None
                continue
            break
        if key is not None:
            _set_or_delete(node, key, rng)
    return json.dumps(doc).encode()


def _set_or_delete(node: dict | list, key, rng: np.random.Generator) -> None:
    if rng.random() < 0.3 and isinstance(node, dict):
        node.pop(key, None)          # an earlier mutation may have deleted it already
    else:
        node[key] = [None, "x", -1, 0, 10**6, 1.5, [], {}, [1, 2], True, "gaze_map"][int(rng.integers(0, 11))]


def test_fuzz_datasets(tmp_path, pipeline_out):
    _, out = pipeline_out
    bases = [d for d in sorted((out / "datasets").iterdir()) if (d / "_dataset.json").is_file()]
    assert len(bases) >= 2, bases
    rng = np.random.default_rng(5)
    cases = []
    for i in range(CASES["dataset"]):
        base = bases[i % len(bases)]
        d = tmp_path / f"ds_{i:03d}" / base.name
        shutil.copytree(base, d)
        if i >= len(bases):
            what = rng.choice(["json_bytes", "common", "take"])
            if what == "json_bytes":
                (d / "_dataset.json").write_bytes(_mutate_bytes((d / "_dataset.json").read_bytes(), rng, text=True))
            elif what == "common":
                (d / "_common_metadata").write_bytes(_mutate_bytes((d / "_common_metadata").read_bytes(), rng))
            else:
                f = sorted(d.glob("*/*/*.parquet"))[0]
                if rng.random() < 0.5:
                    f.write_bytes(_mutate_bytes(f.read_bytes(), rng))
                else:
                    changed = _parquet_variants(pq.read_table(f), rng)
                    if changed is None:
                        f.unlink()
                    else:
                        pq.write_table(changed, f, **write_options(changed.schema))
        cases.append({"kind": "dataset", "path": str(d)})
    _assert_clean(_run_batch(cases, tmp_path))


# ------------------------------------------------------------------------- inputs that once escaped the readers

def test_fuzz_non_utf8_text(tmp_path, pipeline_out):
    """Text inputs with bytes that are not UTF-8: 10 OpenFace, 10 Live Link Face, 10 dataset.json."""
    session, out = pipeline_out
    rng = np.random.default_rng(6)
    bases = {"openface": _head(CORPUS / "openface" / "pyfeat_OpenFace_Test.csv", 30),
             "livelinkface": _head(CORPUS / "livelinkface" / "alex_rom_3_first300.csv", 30)}
    cases = []
    for kind, base in bases.items():
        for i in range(10):
            b = bytearray(base)
            at = int(rng.integers(len(base) // 10, len(base)))
            b[at:at] = bytes(rng.integers(128, 256, size=int(rng.integers(1, 4)), dtype=np.uint8))
            p = tmp_path / f"{kind}_{i:02d}.csv"
            p.write_bytes(bytes(b))
            cases.append({"kind": kind, "path": str(p), "rate_hz": 60.0})
    ds = [d for d in sorted((out / "datasets").iterdir()) if (d / "_dataset.json").is_file()]
    for i in range(10):
        d = tmp_path / f"ds_{i:02d}" / ds[i % len(ds)].name
        shutil.copytree(ds[i % len(ds)], d)
        b = bytearray((d / "_dataset.json").read_bytes())
        at = int(rng.integers(0, len(b)))
        b[at:at] = bytes(rng.integers(128, 256, size=2, dtype=np.uint8))
        (d / "_dataset.json").write_bytes(bytes(b))
        cases.append({"kind": "dataset", "path": str(d)})
    _assert_clean(_run_batch(cases, tmp_path), min_ok=0)


def test_fuzz_tables_inconsistent_with_their_metadata(tmp_path, pipeline_out):
    """Tables that pass the schema check but disagree with their own metadata: 20 per-take tables (cut short,
    metadata entries changed) and 20 datasets whose dataset.json entries (any, sizes, name, counts) are changed or
    deleted."""
    _, out = pipeline_out
    rng = np.random.default_rng(7)
    cases = []
    sources = sorted(out.glob("takes/fz/*/*.parquet"))
    fuzz_out = tmp_path / "out"
    for i in range(20):
        src = sources[i % len(sources)]
        dest = fuzz_out / "takes" / "fz" / f"c{i:03d}" / src.name
        dest.parent.mkdir(parents=True)
        changed = _parquet_variants(pq.read_table(src), rng, CONSISTENCY_OPS)
        table = changed if changed is not None else pq.read_table(src)
        pq.write_table(table, dest, **write_options(table.schema))
        cases.append({"kind": "parquet", "path": str(dest), "out": str(fuzz_out), "session": "fz",
                      "take": f"c{i:03d}", "table": src.stem})
    ds = [d for d in sorted((out / "datasets").iterdir()) if (d / "_dataset.json").is_file()]
    for i in range(20):
        d = tmp_path / f"ds_{i:02d}" / ds[i % len(ds)].name
        shutil.copytree(ds[i % len(ds)], d)
        text = (d / "_dataset.json").read_text()
        (d / "_dataset.json").write_bytes(_mutate_json(text, rng, only=[None, "sizes", "name", "counts"][i % 4]))
        cases.append({"kind": "dataset", "path": str(d)})
    _assert_clean(_run_batch(cases, tmp_path), min_ok=0)
