"""Fault injection: ``gazepipe`` under hostile inputs, killed runs, a full disk and memory bombs (issue 24).

``python bench/bench_faults.py [--seed 24] [--cases N] [--families mutations,kills,disk,bombs]
[--work bench/_work/faults] [-j 2]`` runs four families of seeded cases (the same ``--seed`` gives the same
cases, byte for byte) and prints a summary table:

- ``mutations``: at least 500 mutated inputs across every reader: C3D (header words, POINT:RATE/SCALE/USED/
  FRAMES extremes, parameter names and labels with NUL and control bytes, frame counts beyond the file,
  truncation, flipped bytes, absurd coordinates; the sample session's files and the real-file corpus in
  ``tests/data/corpus/c3d``), Vicon Nexus CSV, QTM TSV and wide CSV (reversed, swapped and duplicated rows,
  repeated frame numbers, frames jumping to 1e12 / 1e18, NaN/inf/1e30 coordinates, 10^7-character lines, a cut
  header), OpenFace CSV, Live Link Face CSV (cut inside the header, no Timecode column, reversed timecodes, a
  huge line), session.toml and markerset.toml (5000 nested arrays, 300-character ids, unknown keys, wrong
  types, path escapes, huge strings, syntax errors) and the head-camera video (truncated, empty, a folder, a
  FIFO, missing), and six named classes of bad input, each with a seeded generator and the exit status it
  calls for: blank lines inside a Nexus CSV's data rows (read whole, with a warning), implausible rates in
  the text exports and session.toml (refused), implausible C3D scales and text-export spans (refused within
  1 mm of the origin, warned of beyond 100 m), byte-order marks (UTF-8 read, UTF-16 refused), link loops as
  a take's file (that take fails, exit 1) and face files of one row or videos far shorter than their take
  (the error names that file). A case runs ``python -m gazepipe run SESSION --out OUT --log-format json --executor serial``
  on a copy of a small session built from ``sample_data/session01`` with one file mutated, or
  ``python -m gazepipe inspect FILE`` for reader-only cases, with a timeout.
- ``kills``: 20 runs (``--executor process -j 2``) killed with SIGKILL at seeded random moments, 10 killing the
  leader only (``os.kill``: what the OOM killer does), 10 the whole process group (``os.killpg``); no process of
  the killed run may be alive 2 s after the kill (its session id, from ``/proc/*/stat``), files left under OUT
  must be complete copies of the reference's, and a rerun must give the reference run's bytes (every file
  under OUT outside ``OUT/.gazepipe``, as ``tests/pipeline/test_fault_tolerance.py`` compares).
- ``disk``: OUT on a 2 MB and a 20 MB tmpfs (the latter also nearly filled beforehand, leaving 0.4, 1.2 or
  2.5 MB: the run's 3 MB of outputs then meet the full disk at different moments), serial and process
  executors (root and ``mount -t tmpfs`` needed; skipped with the reason otherwise): exit 1 (or 2) with one
  line per failure naming a file under OUT, or exit 0 without errors where everything fits; a final
  ``run_end`` summary; no internal error.
- ``bombs``: a small C3D whose header claims 2,140,000 frames, well-formed C3Ds of 2,140,000 frames (sparse
  files of 274 MB and 993 MB, read to the end by ``inspect``), 10^8-character lines in every text reader,
  100 MB session.toml and markerset.toml files: refused within 10 s (the well-formed files read) with peak
  memory under 1 GB.

Each case's outcome is classified as ``ok`` or as one or more problems:

- ``crash``: exit status outside 0, 1, 2, 75 (a signal included), or a Python traceback in the output (a
  ``traceback`` field in a JSON event counts: none is printed without ``--debug``);
- ``internal``: "internal error" in the output;
- ``hang``: the timeout (60 s a run, 30 s an ``inspect``; a bomb's refusal slower than 10 s);
- ``silent``: a mutation of the frame/time column or an absurd coordinate that exits 0 with no new warning
  (warnings the unmutated input gives too do not count), or a bomb that is accepted (exit 0);
- ``multiline``: an error message over several lines, control bytes in any output line, or output that is not
  one JSON event a line in a JSON log (a plain ``error: ...`` line, as a configuration error refused before
  the run starts is printed, counts as an error line);
- ``unnamed``: an error line that does not name the mutated file (its name or path; for a few mutations
  another file the error may rightly name instead, e.g. a missing file's), or a flagged mutation accepted with
  a new warning that does not name the file (``run`` only: ``inspect`` prints the file it reads);
- ``exit``: an exit status other than the one a named class's case calls for (a valid file refused, a take's
  unreadable file refusing the whole run, an implausible rate accepted);
- ``>1GB``: the case's peak resident memory over 1 GiB (``ru_maxrss`` of the command, forked from a small
  launcher so that the bench's own memory does not count: the process and the children it waited for; for
  the process executor, the whole process tree's resident memory sampled every 50 ms);
- ``orphan`` / ``differs`` (kills): a process of the killed run alive 2 s after the kill / outputs that differ
  from the reference's after the rerun (or files left by the kill that are not the reference's).

Printed: one table row per family (the mutations split by reader), with the columns cases, ok, crash,
internal, hang, silent, multiline, unnamed, exit, >1GB, orphan, differs and a total; then every failing case (family,
mutation, file, first line of its output) and ``ALL CLEAN`` when there is no problem at all. The run's results
are also written to ``WORK/results.json``; each failing case's output is kept under ``WORK/cases/<id>/``.
The exit status is 0 whatever the findings (a benchmark, not a test; ``tests/test_faults_fast.py`` runs a
fast subset of the same cases as a test).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import math
import os
import re
import resource
import shutil
import signal
import struct
import subprocess
import sys
import threading
import time
import zlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

SAMPLE = REPO / "sample_data" / "session01"
CORPUS = REPO / "tests" / "data" / "corpus"
FAMILIES = ("mutations", "kills", "disk", "bombs")
PROBLEMS = ("crash", "internal", "hang", "silent", "multiline", "unnamed", "exit", "mem", "orphan", "differs")
COLUMN = {"mem": ">1GB"}
MEM_LIMIT_KB = 1 << 20          # 1 GiB, in ru_maxrss units (KiB on Linux)
RUN_TIMEOUT_S = 60.0
INSPECT_TIMEOUT_S = 30.0
BOMB_REFUSAL_S = 10.0
OK_EXITS = (0, 1, 2, 75)
KILL_TRIALS = 20
ORPHAN_GRACE_S = 2.0

#: the mutation count each reader or named class gets (sum: 617); ``--cases`` caps the total
QUOTA = {"c3d": 200, "vicon_csv": 55, "qtm_tsv": 45, "wide_csv": 40, "openface": 50, "livelinkface": 55,
         "session_toml": 45, "markerset_toml": 35, "video": 20,
         "blank_lines": 12, "rates": 16, "scales": 14, "bom": 10, "link_loops": 10, "named_files": 10}
#: the named classes of bad input (:func:`named_cases`), each with its own seeded generator
NAMED = ("blank_lines", "rates", "scales", "bom", "link_loops", "named_files")
#: the share of a reader's cases run through ``gazepipe run`` (the rest through ``gazepipe inspect``)
RUN_SHARE = {"c3d": 0.45, "vicon_csv": 0.4, "qtm_tsv": 0.4, "wide_csv": 0.4, "openface": 0.25,
             "livelinkface": 0.35}

_UNCLEAN = re.compile("[\x00-\x08\x0a-\x1f\x7f\x85\u2028\u2029\u202a-\u202e\u2066-\u2069]")


def rng_for(seed: int, name: str) -> np.random.Generator:
    """A generator of its own for each family or reader (adding cases to one changes no other)."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


# ================================================================================================ C3D bytes

_HDR_WORDS = {"points": 2, "analog_words": 4, "first": 6, "last": 8, "max_gap": 10, "data_start": 16}
_HDR_FLOATS = {"scale": 12, "rate": 20}


@dataclasses.dataclass
class C3DRecord:
    """One group or parameter record of a C3D parameter section (byte offsets into the file)."""

    at: int
    gid: int
    name: str
    name_at: int
    name_len: int
    off_at: int
    group: str = ""
    ptype: int = 0
    type_at: int = -1
    dims: tuple[int, ...] = ()
    data_at: int = -1
    size: int = 0


def c3d_records(data: bytes) -> tuple[str, list[C3DRecord]]:
    """The byte order (``<`` or ``>``) and the records of a C3D file's parameter section (a lenient walk that
    stops where the chain breaks)."""
    start = (data[0] - 1) * 512
    if start < 512 or start + 4 > len(data):
        return "<", []
    e = ">" if data[start + 3] == 86 else "<"
    end = min(len(data), start + 512 * max(data[start + 2], 1))
    p, recs, groups = start + 4, [], {}
    while p + 4 <= end:
        nlen, gid = struct.unpack_from("bb", data, p)
        if nlen == 0 or gid == 0 or p + 4 + abs(nlen) > end:
            break
        name_at, off_at = p + 2, p + 2 + abs(nlen)
        offset = struct.unpack_from(e + "h", data, off_at)[0]
        rec = C3DRecord(at=p, gid=gid, name=data[name_at:off_at].decode("latin-1").strip().upper(),
                        name_at=name_at, name_len=abs(nlen), off_at=off_at)
        if gid < 0:
            groups[-gid] = rec.name
        elif off_at + 4 <= end:
            q = off_at + 2
            rec.ptype, ndim = struct.unpack_from("b", data, q)[0], data[q + 1]
            rec.type_at, rec.dims, rec.data_at = q, tuple(data[q + 2: q + 2 + ndim]), q + 2 + ndim
            rec.size = abs(rec.ptype) * (math.prod(rec.dims) if ndim else 1)
        recs.append(rec)
        if offset <= 0:
            break
        p = off_at + offset
    for r in recs:
        r.group = groups.get(r.gid, "") if r.gid > 0 else r.name
    return e, recs


def c3d_param(recs: list[C3DRecord], group: str, name: str) -> C3DRecord | None:
    return next((r for r in recs if r.gid > 0 and r.group == group and r.name == name), None)


def c3d_processor(data: bytes) -> str:
    start = (data[0] - 1) * 512
    return {84: "intel", 85: "dec", 86: "mips"}.get(data[start + 3] if 0 < start + 3 < len(data) else -1, "?")


def set_header(b: bytearray, word: str, value: float, e: str = "<") -> None:
    if word in _HDR_FLOATS:
        struct.pack_into(e + "f", b, _HDR_FLOATS[word], value)
    else:
        struct.pack_into(e + "H", b, _HDR_WORDS[word], int(value) & 0xFFFF)


def set_param(b: bytearray, group: str, name: str, value: float) -> bool:
    """Write ``value`` into the first element of a numeric parameter (as its type stores it); False if the
    parameter is absent, not numeric or has no element."""
    e, recs = c3d_records(bytes(b))
    r = c3d_param(recs, group, name)
    if r is None or r.ptype not in (1, 2, 4) or r.size < r.ptype or r.data_at + r.size > len(b):
        return False
    if r.ptype == 4:
        struct.pack_into(e + "f", b, r.data_at, value)
    elif r.ptype == 2:
        struct.pack_into(e + "H", b, r.data_at, int(value) & 0xFFFF)
    else:
        b[r.data_at] = int(value) & 0xFF
    return True


def write_c3d_float(path: Path, n_points: int, n_frames: int, rate_hz: float = 120.0,
                    frames_written: int | None = None, claim_frames: int | None = None) -> None:
    """A minimal Intel float C3D: POINT (USED, SCALE, RATE, FRAMES, LABELS, UNITS) and TRIAL
    (ACTUAL_START_FIELD, ACTUAL_END_FIELD: 32-bit frame numbers, for more than 65535 frames) parameters.

    ``claim_frames`` frames are declared (default ``n_frames``); the data section holds ``n_frames`` frames, of
    which the first ``frames_written`` (default all) carry a slowly moving point cloud and the rest are left
    sparse (zeros, read back as gaps)."""
    claim = n_frames if claim_frames is None else claim_frames
    labels = [f"M{i:03d}" for i in range(n_points)]

    def rec(gid: int, name: str, body: bytes) -> bytes:
        return struct.pack("bb", len(name), gid) + name.encode() + struct.pack("<h", 2 + len(body)) + body

    def prm(gid: int, name: str, ptype: int, dims: tuple[int, ...], data: bytes) -> bytes:
        return rec(gid, name, struct.pack("bB", ptype, len(dims)) + bytes(dims) + data + b"\x00")

    end_field = (claim % 65536, claim // 65536)
    params = b"".join([
        rec(-1, "POINT", b"\x00"),
        prm(1, "USED", 2, (), struct.pack("<H", n_points)),
        prm(1, "SCALE", 4, (), struct.pack("<f", -1.0)),
        prm(1, "RATE", 4, (), struct.pack("<f", rate_hz)),
        prm(1, "FRAMES", 2, (), struct.pack("<H", min(claim, 65535))),
        prm(1, "LABELS", -1, (4, n_points), "".join(lb.ljust(4) for lb in labels).encode()),
        prm(1, "UNITS", -1, (2,), b"mm"),
        rec(-2, "TRIAL", b"\x00"),
        prm(2, "ACTUAL_START_FIELD", 2, (2,), struct.pack("<HH", 1, 0)),
        prm(2, "ACTUAL_END_FIELD", 2, (2,), struct.pack("<HH", *end_field)),
    ]) + b"\x00\x00"
    n_blocks = (4 + len(params) + 511) // 512
    section = (struct.pack("BBBB", 1, 0x50, n_blocks, 84) + params).ljust(512 * n_blocks, b"\x00")
    data_start = 2 + n_blocks
    head = bytearray(512)
    struct.pack_into("<BBHHHHH", head, 0, 2, 0x50, n_points, 0, 1, min(claim, 65535), 0)
    struct.pack_into("<f", head, 12, -1.0)
    struct.pack_into("<HHf", head, 16, data_start, 0, rate_hz)
    written = n_frames if frames_written is None else min(frames_written, n_frames)
    t = np.arange(written, dtype=np.float32)[:, None]
    pts = np.zeros((written, n_points, 4), dtype="<f4")
    pts[..., 0] = 100.0 * np.arange(n_points, dtype=np.float32)[None, :] + 0.01 * t
    pts[..., 1] = 50.0 * np.sin(t / 30.0)
    pts[..., 2] = 1000.0
    pts[..., 3] = 0.5
    with open(path, "wb") as fh:
        fh.write(bytes(head) + section)
        fh.write(pts.tobytes())
        fh.truncate(512 + len(section) + n_frames * n_points * 16)


# ================================================================================================ text writers

def vicon_text(m) -> bytes:
    """A Vicon Nexus "Trajectories" CSV of ``m`` (a Markers), subject prefix ``p01:``, gaps as empty cells."""
    lines = ["Trajectories", f"{m.rate_hz:.6f}".rstrip("0").rstrip("."),
             ",," + ",".join(f"p01:{lb},," for lb in m.labels).rstrip(","),
             "Frame,Sub Frame," + ",".join("X,Y,Z" for _ in m.labels),
             ",," + ",".join("mm,mm,mm" for _ in m.labels)]
    xyz = np.where(m.valid[..., None], m.xyz, np.nan)
    for i in range(xyz.shape[0]):
        cells = ["" if np.isnan(v) else f"{v:.5f}" for v in xyz[i].ravel()]
        lines.append(f"{m.first_frame + i},0," + ",".join(cells))
    return ("\n".join(lines) + "\n").encode()


def qtm_text(m) -> bytes:
    """A QTM 3D TSV export of ``m``: header keys, a Frame/Time column row, gaps as empty cells."""
    n = m.xyz.shape[0]
    lines = [f"NO_OF_FRAMES\t{n}", "NO_OF_CAMERAS\t8", f"NO_OF_MARKERS\t{len(m.labels)}",
             f"FREQUENCY\t{m.rate_hz:.6f}".rstrip("0").rstrip("."), "NO_OF_ANALOG\t0", "ANALOG_FREQUENCY\t0",
             "DESCRIPTION\t--", "TIME_STAMP\t2019-11-28, 13:43:42.715\t1476252.89504471", "DATA_INCLUDED\t3D",
             "MARKER_NAMES\t" + "\t".join(m.labels), "TRAJECTORY_TYPES\t" + "\t".join("Measured" for _ in m.labels),
             "Frame\tTime\t" + "\t".join(f"{lb} {a}" for lb in m.labels for a in "XYZ")]
    xyz = np.where(m.valid[..., None], m.xyz, np.nan)
    for i in range(n):
        cells = ["" if np.isnan(v) else f"{v:.5f}" for v in xyz[i].ravel()]
        lines.append(f"{m.first_frame + i}\t{i / m.rate_hz:.5f}\t" + "\t".join(cells))
    return ("\n".join(lines) + "\n").encode()


# ================================================================================================ sessions

MOCAP_TAKE = "shift_y036_p12"
FOLLOW_TAKE = "follow_standing_03"
FACE_TAKE = "face_04"


def _take_toml(t: dict) -> str:
    out = ["[[takes]]"]
    for k, v in t.items():
        out.append(f"{k} = {v}" if k == "target" else f'{k} = {json.dumps(v)}')
    return "\n".join(out) + "\n"


def session_toml(takes: list[dict], session_id: str = "faults", markerset: bool = True) -> str:
    head = f'schema = 1\n\n[session]\nid = "{session_id}"\nsubject = "p01"\n'
    head += 'markerset = "markerset.toml"\n' if markerset else ""
    return head + "\n" + "\n".join(_take_toml(t) for t in takes)


NEUTRAL = {"id": "neutral", "kind": "neutral", "pose": "standing", "mocap": "mocap/neutral.c3d"}
SHIFT_TARGET = "{ yaw_deg = 36.0, pitch_deg = 12.0 }"


def _shift(mocap: str) -> dict:
    return {"id": MOCAP_TAKE, "kind": "gaze_shift", "pose": "standing", "mocap": mocap, "target": SHIFT_TARGET}


#: base sessions: name -> (takes, files to copy from the sample (relative paths), generated files)
def base_specs() -> dict[str, dict]:
    follow = {"id": FOLLOW_TAKE, "kind": "gaze_follow", "pose": "standing", "mocap": f"mocap/{FOLLOW_TAKE}.c3d",
              "video": f"video/{FOLLOW_TAKE}.mp4", "eyes": f"eyes/{FOLLOW_TAKE}.csv"}
    face = {"id": FACE_TAKE, "kind": "face", "tracked": f"face/{FACE_TAKE}_tracked.csv",
            "clean": f"face/{FACE_TAKE}_clean.csv", "rate_hz": 30, "timecode_fps": 60}
    shift_c3d = f"mocap/{MOCAP_TAKE}.c3d"
    return {
        "c3d": {"takes": [NEUTRAL, _shift(shift_c3d)], "copy": ["mocap/neutral.c3d", shift_c3d]},
        "vicon_csv": {"takes": [NEUTRAL, _shift(f"mocap/{MOCAP_TAKE}.csv")], "copy": ["mocap/neutral.c3d"],
                      "make": {f"mocap/{MOCAP_TAKE}.csv": "vicon"}},
        "qtm_tsv": {"takes": [NEUTRAL, _shift(f"mocap/{MOCAP_TAKE}.tsv")], "copy": ["mocap/neutral.c3d"],
                    "make": {f"mocap/{MOCAP_TAKE}.tsv": "qtm"}},
        "wide_csv": {"takes": [NEUTRAL, _shift(f"mocap/{MOCAP_TAKE}_wide.csv")], "copy": ["mocap/neutral.c3d"],
                     "make": {f"mocap/{MOCAP_TAKE}_wide.csv": "wide"}},
        "follow": {"takes": [NEUTRAL, follow],
                   "copy": ["mocap/neutral.c3d", follow["mocap"], follow["video"], follow["eyes"]]},
        "face": {"takes": [face], "copy": [face["tracked"], face["clean"]], "markerset": False},
        "kills": {"takes": [NEUTRAL, _shift(shift_c3d), {**_shift("mocap/shift_ym036_p00.c3d"),
                                                           "id": "shift_ym036_p00",
                                                           "target": "{ yaw_deg = -36.0, pitch_deg = 0.0 }"},
                            follow, face],
                  "copy": ["mocap/neutral.c3d", shift_c3d, "mocap/shift_ym036_p00.c3d", follow["mocap"],
                           follow["video"], follow["eyes"], face["tracked"], face["clean"]]},
    }


def build_bases(root: Path) -> dict[str, Path]:
    """The base sessions under ``root`` (rebuilt: a few MB copied from the sample session)."""
    from gazepipe.io.c3d import read_c3d
    from gazepipe.io.marker_csv import write_wide_csv

    shutil.rmtree(root, ignore_errors=True)
    markers = read_c3d(SAMPLE / "mocap" / f"{MOCAP_TAKE}.c3d")
    out = {}
    for name, spec in base_specs().items():
        s = root / name
        s.mkdir(parents=True)
        for rel in spec["copy"]:
            (s / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(SAMPLE / rel, s / rel)
        for rel, kind in spec.get("make", {}).items():
            (s / rel).parent.mkdir(parents=True, exist_ok=True)
            if kind == "wide":
                write_wide_csv(s / rel, markers)
            else:
                (s / rel).write_bytes(vicon_text(markers) if kind == "vicon" else qtm_text(markers))
        if spec.get("markerset", True):
            shutil.copyfile(SAMPLE / "markerset.toml", s / "markerset.toml")
        (s / "session.toml").write_text(session_toml(spec["takes"], markerset=spec.get("markerset", True)))
        out[name] = s
    return out


# ================================================================================================ cases

Mutate = Callable[[Path], None]


@dataclasses.dataclass
class Case:
    """One hostile input. ``apply(path)`` replaces the file at ``path`` (a hard link to the original, or a
    copy of it) by the mutated input (or a folder, a FIFO, nothing).

    mode ``run``: ``base`` names a base session (:func:`base_specs`) and ``target`` the file in it (relative);
    mode ``inspect``: ``base`` is the source file's path and ``target`` its name in the case folder.
    ``flag``: a frame/time-column mutation or an absurd value: exit 0 needs a new warning naming the file.
    ``refuse``: exit 0 is a silent acceptance whatever the warnings (bombs). ``limit_s``: slower is a hang."""

    id: str
    family: str
    reader: str
    mutation: str
    mode: str
    base: str
    target: str
    apply: Mutate
    flag: bool = False
    refuse: bool = False
    limit_s: float | None = None
    timeout_s: float | None = None
    names: tuple[str, ...] = ()   # other file names an error may rightly name instead (a missing file's)
    expect: tuple[int, ...] | None = None   # the exit statuses the case calls for (None: any of OK_EXITS)

    @property
    def file_name(self) -> str:
        return Path(self.target).name


def _replace(path: Path, data: bytes) -> None:
    path.unlink(missing_ok=True)
    path.write_bytes(data)


def bytes_mutation(fn: Callable[[bytes], bytes]) -> Mutate:
    def apply(path: Path) -> None:
        _replace(path, fn(path.read_bytes()))
    return apply


def special_mutation(kind: str) -> Mutate:
    """A file that is no regular file: missing, a folder, a FIFO, a link to /dev/zero, unreadable."""
    def apply(path: Path) -> None:
        path.unlink(missing_ok=True)
        if kind == "dir":
            path.mkdir()
            (path / "inside.txt").write_text("a folder, not a file\n")
        elif kind == "fifo":
            os.mkfifo(path)
        elif kind == "devzero":
            path.symlink_to("/dev/zero")
        elif kind == "dangling":
            path.symlink_to(path.parent / "no_such_file")
        elif kind == "empty":
            path.write_bytes(b"")
    return apply


SPECIALS_RUN = ("missing", "dir", "fifo", "devzero", "dangling", "empty")


def _pick(rng: np.random.Generator, seq):
    return seq[int(rng.integers(0, len(seq)))]


# ------------------------------------------------------------------------------------------------ C3D

CTRL_BYTES = (0x00, 0x01, 0x07, 0x0A, 0x0D, 0x1B, 0x7F, 0xFF)
RATES = (0.0, 1e-30, 1e30, math.nan, math.inf, -math.inf, -100.0, 0.5, 20000.0, 1e-5)
SCALES = (0.0, math.nan, math.inf, 1e30, -1e30, 1e-30, -1e-30)


def _c3d_ops(proc: str) -> list[tuple[str, bool, Callable[[bytearray, np.random.Generator], None]]]:  # noqa: C901
    """(mutation name, flag, edit) for a C3D file of processor ``proc`` (float edits only where the bench can
    write the file's float format)."""
    e = ">" if proc == "mips" else "<"
    floats = proc in ("intel", "mips")
    ops: list = []

    def hdr(word, v):
        return lambda b, rng: set_header(b, word, v, e)

    def prm(group, name, v):
        return lambda b, rng: set_param(b, group, name, v)

    for v in (0, 1, 255, 32767, 65535):
        ops.append((f"header.points={v}", False, hdr("points", v)))
    for v in (0, 65535):
        ops.append((f"header.first_frame={v}", False, hdr("first", v)))
    for v in (0, 65535, 2 ** 15):
        ops.append((f"header.last_frame={v}", False, hdr("last", v)))
    for v in (0, 1, 2, 65535):
        ops.append((f"header.data_start={v}", False, hdr("data_start", v)))
    for v in (1, 4000, 65535):
        ops.append((f"header.analog_words={v}", False, hdr("analog_words", v)))
    ops.append(("header.param_block=0", False, lambda b, rng: b.__setitem__(0, 0)))
    ops.append(("header.param_block=255", False, lambda b, rng: b.__setitem__(0, 255)))
    ops.append(("header.key_byte=0", False, lambda b, rng: b.__setitem__(1, 0)))
    if floats:
        for v in SCALES:
            ops.append((f"header.scale={v:g}", False, hdr("scale", v)))
        for v in RATES:
            ops.append((f"header.rate={v:g}", False, hdr("rate", v)))
        for v in RATES:
            ops.append((f"POINT:RATE={v:g}", False, prm("POINT", "RATE", v)))

            def both(b, rng, v=v):
                set_header(b, "rate", v, e)
                set_param(b, "POINT", "RATE", v)
            ops.append((f"POINT:RATE+header.rate={v:g}", False, both))
        for v in SCALES:
            ops.append((f"POINT:SCALE={v:g}", False, prm("POINT", "SCALE", v)))
    for v in (0, 1, 32767, 65535):
        ops.append((f"POINT:USED={v}", False, prm("POINT", "USED", v)))
    for v in (0, 65535):
        ops.append((f"POINT:FRAMES={v}", False, prm("POINT", "FRAMES", v)))

    def frames_beyond(b, rng):   # header and POINT:FRAMES claim 50x the frames the file holds
        _, recs = c3d_records(bytes(b))
        first, last = struct.unpack_from(e + "HH", b, 6)
        n = min(65535, first + 50 * max(last - first + 1, 1))
        set_header(b, "last", n, e)
        set_param(b, "POINT", "FRAMES", n)
    ops.append(("frames_beyond_file(50x)", False, frames_beyond))

    def name_ctrl(b, rng):
        _, recs = c3d_records(bytes(b))
        r = _pick(rng, recs)
        b[r.name_at + int(rng.integers(0, r.name_len))] = _pick(rng, CTRL_BYTES)
    for k in range(3):
        ops.append((f"param_name.control_byte#{k}", False, name_ctrl))

    def point_name_ctrl(b, rng):
        _, recs = c3d_records(bytes(b))
        r = next((r for r in recs if r.gid < 0 and r.name == "POINT"), None) or _pick(rng, recs)
        b[r.name_at] = _pick(rng, CTRL_BYTES)
    ops.append(("group_name(POINT).control_byte", False, point_name_ctrl))

    def rate_name_nul(b, rng):
        _, recs = c3d_records(bytes(b))
        r = c3d_param(recs, "POINT", "RATE") or _pick(rng, recs)
        b[r.name_at + r.name_len - 1] = 0
    ops.append(("param_name(RATE).NUL", False, rate_name_nul))

    def label_ctrl(b, rng, seq=b"\x1b[31m\x00\x07"):
        _, recs = c3d_records(bytes(b))
        r = c3d_param(recs, "POINT", "LABELS")
        if r is None or r.size == 0:
            return
        i = r.data_at + int(rng.integers(0, max(1, r.size - len(seq))))
        b[i: i + len(seq)] = seq[: max(0, min(len(seq), r.data_at + r.size - i))]
    ops.append(("POINT:LABELS.escape_sequence", False, label_ctrl))
    ops.append(("POINT:LABELS.newline", False, lambda b, rng: label_ctrl(b, rng, b"\r\n")))

    def ptype(v):
        def edit(b, rng):
            _, recs = c3d_records(bytes(b))
            params = [r for r in recs if r.type_at >= 0]
            if params:
                b[_pick(rng, params).type_at] = v & 0xFF
        return edit
    for v in (0, 3, -2, -1):
        ops.append((f"param.type={v}", False, ptype(v)))

    def pdims(b, rng):
        _, recs = c3d_records(bytes(b))
        params = [r for r in recs if r.type_at >= 0]
        if params:
            r = _pick(rng, params)
            b[r.type_at + 1] = 255
    ops.append(("param.ndims=255", False, pdims))

    def poffset(v):
        def edit(b, rng):
            _, recs = c3d_records(bytes(b))
            if recs:
                struct.pack_into(e + "h", b, _pick(rng, recs).off_at, v)
        return edit
    for v in (0, -4, 32767, 1):
        ops.append((f"param.next_offset={v}", False, poffset(v)))

    def section(i, v):
        return lambda b, rng: b.__setitem__((b[0] - 1) * 512 + i, v) if 0 < (b[0] - 1) * 512 + i < len(b) else None
    ops.append(("param_section.blocks=0", False, section(2, 0)))
    ops.append(("param_section.blocks=255", False, section(2, 255)))
    ops.append(("param_section.processor=0", False, section(3, 0)))
    ops.append(("param_section.processor=87", False, section(3, 87)))

    def flip(region):
        def edit(b, rng):
            lo, hi = {"header": (0, 512), "params": ((b[0] - 1) * 512, (b[0] - 1) * 512 + 512),
                      "anywhere": (0, len(b))}[region]
            hi = min(hi, len(b))
            for _ in range(int(rng.integers(1, 9))):
                if hi > lo >= 0:
                    b[int(rng.integers(lo, hi))] = int(rng.integers(0, 256))
        return edit
    for region in ("header", "params", "anywhere"):
        for k in range(2):
            ops.append((f"flip_bytes.{region}#{k}", False, flip(region)))
    return ops


def _c3d_data_ops() -> list[tuple[str, bool, Callable[[bytearray, np.random.Generator], None]]]:
    """Coordinate edits of a float, analog-free Intel C3D (the sample files): absurd values in some samples."""
    def coords(value, axes=(0, 1, 2), count=5):
        def edit(b, rng):
            n_points, _, first, last = struct.unpack_from("<HHHH", b, 2)
            data_at = (struct.unpack_from("<H", b, 16)[0] - 1) * 512
            n = last - first + 1
            for _ in range(count):
                t, m = int(rng.integers(0, n)), int(rng.integers(0, n_points))
                for a in axes:
                    struct.pack_into("<f", b, data_at + (t * n_points + m) * 16 + 4 * a, value)
        return edit
    return [("coords.inf", True, coords(math.inf)), ("coords.-inf", True, coords(-math.inf, axes=(2,))),
            ("coords.1e30", True, coords(1e30)), ("coords.-3e38", True, coords(-3e38, axes=(1,))),
            ("coords.partial_nan", False, coords(math.nan, axes=(0,))),   # a gap by SPEC §1's rule
            ("coords.nan_xyz", False, coords(math.nan)),
            ("coords.all_1e30", True, coords(1e30, count=100000)),
            ("coords.2e6mm", True, coords(2e6, axes=(0,)))]


def _truncations(data_len: int, rng: np.random.Generator) -> list[tuple[str, Callable[[bytes], bytes]]]:
    cuts = [0, 100, 511, 512, 1024, int(rng.integers(1024, max(1025, data_len))), data_len - 1]
    out = [(f"truncate@{c}", (lambda d, c=c: d[:c])) for c in cuts]
    junk = rng.integers(0, 256, 4096, dtype=np.uint8).tobytes()
    out.append(("append_junk_4k", lambda d: d + junk))
    out.append(("half_file", lambda d: d[: len(d) // 2]))
    return out


def c3d_cases(seed: int, n: int) -> list[Case]:
    """``n`` C3D mutations: every mutation of the sample session's shift take (run or inspect), then the
    real-file corpus's (inspect) in a seeded order."""
    rng = rng_for(seed, "c3d")
    sample = SAMPLE / "mocap" / f"{MOCAP_TAKE}.c3d"
    corpus = sorted((CORPUS / "c3d").glob("*.c3d"))
    menu: list[tuple[Path, str, bool, str, object]] = []    # (source, name, flag, kind, what)
    for src in [sample, *corpus]:
        data = src.read_bytes()
        for name, flag, edit in _c3d_ops(c3d_processor(data)):
            menu.append((src, name, flag, "edit", edit))
        for name, fn in _truncations(len(data), rng):
            menu.append((src, name, False, "bytes", fn))
    for name, flag, edit in _c3d_data_ops():
        menu.append((sample, name, flag, "edit", edit))
    for kind in SPECIALS_RUN:
        menu.append((sample, f"special.{kind}", False, "special", kind))
    sample_items = [it for it in menu if it[0] == sample]
    others = [menu[i] for i in rng.permutation(len(menu)) if menu[i][0] != sample]
    cases = []
    for k, (src, name, flag, kind, what) in enumerate((sample_items + others)[:n]):
        sub = int(rng.integers(0, 2**31))
        if kind == "special":
            apply = special_mutation(what)
        elif kind == "bytes":
            apply = bytes_mutation(what)
        else:
            apply = bytes_mutation(lambda d, edit=what, sub=sub: _edited(d, edit, sub))
        cid = f"c3d-{k:03d}"
        if src == sample and (kind == "special" or rng.random() < RUN_SHARE["c3d"]):
            target = f"mocap/{MOCAP_TAKE}.c3d"
            if kind != "special" and rng.random() < 0.12:
                target = "mocap/neutral.c3d"
            cases.append(Case(cid, "mutations", "c3d", name, "run", "c3d", target, apply, flag))
        else:
            cases.append(Case(cid, "mutations", "c3d", name, "inspect", str(src), src.name, apply, flag))
    return cases


def _edited(data: bytes, edit, sub: int) -> bytes:
    b = bytearray(data)
    edit(b, np.random.default_rng(sub))
    return bytes(b)


# ------------------------------------------------------------------------------------------------ text tables

@dataclasses.dataclass(frozen=True)
class TextSpec:
    """Where a text format keeps its rows: ``header`` lines before the data, ``sep``, the frame column (or
    the Live Link Face timecode), the time column, the value columns."""

    reader: str
    header: int
    sep: bytes
    frame_col: int | None
    time_col: int | None
    value_cols: tuple[int, ...]
    timecode: bool = False


def _split(data: bytes, spec: TextSpec) -> tuple[list[bytes], list[list[bytes]], bytes]:
    eol = b"\r\n" if b"\r\n" in data[:4096] else b"\n"
    lines = data.split(eol)
    while lines and lines[-1] == b"":
        lines.pop()
    return lines[: spec.header], [ln.split(spec.sep) for ln in lines[spec.header:]], eol


def _join(head: list[bytes], rows: list[list[bytes]], spec: TextSpec, eol: bytes = b"\n") -> bytes:
    return eol.join(head + [spec.sep.join(r) for r in rows]) + eol


def _tc(frame: int, fps: int = 60) -> bytes:
    s, f = divmod(frame, fps)
    m, s = divmod(s, 60)
    h, m = divmod(m, 60)
    return f"{h:02d}:{m:02d}:{s:02d}:{f:02d}.000".encode()


def _rows_op(fn: Callable[[list[bytes], list[list[bytes]], TextSpec, np.random.Generator], None]):
    def make(spec: TextSpec, sub: int) -> Callable[[bytes], bytes]:
        def mutate(data: bytes) -> bytes:
            head, rows, eol = _split(data, spec)
            fn(head, rows, spec, np.random.default_rng(sub))
            return _join(head, rows, spec, eol)
        return mutate
    return make


def _mid(rng: np.random.Generator, rows: list) -> int:
    return int(rng.integers(1, max(2, len(rows) - 1)))


def _set_col(col: str, value: bytes | Callable[[bytes, int], bytes], which: str = "one"):
    def fn(head, rows, spec, rng):
        c = spec.frame_col if col == "frame" and spec.frame_col is not None else spec.time_col
        if c is None:
            return
        idx = range(len(rows)) if which == "all" else [_mid(rng, rows)]
        for i in idx:
            if c < len(rows[i]):
                rows[i][c] = value(rows[i][c], i) if callable(value) else value
    return _rows_op(fn)


def _text_ops(spec: TextSpec) -> list[tuple[str, bool, Callable[[TextSpec, int], Callable[[bytes], bytes]]]]:
    """(mutation name, flag, maker) for a text format; ``maker(spec, sub_seed)`` gives the byte mutation."""
    ops: list = []
    frame = "timecode" if spec.timecode else "frame"

    def reverse(head, rows, spec, rng):
        rows.reverse()

    def swap(head, rows, spec, rng):
        i = _mid(rng, rows)
        j = min(len(rows) - 1, i + int(rng.integers(1, 20)))
        rows[i], rows[j] = rows[j], rows[i]

    def dup(head, rows, spec, rng):
        i = _mid(rng, rows)
        rows.insert(i, list(rows[i]))

    def repeat(head, rows, spec, rng):
        c = spec.frame_col if spec.frame_col is not None else spec.time_col
        i = _mid(rng, rows)
        rows[i][c] = rows[i - 1][c]

    def step_back(head, rows, spec, rng):
        i = _mid(rng, rows)
        if spec.timecode:
            rows[i][0] = rows[max(0, i - 10)][0]
        else:
            rows[i][spec.frame_col] = str(int(float(rows[i][spec.frame_col])) - 10).encode()

    def drop(head, rows, spec, rng):   # a block of rows from the middle half: frames missing between rows
        i = int(rng.integers(len(rows) // 4, max(len(rows) // 4 + 1, 3 * len(rows) // 4)))
        del rows[i: i + int(rng.integers(3, 12))]

    ops += [("rows.reversed", True, _rows_op(reverse)), ("rows.swap", True, _rows_op(swap)),
            ("rows.duplicate", True, _rows_op(dup)), (f"{frame}.repeat_previous", True, _rows_op(repeat)),
            (f"{frame}.step_back", True, _rows_op(step_back)), ("rows.dropped_block", True, _rows_op(drop))]
    if spec.timecode:
        for v in (b"23:59:59:59.000", b"00:00:00:00.000", b"99:99:99:99.9", b"12:00:00:00.500", b"", b"nan"):
            ops.append((f"timecode.jump={v.decode() or 'empty'}", True, _set_col("frame", v)))
        ops.append(("timecode.all_same", True, _set_col("frame", b"10:00:00:00.000", "all")))
        ops.append(("timecode.reversed_only", True, _rows_op(_reverse_col(0))))
    else:
        for v in (b"1000000000000", b"1000000000000000000", b"2147483648", b"-5", b"0", b"1e12", b"nan", b"inf",
                  b"1.5", b""):
            ops.append((f"frame.jump={v.decode() or 'empty'}", True, _set_col("frame", v)))
        ops.append(("frame.all=1e18", True, _set_col("frame", b"1000000000000000000", "all")))
        ops.append(("frame.all_same", True, _set_col("frame", b"7", "all")))
        ops.append(("frame.times_1e12", True,
                    _set_col("frame", lambda v, i: str(int(float(v)) * 10**12).encode(), "all")))
        if spec.time_col is not None:
            ops.append(("time.reversed_only", True, _rows_op(_reverse_col(spec.time_col))))
            for v in (b"1e12", b"-1", b"nan", b"inf"):
                ops.append((f"time.jump={v.decode()}", True, _set_col("time", v)))
    flag_values = spec.reader in ("vicon_csv", "qtm_tsv", "wide_csv")
    for v, partial, flag in ((b"inf", False, flag_values), (b"-inf", True, flag_values),
                             (b"1e30", False, flag_values), (b"-1e300", True, flag_values),
                             (b"nan", True, flag_values), (b"nan", False, False), (b"abc", True, False),
                             (b"0x10", True, False), (b"1,5", True, False)):
        ops.append((f"values.{v.decode()}{'(one)' if partial else '(xyz)'}", flag,
                    _rows_op(_values(v, partial))))
    ops += [("header.cut", False, _cut_header), ("data.cut_mid_row", False, _cut_data),
            ("line.huge_row(1e7)", False, _huge(10**7, header=False)),
            ("line.huge_header(1e7)", False, _huge(10**7, header=True)),
            ("column.drop_first", False, _drop_col(0)), ("column.drop_value", False, _drop_col(-1)),
            ("column.rename_first", False, _rename_col(0)), ("header.only", False, _rows_op(_no_rows)),
            ("file.empty", False, lambda spec, sub: lambda d: b""),
            ("line_endings.crlf", False, lambda spec, sub: lambda d: d.replace(b"\n", b"\r\n")),
            ("bom", False, lambda spec, sub: lambda d: b"\xef\xbb\xbf" + d),
            ("bytes.non_utf8_cell", False, _rows_op(_values(b"\xff\xfe\x80", True))),
            ("header.nul_and_escape", False, _header_bytes(b"\x00\x1b[2J\x07")),
            ("row.short", False, _rows_op(_short_row)), ("row.long", False, _rows_op(_long_row)),
            ("rows.blank_lines", False, _rows_op(_blank_rows)), ("bytes.random_flips", False, _flips)]
    return ops


def _reverse_col(c: int):
    def fn(head, rows, spec, rng):
        vals = [r[c] for r in rows if c < len(r)]
        for r, v in zip([r for r in rows if c < len(r)], reversed(vals), strict=True):
            r[c] = v
    return fn


def _values(v: bytes, partial: bool):
    def fn(head, rows, spec, rng):
        for _ in range(3):
            r = rows[_mid(rng, rows)]
            k = int(rng.integers(0, len(spec.value_cols) // 3)) * 3
            for c in spec.value_cols[k: k + (1 if partial else 3)]:
                if c < len(r):
                    r[c] = v
    return fn


def _no_rows(head, rows, spec, rng):
    rows.clear()


def _short_row(head, rows, spec, rng):
    r = rows[_mid(rng, rows)]
    del r[len(r) // 2:]


def _long_row(head, rows, spec, rng):
    rows[_mid(rng, rows)].extend([b"1", b"2", b"3", b"4"])


def _blank_rows(head, rows, spec, rng):
    for _ in range(3):
        rows.insert(_mid(rng, rows), [b""])


def _cut_header(spec: TextSpec, sub: int) -> Callable[[bytes], bytes]:
    def mutate(d: bytes) -> bytes:
        end = 0
        for _ in range(spec.header):
            end = d.index(b"\n", end) + 1
        return d[: int(np.random.default_rng(sub).integers(1, max(2, end)))]
    return mutate


def _cut_data(spec: TextSpec, sub: int) -> Callable[[bytes], bytes]:
    def mutate(d: bytes) -> bytes:
        i = int(np.random.default_rng(sub).integers(len(d) // 2, len(d) - 1))
        while i < len(d) - 1 and d[i: i + 1] in (b"\n", spec.sep):
            i += 1
        return d[:i]
    return mutate


def _huge(n: int, header: bool):
    def make(spec: TextSpec, sub: int) -> Callable[[bytes], bytes]:
        def mutate(d: bytes) -> bytes:
            head, rows, eol = _split(d, spec)
            if header:
                head[-1] = head[-1] + spec.sep + b"x" * n
            else:
                r = rows[len(rows) // 2]
                c = spec.value_cols[0]
                r[c] = b"1" * n
            return _join(head, rows, spec, eol)
        return mutate
    return make


def _drop_col(which: int):
    def make(spec: TextSpec, sub: int) -> Callable[[bytes], bytes]:
        c = (spec.frame_col if spec.frame_col is not None else 0) if which == 0 else spec.value_cols[-1]

        def mutate(d: bytes) -> bytes:
            head, rows, eol = _split(d, spec)
            head = [spec.sep.join(h.split(spec.sep)[:c] + h.split(spec.sep)[c + 1:])
                    if len(h.split(spec.sep)) > c + 1 else h for h in head]
            rows = [r[:c] + r[c + 1:] for r in rows]
            return _join(head, rows, spec, eol)
        return mutate
    return make


def _rename_col(which: int):
    def make(spec: TextSpec, sub: int) -> Callable[[bytes], bytes]:
        def mutate(d: bytes) -> bytes:
            head, rows, eol = _split(d, spec)
            cells = head[-1].split(spec.sep)
            c = spec.frame_col if spec.frame_col is not None else 0
            if c < len(cells):
                cells[c] = b"Frmae"
            head[-1] = spec.sep.join(cells)
            return _join(head, rows, spec, eol)
        return mutate
    return make


def _header_bytes(seq: bytes):
    def make(spec: TextSpec, sub: int) -> Callable[[bytes], bytes]:
        def mutate(d: bytes) -> bytes:
            head, rows, eol = _split(d, spec)
            i = max(0, spec.header - 1)
            cells = head[i].split(spec.sep) if head else [b""]
            k = spec.value_cols[0] if spec.value_cols[0] < len(cells) else len(cells) - 1
            cells[k] = cells[k][:2] + seq + cells[k][2:]
            if head:
                head[i] = spec.sep.join(cells)
            return _join(head, rows, spec, eol)
        return mutate
    return make


def _flips(spec: TextSpec, sub: int) -> Callable[[bytes], bytes]:
    def mutate(d: bytes) -> bytes:
        rng = np.random.default_rng(sub)
        b = bytearray(d)
        for _ in range(int(rng.integers(1, 12))):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(32, 127))
        return bytes(b)
    return mutate


@functools.cache
def text_specs() -> dict[str, TextSpec]:
    from gazepipe.io.c3d import read_c3d

    n = len(read_c3d(SAMPLE / "mocap" / f"{MOCAP_TAKE}.c3d").labels)
    values = tuple(range(2, 2 + 3 * n))
    of_head = [c.strip() for c in (SAMPLE / "eyes" / f"{FOLLOW_TAKE}.csv").read_text().split("\n", 1)[0].split(",")]
    llf_head = (SAMPLE / "face" / f"{FACE_TAKE}_tracked.csv").read_text().split("\n", 1)[0].split(",")
    return {
        "vicon_csv": TextSpec("vicon_csv", 5, b",", 0, None, values),
        "qtm_tsv": TextSpec("qtm_tsv", 12, b"\t", 0, 1, values),
        "wide_csv": TextSpec("wide_csv", 1, b",", 0, 1, values),
        "openface": TextSpec("openface", 1, b",", 0, of_head.index("timestamp"),
                             tuple(of_head.index(f"gaze_{e}_{a}") for e in (0, 1) for a in "xyz")),
        "livelinkface": TextSpec("livelinkface", 1, b",", None, 0, tuple(range(2, min(len(llf_head), 53))),
                                 timecode=True),
    }


def text_cases(seed: int, reader: str, n: int, bases: dict[str, Path] | None = None) -> list[Case]:
    """``n`` mutations of one text reader's file: the base session's (run or inspect) and, for OpenFace and
    Live Link Face, the real files of the corpus (inspect)."""
    rng = rng_for(seed, reader)
    spec = text_specs()[reader]
    run_base = {"vicon_csv": "vicon_csv", "qtm_tsv": "qtm_tsv", "wide_csv": "wide_csv", "openface": "follow",
                "livelinkface": "face"}[reader]
    target = {"vicon_csv": f"mocap/{MOCAP_TAKE}.csv", "qtm_tsv": f"mocap/{MOCAP_TAKE}.tsv",
              "wide_csv": f"mocap/{MOCAP_TAKE}_wide.csv", "openface": f"eyes/{FOLLOW_TAKE}.csv",
              "livelinkface": f"face/{FACE_TAKE}_tracked.csv"}[reader]
    extra = {"openface": sorted((CORPUS / "openface").glob("*.csv")),
             "livelinkface": sorted((CORPUS / "livelinkface").glob("*.csv"))}.get(reader, [])
    ops = _text_ops(spec)
    order = list(range(len(ops))) + [int(i) for i in rng.permutation(len(ops))] * 3
    cases = []
    for k, i in enumerate(order[:n]):
        name, flag, maker = ops[i]
        apply = bytes_mutation(maker(spec, int(rng.integers(0, 2**31))))
        cid = f"{reader}-{k:03d}"
        if extra and k >= len(ops) and rng.random() < 0.5:
            src = extra[int(rng.integers(0, len(extra)))]
            cases.append(Case(cid, "mutations", reader, name, "inspect", str(src), src.name, apply, flag))
        elif rng.random() < RUN_SHARE[reader]:
            cases.append(Case(cid, "mutations", reader, name, "run", run_base, target, apply, flag))
        else:
            src = (bases or {}).get(run_base, Path("<base>/" + run_base)) / target
            cases.append(Case(cid, "mutations", reader, name, "inspect", str(src), Path(target).name, apply, flag))
    return cases


# ------------------------------------------------------------------------------------------------ TOML

def nested(depth: int, inner: str = "1") -> str:
    return "[" * depth + inner + "]" * depth


def _toml_edit(old: str | None, new: str, count: int = 1) -> Callable[[bytes], bytes]:
    """Replace the first ``count`` occurrences of ``old`` (None: append ``new`` at the end)."""
    def mutate(d: bytes) -> bytes:
        text = d.decode()
        if old is None:
            return (text + "\n" + new + "\n").encode()
        assert old in text, old
        return text.replace(old, new, count).encode()
    return mutate


def session_toml_cases(seed: int, n: int) -> list[Case]:
    rng = rng_for(seed, "session_toml")
    sid = f'id = "{MOCAP_TAKE}"'
    mocap = f'mocap = "mocap/{MOCAP_TAKE}.c3d"'
    pose = 'pose = "standing"'
    long_id = "t" * 300
    ops: list[tuple[str, Callable[[bytes], bytes]]] = [
        ("nested_arrays(5000).top", _toml_edit("schema = 1", "schema = 1\nx = " + nested(5000))),
        ("nested_arrays(5000).take_pose", _toml_edit(pose, "pose = " + nested(5000))),
        ("nested_arrays(20).take_pose", _toml_edit(pose, "pose = " + nested(20))),
        ("nested_tables(3000).inline", _toml_edit(None, "y = " + "{a=" * 3000 + "1" + "}" * 3000)),
        ("take_id.300_chars", _toml_edit(sid, f'id = "{long_id}"')),
        ("take_id.101_chars", _toml_edit(sid, f'id = "{"t" * 101}"')),
        ("session_id.300_chars", _toml_edit('id = "faults"', f'id = "{"s" * 300}"')),
        ("subject.300_chars", _toml_edit('subject = "p01"', f'subject = "{"p" * 300}"')),
        ("take_id.slash", _toml_edit(sid, 'id = "a/b"')),
        ("take_id.dotdot", _toml_edit(sid, 'id = ".."')),
        ("take_id.empty", _toml_edit(sid, 'id = ""')),
        ("take_id.nul", _toml_edit(sid, 'id = "a\\u0000b"')),
        ("take_id.escape_seq", _toml_edit(sid, 'id = "a\\u001b[31mb"')),
        ("take_id.bidi", _toml_edit(sid, 'id = "a\\u202eb"')),
        ("take_id.duplicate", _toml_edit(sid, 'id = "neutral"')),
        ("unknown_key.top", _toml_edit("schema = 1", 'schema = 1\ncolour = "red"')),
        ("unknown_key.session", _toml_edit('subject = "p01"', 'subject = "p01"\nsubjct = "p02"')),
        ("unknown_key.take", _toml_edit(mocap, mocap + '\nmocapp = "x.c3d"')),
        ("type.schema_string", _toml_edit("schema = 1", 'schema = "1"')),
        ("type.schema_2", _toml_edit("schema = 1", "schema = 2")),
        ("type.take_id_int", _toml_edit(sid, "id = 5")),
        ("type.kind_unknown", _toml_edit('kind = "gaze_shift"', 'kind = "dance"')),
        ("type.pose_int", _toml_edit(pose, "pose = 3")),
        ("type.rate_string", _toml_edit(mocap, mocap + '\nrate_hz = "fast"')),
        ("type.rate_nan", _toml_edit(mocap, mocap + "\nrate_hz = nan")),
        ("type.rate_inf", _toml_edit(mocap, mocap + "\nrate_hz = inf")),
        ("type.rate_1e30", _toml_edit(mocap, mocap + "\nrate_hz = 1e30")),
        ("type.rate_negative", _toml_edit(mocap, mocap + "\nrate_hz = -30.0")),
        ("type.target_int", _toml_edit(SHIFT_TARGET, "3")),
        ("type.target_yaw_string", _toml_edit(SHIFT_TARGET, '{ yaw_deg = "x", pitch_deg = 1.0 }')),
        ("type.target_yaw_nan", _toml_edit(SHIFT_TARGET, "{ yaw_deg = nan, pitch_deg = 0.0 }")),
        ("type.target_yaw_1e308", _toml_edit(SHIFT_TARGET, "{ yaw_deg = 1e308, pitch_deg = 0.0 }")),
        ("type.mocap_int", _toml_edit(mocap, "mocap = 42")),
        ("type.mocap_array", _toml_edit(mocap, 'mocap = ["a.c3d"]')),
        ("type.takes_int", lambda d: re.sub(rb"\[\[takes\]\][^\[]*", b"", d).replace(
            b'markerset = "markerset.toml"', b'markerset = "markerset.toml"\n') + b"\ntakes = 5\n"),
        ("path.escape_relative", _toml_edit(mocap, 'mocap = "../../../../../../etc/passwd"')),
        ("path.escape_absolute", _toml_edit(mocap, 'mocap = "/etc/passwd"')),
        ("path.escape_markerset", _toml_edit('markerset = "markerset.toml"', 'markerset = "../markerset.toml"')),
        ("path.dev_zero", _toml_edit(mocap, 'mocap = "/dev/zero"')),
        ("path.markerset_dev_zero", _toml_edit('markerset = "markerset.toml"', 'markerset = "/dev/zero"')),
        ("path.empty", _toml_edit(mocap, 'mocap = ""')),
        ("path.folder", _toml_edit(mocap, 'mocap = "mocap"')),
        ("path.missing_file", _toml_edit(mocap, 'mocap = "mocap/not_there.c3d"')),   # names: not_there.c3d
        ("path.nul", _toml_edit(mocap, 'mocap = "mocap/a\\u0000.c3d"')),
        ("huge_string.2MB", _toml_edit('subject = "p01"', f'subject = "{"p" * 2_000_000}"')),
        ("huge_string.500kB_pose", _toml_edit(pose, f'pose = "{"s" * 500_000}"')),
        ("syntax.unclosed_table", _toml_edit("[session]", "[session")),
        ("syntax.duplicate_key", _toml_edit('subject = "p01"', 'subject = "p01"\nsubject = "p02"')),
        ("syntax.non_utf8", lambda d: d.replace(b"p01", b"p\xff\xfe1", 1)),
        ("syntax.nul_byte", lambda d: d.replace(b"p01", b"p\x001", 1)),
        ("syntax.bom", lambda d: b"\xef\xbb\xbf" + d),
        ("syntax.crlf", lambda d: d.replace(b"\n", b"\r\n")),
        ("syntax.empty", lambda d: b""),
        ("syntax.random_bytes", lambda d: bytes(range(256)) * 4),
        ("syntax.cut_mid_take", lambda d: d[: len(d) - 25]),
        ("structure.no_takes", lambda d: d.split(b"[[takes]]")[0]),
        ("structure.no_subject", _toml_edit('subject = "p01"\n', "")),
        ("structure.no_session_table", lambda d: d.replace(b"[session]", b"", 1)),
        ("structure.take_without_kind", _toml_edit('kind = "gaze_shift"\n', "")),
    ]
    order = list(range(len(ops))) + [int(i) for i in rng.permutation(len(ops))]
    cases = []
    for k, i in enumerate(order[:n]):
        name, fn = ops[i]
        cases.append(Case(f"session_toml-{k:03d}", "mutations", "session_toml", name, "run", "c3d", "session.toml",
                          bytes_mutation(fn), names=("not_there.c3d",) if name == "path.missing_file" else ()))
    return cases


def markerset_toml_cases(seed: int, n: int) -> list[Case]:
    rng = rng_for(seed, "markerset_toml")
    pel = 'markers = ["PEL_L", "PEL_R", "PEL_B"]'
    ops: list[tuple[str, Callable[[bytes], bytes]]] = [
        ("nested_arrays(5000).markers", _toml_edit(pel, "markers = " + nested(5000, '"PEL_L"'))),
        ("nested_arrays(5000).top", _toml_edit("schema = 1", "schema = 1\nz = " + nested(5000))),
        ("unknown_key.top", _toml_edit("schema = 1", 'schema = 1\ncolour = "red"')),
        ("unknown_key.segment", _toml_edit(pel, pel + "\nweight = 3")),
        ("type.markers_string", _toml_edit(pel, 'markers = "PEL_L"')),
        ("type.up_axis_int", _toml_edit('up_axis = "z"', "up_axis = 3")),
        ("type.up_axis_w", _toml_edit('up_axis = "z"', 'up_axis = "w"')),
        ("type.units_furlongs", _toml_edit('units = "mm"', 'units = "furlongs"')),
        ("type.eye_offset_short", _toml_edit("eye_offset_mm = [0.0, -93.0, 105.0]", "eye_offset_mm = [1.0, 2.0]")),
        ("type.eye_offset_nan", _toml_edit("eye_offset_mm = [0.0, -93.0, 105.0]", "eye_offset_mm = [nan, 0.0, 0.0]")),
        ("type.eye_offset_1e308",
         _toml_edit("eye_offset_mm = [0.0, -93.0, 105.0]", "eye_offset_mm = [1e308, 0.0, 0.0]")),
        ("type.clapper_string", _toml_edit('clapper = ["CLAP1", "CLAP2"]', 'clapper = "CLAP1"')),
        ("type.root_int", _toml_edit('root = "SACR"', "root = 5")),
        ("type.schema_2", _toml_edit("schema = 1", "schema = 2")),
        ("parent.missing", _toml_edit('parent = "pelvis"', 'parent = "pelvix"')),
        ("parent.self", _toml_edit('parent = "spine1"', 'parent = "spine2"')),
        ("parent.after_child", _toml_edit('parent = "pelvis"', 'parent = "chest"')),
        ("segment.no_markers", _toml_edit(pel, "markers = []")),
        ("segment.two_markers", _toml_edit(pel, 'markers = ["PEL_L", "PEL_R"]')),
        ("marker.duplicate", _toml_edit(pel, 'markers = ["PEL_L", "PEL_L", "PEL_B"]')),
        ("marker.300_chars", _toml_edit(pel, f'markers = ["{"M" * 300}", "PEL_R", "PEL_B"]')),
        ("marker.nul", _toml_edit(pel, 'markers = ["PEL\\u0000L", "PEL_R", "PEL_B"]')),
        ("marker.escape_seq", _toml_edit(pel, 'markers = ["PEL\\u001b[31mL", "PEL_R", "PEL_B"]')),
        ("marker.not_in_capture", _toml_edit(pel, 'markers = ["PEL_Q", "PEL_R", "PEL_B"]')),
        ("root.not_in_capture", _toml_edit('root = "SACR"', 'root = "SACQ"')),
        ("root.path", _toml_edit('root = "SACR"', 'root = "../../etc/passwd"')),
        ("huge_string.2MB", _toml_edit('root = "SACR"', f'root = "{"R" * 2_000_000}"')),
        ("syntax.unclosed_table", _toml_edit("[segments.pelvis]", "[segments.pelvis")),
        ("syntax.duplicate_table", _toml_edit("[segments.spine1]", "[segments.pelvis]")),
        ("syntax.non_utf8", lambda d: d.replace(b"SACR", b"SA\xffR", 1)),
        ("syntax.empty", lambda d: b""),
        ("syntax.cut", lambda d: d[: len(d) // 3]),
        ("syntax.bom", lambda d: b"\xef\xbb\xbf" + d),
        ("special.missing", None),
        ("special.dir", None),
        ("special.fifo", None),
    ]
    order = list(range(len(ops))) + [int(i) for i in rng.permutation(len(ops))]
    cases = []
    for k, i in enumerate(order[:n]):
        name, fn = ops[i]
        apply = special_mutation(name.split(".", 1)[1]) if fn is None else bytes_mutation(fn)
        # a marker the captures lack is a capture's fault as much as the markerset's: naming either will do
        also = ("neutral.c3d", f"{MOCAP_TAKE}.c3d") if name.endswith("not_in_capture") or name in (
            "root.path", "marker.300_chars") else ()
        cases.append(Case(f"markerset_toml-{k:03d}", "mutations", "markerset_toml", name, "run", "c3d",
                          "markerset.toml", apply, names=also))
    return cases


# ------------------------------------------------------------------------------------------------ video

def video_cases(seed: int, n: int) -> list[Case]:
    rng = rng_for(seed, "video")
    target = f"video/{FOLLOW_TAKE}.mp4"

    def flips(k):
        def fn(d: bytes) -> bytes:
            r = np.random.default_rng([seed, k])
            b = bytearray(d)
            for _ in range(int(r.integers(5, 60))):
                b[int(r.integers(len(b) // 10, len(b)))] = int(r.integers(0, 256))
            return bytes(b)
        return fn

    ops: list[tuple[str, Mutate]] = [
        ("truncate@50%", bytes_mutation(lambda d: d[: len(d) // 2])),
        ("truncate@10%", bytes_mutation(lambda d: d[: len(d) // 10])),
        ("truncate@1%", bytes_mutation(lambda d: d[: len(d) // 100])),
        ("truncate@100B", bytes_mutation(lambda d: d[:100])),
        ("truncate_tail_10%", bytes_mutation(lambda d: d[: len(d) * 9 // 10])),
        ("zero_bytes", special_mutation("empty")),
        ("directory", special_mutation("dir")),
        ("missing", special_mutation("missing")),
        ("fifo", special_mutation("fifo")),
        ("symlink_dev_zero", special_mutation("devzero")),
        ("dangling_symlink", special_mutation("dangling")),
        ("random_bytes_64k", bytes_mutation(lambda d: bytes(np.random.default_rng(seed).integers(
            0, 256, 65536, dtype=np.uint8)))),
        ("text_file", bytes_mutation(lambda d: b"not a video\n" * 100)),
        ("append_junk_1MB", bytes_mutation(lambda d: d + bytes(1 << 20))),
        ("header_zeroed", bytes_mutation(lambda d: bytes(64) + d[64:])),
    ] + [(f"flip_bytes#{k}", bytes_mutation(flips(k))) for k in range(5)]
    order = list(range(len(ops))) + [int(i) for i in rng.permutation(len(ops))]
    return [Case(f"video-{k:03d}", "mutations", "video", ops[i][0], "run", "follow", target, ops[i][1])
            for k, i in enumerate(order[:n])]


# ------------------------------------------------------------------------------------------------ named classes
#
# Classes of bad input with a known right answer, each case expecting an exit status (``Case.expect``): a blank
# line inside a Nexus CSV's data rows (read whole, with a warning), implausible rates in text exports and
# session.toml (refused), implausible C3D scales and text-export spans (refused within 1 mm of the origin,
# warned of beyond 100 m), byte-order marks (UTF-8 read, UTF-16 refused), link loops and other unreadable
# paths as a take's file (that take fails, exit 1), face files of too few rows and videos far shorter than
# their take (the error names that file).


def set_float_param(b: bytearray, group: str, name: str, value: float) -> bool:
    """:func:`set_param` for a float parameter in the file's own float format, DEC included."""
    if c3d_processor(bytes(b)) != "dec":
        return set_param(b, group, name, value)
    _, recs = c3d_records(bytes(b))
    r = c3d_param(recs, group, name)
    if r is None or r.ptype != 4 or r.data_at + 4 > len(b):
        return False
    ieee = struct.pack("<f", value * 4.0)
    b[r.data_at: r.data_at + 4] = ieee[2:4] + ieee[0:2]   # DEC: exponent offset by 2, words swapped
    return True


def _vicon_blank_lines(sub: int) -> Callable[[bytes], bytes]:
    """1-6 runs of 1-3 blank lines (empty, or a lone ``\r``) among a Nexus CSV's data rows, and sometimes a
    Devices block after the Trajectories block (its blank separator must still end the data)."""
    def mutate(d: bytes) -> bytes:
        rng = np.random.default_rng(sub)
        spec = text_specs()["vicon_csv"]
        head, rows, eol = _split(d, spec)
        lines = [spec.sep.join(r) for r in rows]
        for i in sorted(rng.choice(np.arange(1, len(lines)), int(rng.integers(1, 7)), replace=False))[::-1]:
            lines[int(i):int(i)] = [b"\r" if rng.random() < 0.2 else b""] * int(rng.integers(1, 4))
        tail = b""
        if rng.random() < 0.5:
            tail = eol.join([b"", b"Devices", b"1000", b",,Force", b"Frame,Sub Frame,Fx", b",,N", b"1,0,5.0"]) + eol
        return eol.join(head + lines) + eol + tail
    return mutate


#: implausible capture rates (Hz): beyond 10 kHz, below 1 Hz, zero, negative, not finite
BAD_RATES = (1e9, 1e12, 20000.0, 1e30, 0.5, 1e-3, 0.0, -120.0, math.inf, math.nan)


def _bad_rate(rng: np.random.Generator) -> float:
    if rng.random() < 0.5:   # a seeded draw as well as the fixed extremes
        return float(10 ** rng.uniform(4.05, 15)) if rng.random() < 0.5 else float(10 ** rng.uniform(-6, -0.05))
    return float(_pick(rng, BAD_RATES))


def _rate_text(reader: str, rate: float) -> Callable[[bytes], bytes]:
    """A text export of ``reader`` whose rate (Nexus rate line, QTM FREQUENCY, wide CSV time steps) is ``rate``."""
    def mutate(d: bytes) -> bytes:
        if reader == "vicon_csv":
            lines = d.split(b"\n")
            lines[1] = repr(rate).encode()
            return b"\n".join(lines)
        if reader == "qtm_tsv":
            return re.sub(rb"(?m)^FREQUENCY\t[^\t\r\n]*", b"FREQUENCY\t" + repr(rate).encode(), d, count=1)
        spec = text_specs()["wide_csv"]
        head, rows, eol = _split(d, spec)
        step = 1.0 / rate if math.isfinite(rate) and rate > 0 else 1e-9
        for i, r in enumerate(rows):
            r[spec.time_col] = repr(i * step).encode()
        return _join(head, rows, spec, eol)
    return mutate


def _scaled_text(factor: float, units: bytes | None = None) -> Callable[[bytes], bytes]:
    """A Nexus CSV with every coordinate multiplied by ``factor`` (and its units row set to ``units``)."""
    def mutate(d: bytes) -> bytes:
        spec = text_specs()["vicon_csv"]
        head, rows, eol = _split(d, spec)
        for r in rows:
            for c in spec.value_cols:
                if c < len(r) and r[c].strip():
                    r[c] = repr(float(r[c]) * factor).encode()
        if units is not None:
            head[4] = b",," + b",".join([units] * len(spec.value_cols))
        return _join(head, rows, spec, eol)
    return mutate


def _loop(kind: str) -> Mutate:
    """The file replaced by a link loop: to itself, through a second link, or at the end of a long chain."""
    def apply(path: Path) -> None:
        path.unlink(missing_ok=True)
        if kind == "self":
            path.symlink_to(path.name)
        elif kind == "pair":
            other = path.with_name(path.name + ".other")
            other.unlink(missing_ok=True)
            other.symlink_to(path.name)
            path.symlink_to(other.name)
        else:   # a chain of 50 links back to itself: more than the system follows (ELOOP)
            names = [path.name] + [f"{path.name}.{k}" for k in range(1, 50)]
            for a, b in zip(names, names[1:] + names[:1], strict=True):
                link = path.with_name(a)
                link.unlink(missing_ok=True)
                link.symlink_to(b)
    return apply


def _face_rows(keep: int) -> Callable[[bytes], bytes]:
    """A Live Link Face file cut to its header and ``keep`` data rows."""
    def mutate(d: bytes) -> bytes:
        lines = d.split(b"\n")
        return b"\n".join(lines[: 1 + keep]) + b"\n"
    return mutate


def _short_video(frames: int, cut_eyes: bool) -> Mutate:
    """The take's video re-encoded with only its first ``frames`` frames (and, with ``cut_eyes``, the eyes CSV
    cut to the same span, as OpenFace would give for that video)."""
    def apply(path: Path) -> None:
        import cv2

        src = SAMPLE / "video" / path.name
        cap = cv2.VideoCapture(str(src))
        fps = cap.get(cv2.CAP_PROP_FPS) or 60.0
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        tmp = path.with_name("short_" + path.name)
        out = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
        for _ in range(frames):
            ok, frame = cap.read()
            if not ok:
                break
            out.write(frame)
        out.release()
        cap.release()
        path.unlink(missing_ok=True)
        tmp.rename(path)
        if cut_eyes:
            eyes = path.parent.parent / "eyes" / (path.stem + ".csv")
            _replace(eyes, b"".join(eyes.read_bytes().splitlines(keepends=True)[: frames + 1]))
    return apply


def named_cases(seed: int, quota: dict[str, int], bases: dict[str, Path] | None = None) -> list[Case]:  # noqa: C901
    """The named classes' cases (``quota``: cases per class), seeded: the same seed gives the same cases."""
    b = bases or {}

    def src(name: str, rel: str) -> str:
        return str(b.get(name, Path("<base>/" + name)) / rel)

    vicon, qtm, wide = (RUN_TARGET[r][1] for r in ("vicon_csv", "qtm_tsv", "wide_csv"))
    cases: list[Case] = []

    def add(cls: str, k: int, mutation: str, mode: str, base: str, target: str, apply: Mutate, *,
            flag: bool = False, expect: tuple[int, ...] | None = None, names: tuple[str, ...] = ()) -> None:
        cases.append(Case(f"{cls}-{k:03d}", "mutations", cls, mutation, mode, base, target, apply, flag,
                          expect=expect, names=names))

    # 1. blank lines inside a Nexus CSV's data rows: read whole (exit 0) with a warning naming the file
    rng = rng_for(seed, "blank_lines")
    for k in range(quota["blank_lines"]):
        sub = int(rng.integers(0, 2**31))
        apply = bytes_mutation(_vicon_blank_lines(sub))
        if rng.random() < 0.4:
            add("blank_lines", k, f"vicon.blank_lines#{sub % 1000}", "run", "vicon_csv", vicon, apply, flag=True,
                expect=(0,))
        else:
            add("blank_lines", k, f"vicon.blank_lines#{sub % 1000}", "inspect", src("vicon_csv", vicon),
                Path(vicon).name, apply, flag=True, expect=(0,))

    # 2. implausible rates: a text export's (its take fails, exit 1) or session.toml's (exit 2)
    rng = rng_for(seed, "rates")
    for k in range(quota["rates"]):
        rate = _bad_rate(rng)
        where = _pick(rng, ("vicon_csv", "qtm_tsv", "wide_csv", "session_toml"))
        if where == "session_toml":
            apply = bytes_mutation(_toml_edit("rate_hz = 30", f"rate_hz = {_toml_float(rate)}"))
            add("rates", k, f"session_toml.rate_hz={rate:.6g}", "run", "face", "session.toml", apply, expect=(2,))
            continue
        base, target = RUN_TARGET[where]
        apply = bytes_mutation(_rate_text(where, rate))
        if rng.random() < 0.4:
            add("rates", k, f"{where}.rate={rate:.6g}", "run", base, target, apply, expect=(1,))
        else:
            add("rates", k, f"{where}.rate={rate:.6g}", "inspect", src(base, target), Path(target).name, apply,
                expect=(1,))

    # 3. implausible scales: an integer C3D's POINT:SCALE (refused when tiny, warned of when huge), a Nexus
    #    CSV's values (refused within 1 mm of the origin) or units (warned of over 100 m)
    rng = rng_for(seed, "scales")
    ints = [CORPUS / "c3d" / n for n in ("Eb015pi.c3d", "ART-Human_2persons_integer.c3d", "Eb015si.c3d",
                                         "Eb015vi.c3d", "gait-raw.c3d")]
    for k in range(quota["scales"]):
        what = _pick(rng, ("c3d.tiny", "c3d.tiny", "c3d.huge", "vicon.tiny", "vicon.metres"))
        if what.startswith("c3d"):
            f = _pick(rng, ints)
            scale = float(10 ** rng.uniform(-38, -6)) if what == "c3d.tiny" else float(10 ** rng.uniform(2.5, 4))

            def edit(b: bytearray, rng: np.random.Generator, scale: float = scale) -> None:
                set_float_param(b, "POINT", "SCALE", scale)
            apply = bytes_mutation(lambda d, edit=edit: _edited(d, edit, 0))
            add("scales", k, f"POINT:SCALE={scale:.3g}", "inspect", str(f), f.name, apply,
                flag=what == "c3d.huge", expect=(1,) if what == "c3d.tiny" else None)
        elif what == "vicon.tiny":
            factor = float(10 ** rng.uniform(-30, -4))
            mode = "run" if rng.random() < 0.4 else "inspect"
            add("scales", k, f"vicon.values*{factor:.3g}", mode, "vicon_csv" if mode == "run" else
                src("vicon_csv", vicon), vicon if mode == "run" else Path(vicon).name,
                bytes_mutation(_scaled_text(factor)), expect=(1,))
        else:   # millimetres labelled metres, scaled so that they stay within 1 km but span over 100 m
            factor = float(10 ** rng.uniform(-0.85, -0.3))   # the base take spans 0.8 m, reaches 1.8 m
            add("scales", k, f"vicon.values*{factor:.3g}.units=m", "inspect", src("vicon_csv", vicon),
                Path(vicon).name, bytes_mutation(_scaled_text(factor, b"m")), flag=True)

    # 4. byte-order marks: UTF-8 read (exit 0), UTF-16 refused with a line naming the file (exit 1)
    rng = rng_for(seed, "bom")
    for k in range(quota["bom"]):
        reader = _pick(rng, ("vicon_csv", "vicon_csv", "qtm_tsv", "wide_csv"))
        base, target = RUN_TARGET[reader]
        enc = _pick(rng, ("utf-8-sig", "utf-8-sig", "utf-16", "utf-16-le", "utf-16-be"))
        crlf = bool(rng.random() < 0.3)

        def encode(d: bytes, enc: str = enc, crlf: bool = crlf) -> bytes:
            text = d.decode("utf-8").replace("\n", "\r\n") if crlf else d.decode("utf-8")
            return ("\ufeff" + text).encode(enc) if enc in ("utf-16-le", "utf-16-be") else text.encode(enc)
        expect = (0,) if enc == "utf-8-sig" else (1,)
        mutation = f"{reader}.bom={enc}{'.crlf' if crlf else ''}"
        if rng.random() < 0.4:
            add("bom", k, mutation, "run", base, target, bytes_mutation(encode), expect=expect)
        else:
            add("bom", k, mutation, "inspect", src(base, target), Path(target).name, bytes_mutation(encode),
                expect=expect)

    # 5. a take's file a link loop: that take fails (exit 1), the error naming the file
    rng = rng_for(seed, "link_loops")
    targets = [("c3d", RUN_TARGET["c3d"][1]), ("c3d", "mocap/neutral.c3d"), ("vicon_csv", vicon),
               ("follow", f"eyes/{FOLLOW_TAKE}.csv"), ("follow", f"video/{FOLLOW_TAKE}.mp4"),
               ("face", f"face/{FACE_TAKE}_tracked.csv"), ("face", f"face/{FACE_TAKE}_clean.csv")]
    for k in range(quota["link_loops"]):
        base, target = targets[k % len(targets)] if k < len(targets) else _pick(rng, targets)
        kind = _pick(rng, ("self", "pair", "chain"))
        add("link_loops", k, f"link_loop.{kind}", "run", base, target, _loop(kind), expect=(1,))

    # 6. errors that must name their file: a face file of 0-2 rows, a video far shorter than its take
    rng = rng_for(seed, "named_files")
    for k in range(quota["named_files"]):
        if rng.random() < 0.5:
            target = f"face/{FACE_TAKE}_{_pick(rng, ('tracked', 'clean'))}.csv"
            keep = int(rng.integers(0, 2))
            add("named_files", k, f"face.rows={keep}", "run", "face", target, bytes_mutation(_face_rows(keep)),
                expect=(1,))
        else:
            frames = int(rng.integers(60, 400))
            cut = bool(rng.random() < 0.6)
            add("named_files", k, f"video.frames={frames}{'+eyes' if cut else ''}", "run", "follow",
                f"video/{FOLLOW_TAKE}.mp4", _short_video(frames, cut), flag=True)
    return cases


def _toml_float(v: float) -> str:
    return "nan" if math.isnan(v) else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))


#: the base session and file each reader's run cases mutate
RUN_TARGET = {"c3d": ("c3d", f"mocap/{MOCAP_TAKE}.c3d"), "vicon_csv": ("vicon_csv", f"mocap/{MOCAP_TAKE}.csv"),
              "qtm_tsv": ("qtm_tsv", f"mocap/{MOCAP_TAKE}.tsv"),
              "wide_csv": ("wide_csv", f"mocap/{MOCAP_TAKE}_wide.csv"),
              "openface": ("follow", f"eyes/{FOLLOW_TAKE}.csv"),
              "livelinkface": ("face", f"face/{FACE_TAKE}_tracked.csv")}


def with_mode(case: Case, mode: str, bases: dict[str, Path]) -> Case:
    """The same mutation of the same file through ``gazepipe run`` or ``gazepipe inspect`` (only for a case
    made from the base session's file, not from a corpus file)."""
    if case.mode == mode:
        return case
    base, target = RUN_TARGET[case.reader]
    if mode == "run":
        if Path(case.base).name != Path(target).name:
            raise ValueError(f"{case.id} mutates {case.base}, not a base session's file")
        return dataclasses.replace(case, id=f"{case.id}-run", mode="run", base=base, target=target)
    return dataclasses.replace(case, id=f"{case.id}-inspect", mode="inspect",
                               base=str(bases[case.base] / case.target), target=Path(case.target).name)


def mutation_cases(seed: int, bases: dict[str, Path] | None = None, quota: dict[str, int] | None = None) -> list[Case]:
    """Every mutation case, in a fixed order for a seed (``bases``: the base sessions, for the paths of
    inspect cases made from their files)."""
    q = dict(QUOTA, **(quota or {}))
    cases = c3d_cases(seed, q["c3d"])
    for reader in ("vicon_csv", "qtm_tsv", "wide_csv", "openface", "livelinkface"):
        cases += text_cases(seed, reader, q[reader], bases)
    cases += session_toml_cases(seed, q["session_toml"])
    cases += markerset_toml_cases(seed, q["markerset_toml"])
    cases += video_cases(seed, q["video"])
    cases += named_cases(seed, q, bases)
    return cases


# ------------------------------------------------------------------------------------------------ bombs

def bomb_cases(seed: int, bases: dict[str, Path] | None = None) -> list[Case]:
    """Inputs that would exhaust memory or time if a reader trusted them: each must be refused (exit 1 or 2)
    within 10 s with peak memory under 1 GB (the well-formed large C3D must be read, in bounded memory)."""
    big = 10**8

    def claim_2m(path: Path) -> None:
        path.unlink(missing_ok=True)
        write_c3d_float(path, 35, 200, rate_hz=29.97, claim_frames=2_140_000)

    def honest(n_points: int):
        def apply(path: Path) -> None:
            path.unlink(missing_ok=True)
            write_c3d_float(path, n_points, 2_140_000, rate_hz=120.0, frames_written=1000)
        return apply

    def points_65535(d: bytes) -> bytes:
        b = bytearray(d)
        set_header(b, "points", 65535)
        set_header(b, "last", 65535)
        set_param(b, "POINT", "USED", 65535)
        return bytes(b)

    def huge_line(spec_name: str, header: bool):
        spec = text_specs()[spec_name]

        def fn(d: bytes) -> bytes:
            head, rows, eol = _split(d, spec)
            blob = (b"x" if header else b"1") * big
            if header:
                head[-1] = head[-1] + spec.sep + blob
            else:
                rows[len(rows) // 2][spec.value_cols[0]] = blob
            return _join(head, rows, spec, eol)
        return fn

    def one_line_file(d: bytes) -> bytes:
        return b"1," * (big // 2)

    def huge_toml(key: str):
        def fn(d: bytes) -> bytes:
            return d.replace(f'{key} = "'.encode(), f'{key} = "'.encode() + b"a" * big, 1)
        return fn

    def many_takes(d: bytes) -> bytes:   # a 100 MB session.toml of valid takes
        take = d.split(b"[[takes]]")[1]
        return d + b"".join(b"[[takes]]" + take.replace(b'id = "neutral"', f'id = "t{i}"'.encode(), 1)
                            for i in range(big // len(take)))

    b = bases or {}

    def src(name: str, rel: str) -> str:
        return str(b.get(name, Path("<base>/" + name)) / rel)

    def case(k, reader, mutation, mode, base, target, apply, limit=BOMB_REFUSAL_S, refuse=True, timeout=30.0):
        return Case(f"bomb-{k:02d}", "bombs", reader, mutation, mode, base, target, apply, refuse=refuse,
                    limit_s=limit, timeout_s=timeout)

    shift = f"mocap/{MOCAP_TAKE}.c3d"
    cases = [
        case(0, "c3d", "header_claims_2140000_frames(small_file)", "inspect", src("c3d", shift), "claim.c3d",
             claim_2m),
        case(1, "c3d", "header_claims_2140000_frames(small_file)", "run", "c3d", shift, claim_2m),
        case(2, "c3d", "header_65535_points_65535_frames", "inspect", src("c3d", shift), "points.c3d",
             bytes_mutation(points_65535)),
        case(3, "c3d", "well_formed_2140000_frames_8_points(274MB_sparse)", "inspect", src("c3d", shift),
             "honest.c3d", honest(8), limit=None, refuse=False, timeout=120.0),
        case(15, "c3d", "well_formed_2140000_frames_29_points(993MB_sparse)", "inspect", src("c3d", shift),
             "honest_1gb.c3d", honest(29), limit=None, refuse=False, timeout=180.0),
        case(4, "vicon_csv", "row_of_1e8_chars", "inspect", src("vicon_csv", f"mocap/{MOCAP_TAKE}.csv"),
             "vicon.csv", bytes_mutation(huge_line("vicon_csv", False))),
        case(5, "vicon_csv", "row_of_1e8_chars", "run", "vicon_csv", f"mocap/{MOCAP_TAKE}.csv",
             bytes_mutation(huge_line("vicon_csv", False))),
        case(6, "qtm_tsv", "row_of_1e8_chars", "inspect", src("qtm_tsv", f"mocap/{MOCAP_TAKE}.tsv"), "qtm.tsv",
             bytes_mutation(huge_line("qtm_tsv", False))),
        case(7, "wide_csv", "header_of_1e8_chars", "inspect", src("wide_csv", f"mocap/{MOCAP_TAKE}_wide.csv"),
             "wide.csv", bytes_mutation(huge_line("wide_csv", True))),
        case(8, "wide_csv", "one_line_file_of_1e8_chars", "inspect",
             src("wide_csv", f"mocap/{MOCAP_TAKE}_wide.csv"), "oneline.csv", bytes_mutation(one_line_file)),
        case(9, "openface", "row_of_1e8_chars", "inspect", src("follow", f"eyes/{FOLLOW_TAKE}.csv"), "of.csv",
             bytes_mutation(huge_line("openface", False))),
        case(10, "livelinkface", "row_of_1e8_chars", "inspect", src("face", f"face/{FACE_TAKE}_tracked.csv"),
             "llf.csv", bytes_mutation(huge_line("livelinkface", False))),
        case(11, "livelinkface", "row_of_1e8_chars", "run", "face", f"face/{FACE_TAKE}_tracked.csv",
             bytes_mutation(huge_line("livelinkface", False))),
        case(12, "session_toml", "string_of_1e8_chars", "run", "c3d", "session.toml",
             bytes_mutation(huge_toml("subject"))),
        case(13, "session_toml", "100MB_of_takes", "run", "c3d", "session.toml", bytes_mutation(many_takes)),
        case(14, "markerset_toml", "string_of_1e8_chars", "run", "c3d", "markerset.toml",
             bytes_mutation(huge_toml("root"))),
    ]
    return cases


# ================================================================================================ running

@dataclasses.dataclass
class Outcome:
    case_id: str
    family: str
    reader: str
    mutation: str
    mode: str
    file: str
    exit: int | None
    seconds: float
    peak_mb: float
    problems: list[tuple[str, str]]
    first_line: str

    @property
    def ok(self) -> bool:
        return not self.problems


def session_processes(sid: int) -> list[int]:
    """Live (not zombie) processes whose session id is ``sid`` (``/proc/PID/stat`` field 6)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[3]) == sid and fields[0] != "Z":
            out.append(int(d.name))
    return out


def _cmdline(pid: int) -> str:
    try:
        return (Path("/proc") / str(pid) / "cmdline").read_bytes().replace(b"\x00", b" ").decode()[:120].strip()
    except OSError:
        return "?"


class TreeSampler:
    """Peak summed resident memory (KiB) of a process and its descendants, sampled every 50 ms."""

    def __init__(self, pid: int) -> None:
        self.pid, self.peak_kb = pid, 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, daemon=True)
        self._t.start()

    def _loop(self) -> None:
        import psutil

        try:
            root = psutil.Process(self.pid)
        except psutil.Error:
            return
        while not self._stop.is_set():
            total = 0
            try:
                procs = [root, *root.children(recursive=True)]
            except psutil.Error:
                break
            for p in procs:
                try:
                    total += p.memory_info().rss // 1024
                except psutil.Error:
                    pass
            self.peak_kb = max(self.peak_kb, total)
            self._stop.wait(0.05)

    def stop(self) -> int:
        self._stop.set()
        self._t.join(timeout=1)
        return self.peak_kb


#: runs ``argv[2:]`` as a child forked from this small process and writes "exit maxrss_kb" to ``argv[1]``.
#: A process forked from the (large) bench inherits the bench's resident set as its high-water mark, which
#: ``ru_maxrss`` keeps through ``exec``; a child of this launcher starts from the launcher's few MB, so its
#: ``ru_maxrss`` is its own peak (and that of the children it waited for).
_LAUNCHER = r"""
import os, resource, sys
resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
pid = os.fork()
if pid == 0:
    try:
        os.execv(sys.argv[2], sys.argv[2:])
    finally:
        os._exit(127)
_, status, ru = os.wait4(pid, 0)
with open(sys.argv[1], "w") as fh:
    fh.write("%d %d" % (os.waitstatus_to_exitcode(status), ru.ru_maxrss))
"""


def run_command(cmd: list[str], cwd: Path, timeout_s: float, sample_tree: bool = False) -> dict:
    """Run ``cmd`` (through :data:`_LAUNCHER`) in a session of its own, stdout and stderr to files; kill its
    group at the timeout. Returns exit (negative: a signal), seconds, peak_kb (the command's ``ru_maxrss``, or
    the resident memory of its process tree sampled every 50 ms when ``sample_tree`` and larger), timed_out,
    stdout, stderr."""
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONDONTWRITEBYTECODE="1")
    env.pop("GAZEPIPE_DEBUG", None)
    status_file = cwd / "exit.txt"
    status_file.unlink(missing_ok=True)
    with open(cwd / "stdout.txt", "wb") as out, open(cwd / "stderr.txt", "wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-S", "-c", _LAUNCHER, str(status_file), *cmd], cwd=cwd,
                                stdout=out, stderr=err, stdin=subprocess.DEVNULL, start_new_session=True, env=env)
        sampler = TreeSampler(proc.pid) if sample_tree else None
        timed_out = False
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            timed_out = True
        seconds = time.perf_counter() - t0
        try:   # nothing of the case may outlive it (and a hung case is stopped here)
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        proc.wait()
    peak, code = 0, proc.returncode
    try:
        code_s, peak_s = status_file.read_text().split()
        code, peak = int(code_s), int(peak_s)
    except (OSError, ValueError):
        pass
    if sampler is not None:
        peak = max(peak, sampler.stop())
    return {"exit": code, "seconds": seconds, "peak_kb": peak, "timed_out": timed_out,
            "stdout": (cwd / "stdout.txt").read_bytes().decode("utf-8", "replace"),
            "stderr": (cwd / "stderr.txt").read_bytes().decode("utf-8", "replace")}


def prepare(case: Case, bases: dict[str, Path], folder: Path) -> tuple[list[str], Path]:
    """Make the case's input under ``folder``; return its command and the mutated file's path."""
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    if case.mode == "run":
        session = folder / "s"
        shutil.copytree(bases[case.base], session, copy_function=os.link)
        target = session / case.target
        case.apply(target)
        cmd = [sys.executable, "-m", "gazepipe", "run", str(session), "--out", str(folder / "out"),
               "--log-format", "json", "--executor", "serial"]
        return cmd, target
    target = folder / case.target
    src = Path(case.base)
    if src.is_file():
        os.link(src, target)
    case.apply(target)
    return [sys.executable, "-m", "gazepipe", "inspect", str(target)], target


def _events(text: str) -> tuple[list[dict], list[str]]:
    events, stray = [], []
    for line in text.splitlines():
        if not line.strip():
            continue
        try:
            ev = json.loads(line)
        except ValueError:
            stray.append(line)
            continue
        if isinstance(ev, dict):
            events.append(ev)
        else:
            stray.append(line)
    return events, stray


def _clip(s: str, n: int = 200) -> str:
    s = s.encode("unicode_escape").decode("ascii") if _UNCLEAN.search(s) else s
    return s if len(s) <= n else s[: n - 3] + "..."


def _names(msg: str, target: Path, folder: Path, also: tuple[str, ...] = ()) -> bool:
    """Whether an error line names the file: its name, or its path (absolute or relative to the case), or
    one of the ``also`` names."""
    rel = str(target.relative_to(folder)) if target.is_relative_to(folder) else str(target)
    return target.name in msg or rel in msg or str(target) in msg or any(a in msg for a in also)


#: warnings whose counts are the news (dropped frames): compared as they are, the others with numbers masked
#: (a count of rows or samples that a mutation shifts is no report of the mutation)
_COUNTED = re.compile(r"dropped|without a row|gap\(s\)")


def _normal(msg: str, folder: Path) -> str:
    msg = msg.replace(str(folder), "<CASE>")
    return msg if _COUNTED.search(msg) else re.sub(r"\d+(\.\d+)?(e[-+]?\d+)?", "#", msg)


def _inspect_warnings(stdout: str) -> list[str]:
    """What ``inspect`` reports beyond its facts: warning lines, and clauses of the summary that count
    dropped frames."""
    out = []
    for ln in stdout.splitlines():
        ln = ln.strip()
        if ln.startswith("warning"):
            out.append(ln)
        else:
            out += [part.strip() for part in ln.split(",") if _COUNTED.search(part)]
    return out


def classify(case: Case, res: dict, target: Path, folder: Path, baseline: set[str] | None) -> Outcome:  # noqa: C901
    """Turn a finished command into an :class:`Outcome` (see the module docstring for the problems)."""
    problems: list[tuple[str, str]] = []
    out, err, rc = res["stdout"], res["stderr"], res["exit"]
    text = out + err
    errors: list[str] = []
    warnings: list[str] = []
    if case.mode == "run":
        events, stray = _events(err + "\n" + out)
        # a configuration error refused before the run starts is a plain "error: ..." line, as on a terminal
        plain = [s for s in stray if s.startswith("error: ")]
        stray = [s for s in stray if not s.startswith("error: ")]
        errors += [s[len("error: "):] for s in plain]
        for ev in events:
            msg = str(ev.get("message", ""))
            if ev.get("traceback"):
                problems.append(("crash", f"traceback in the JSON log: {_clip(str(ev['traceback']).strip().splitlines()[-1] if str(ev['traceback']).strip() else '')}"))
            if ev.get("level") == "error" and ev.get("event") != "run_end":
                errors.append(msg)
            elif ev.get("level") == "warning":
                warnings.append(msg)
        if stray:
            if any("Traceback (most recent call last)" in s for s in stray):
                problems.append(("crash", "Python traceback in the output"))
            else:
                native = " (native library output)" if stray[0].startswith("[") else ""
                problems.append(("multiline", f"{len(stray)} line(s) not JSON events{native}: {_clip(stray[0])}"))
        unclean = [e for e in errors + warnings if _UNCLEAN.search(e)]
        if unclean:
            problems.append(("multiline", f"control bytes or line breaks in a message: {_clip(unclean[0])}"))
        if events and events[-1].get("event") != "run_end" and rc in (0, 1) and not res["timed_out"]:
            problems.append(("multiline", f"the log does not end with the run's summary: {_clip(events[-1].get('message', ''))}"))
    else:
        err_lines = [ln for ln in err.splitlines() if ln.strip()]
        errors = [ln for ln in err_lines if ln.startswith("error:")]
        warnings = _inspect_warnings(out) + [ln for ln in err_lines if not ln.startswith("error:")]
        if "Traceback (most recent call last)" in text:
            problems.append(("crash", "Python traceback in the output"))
        elif rc != 0 and len(err_lines) > 1:
            problems.append(("multiline", f"{len(err_lines)} lines on stderr: {_clip(err_lines[1])}"))
        bad = [ln for ln in text.splitlines() if _UNCLEAN.search(ln.replace("\t", " "))]
        if bad:
            problems.append(("multiline", f"control bytes in an output line: {_clip(bad[0])}"))
    if res["timed_out"]:
        problems.append(("hang", f"no exit in {res['seconds']:.0f} s"))
    elif rc not in OK_EXITS:
        problems.append(("crash", f"exit {rc}" + (f" (signal {-rc})" if rc < 0 else "")))
    if case.expect is not None and not res["timed_out"] and rc not in case.expect:
        problems.append(("exit", f"exit {rc}, the case calls for {' or '.join(str(c) for c in case.expect)}"))
    if case.limit_s is not None and not res["timed_out"] and res["seconds"] > case.limit_s:
        problems.append(("hang", f"took {res['seconds']:.1f} s (limit {case.limit_s:g} s)"))
    if re.search(r"internal error", text, re.I):
        line = next(ln for ln in text.splitlines() if re.search(r"internal error", ln, re.I))
        problems.append(("internal", _clip(line)))
    if rc in (1, 2) and not res["timed_out"]:
        if not errors:
            problems.append(("unnamed", f"exit {rc} without an error line"))
        else:
            unnamed = [e for e in errors if not _names(e, target, folder, case.names)]
            if unnamed:
                problems.append(("unnamed", f"{len(unnamed)} of {len(errors)} error line(s) do not name "
                                            f"{case.file_name}: {_clip(unnamed[0])}"))
    if rc == 0 and (case.flag or case.refuse):
        new = [w for w in warnings if _normal(w, folder) not in (baseline or set())]
        mine = [w for w in new if case.mode == "inspect" or _names(w, target, folder, case.names)]
        if case.refuse:
            problems.append(("silent", "accepted (exit 0)" + (f"; warnings: {_clip(new[0])}" if new else "")))
        elif new and not mine:
            problems.append(("unnamed", f"exit 0, warned without naming the file: {_clip(new[0])}"))
        elif not new:
            problems.append(("silent", "exit 0 and no new warning"))
    if res["peak_kb"] > MEM_LIMIT_KB:
        problems.append(("mem", f"peak {res['peak_kb'] / 1024:.0f} MB"))
    first = (errors or [ln for ln in (err + out).splitlines() if ln.strip()] or [""])[0]
    if case.mode == "run" and not errors:
        evs, _ = _events(err)
        first = evs[-1].get("message", first) if evs else first
    seen: set = set()
    problems = [p for p in problems if not (p in seen or seen.add(p))]
    return Outcome(case.id, case.family, case.reader, case.mutation, case.mode, case.target, rc,
                   round(res["seconds"], 2), round(res["peak_kb"] / 1024, 1), problems, _clip(first, 240))


class Runner:
    """Runs cases against the base sessions in ``work``, keeping the unmutated inputs' warnings as
    baselines (computed once, on demand)."""

    def __init__(self, work: Path, bases: dict[str, Path] | None = None) -> None:
        self.work = work
        self.bases = bases if bases is not None else build_bases(work / "bases")
        self._baselines: dict[tuple[str, str], set[str]] = {}
        self._lock = threading.Lock()
        self._key_locks: dict[tuple[str, str], threading.Lock] = {}

    def baseline(self, case: Case) -> set[str]:
        """Normalised warnings the unmutated input gives (run: the base session; inspect: the source file)."""
        key = (case.mode, case.base)
        with self._lock:
            lock = self._key_locks.setdefault(key, threading.Lock())
        with lock:
            if key not in self._baselines:
                folder = self.work / "baselines" / re.sub(r"[^A-Za-z0-9_.-]", "_", f"{case.mode}_{case.base}")[-80:]
                ref = dataclasses.replace(case, apply=lambda p: None, flag=False, refuse=False)
                cmd, target = prepare(ref, self.bases, folder)
                res = run_command(cmd, folder, RUN_TIMEOUT_S)
                if case.mode == "run":
                    events, _ = _events(res["stderr"])
                    ws = [str(e.get("message", "")) for e in events if e.get("level") == "warning"]
                else:
                    ws = _inspect_warnings(res["stdout"])
                self._baselines[key] = {_normal(w, folder) for w in ws}
            return self._baselines[key]

    def run(self, case: Case, keep: bool = False) -> Outcome:
        folder = self.work / "cases" / case.id
        cmd, target = prepare(case, self.bases, folder)
        timeout = case.timeout_s or (RUN_TIMEOUT_S if case.mode == "run" else INSPECT_TIMEOUT_S)
        res = run_command(cmd, folder, timeout)
        baseline = self.baseline(case) if case.flag and res["exit"] == 0 else None
        outcome = classify(case, res, target, folder, baseline)
        if not keep:
            for p in folder.iterdir():
                if p.name not in ("stdout.txt", "stderr.txt", "exit.txt") or outcome.ok:
                    if p.is_dir() and not p.is_symlink():
                        shutil.rmtree(p, ignore_errors=True)
                    else:
                        p.unlink(missing_ok=True)
            if outcome.ok:
                shutil.rmtree(folder, ignore_errors=True)
            else:
                (folder / "case.json").write_text(json.dumps(dataclasses.asdict(outcome), indent=1))
        return outcome


def run_cases(runner: Runner, cases: list[Case], jobs: int, progress: bool = True) -> list[Outcome]:
    done = 0
    lock = threading.Lock()
    t0 = time.perf_counter()

    def one(case: Case) -> Outcome:
        nonlocal done
        out = runner.run(case)
        with lock:
            done += 1
            if progress and (done % 50 == 0 or done == len(cases)):
                print(f"  {done}/{len(cases)} cases, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        return out

    with ThreadPoolExecutor(max_workers=max(1, jobs)) as ex:
        return list(ex.map(one, cases))


# ================================================================================================ kills

def _digest(out: Path) -> dict[str, str]:
    """sha256 of every file under OUT outside OUT/.gazepipe (the run's records, logs and temporaries)."""
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and ".gazepipe" not in p.relative_to(out).parts}


def _run_cmd(session: Path, out: Path, executor: str = "process") -> list[str]:
    cmd = [sys.executable, "-m", "gazepipe", "run", str(session), "--out", str(out), "--log-format", "json",
           "--executor", executor]
    return cmd + (["-j", "2"] if executor != "serial" else [])


def kill_family(seed: int, work: Path, bases: dict[str, Path], trials: int = KILL_TRIALS) -> list[Outcome]:  # noqa: C901
    """SIGKILL ``trials`` process-executor runs at seeded random moments (half the leader only, half its
    group), check for orphans 2 s later, rerun, compare with the reference run's bytes."""
    rng = rng_for(seed, "kills")
    session = bases["kills"]
    root = work / "kills"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    ref_out = root / "reference"
    ref = run_command(_run_cmd(session, ref_out), root, 300.0, sample_tree=True)
    ref_digest = _digest(ref_out)
    outcomes = []
    if ref["exit"] != 0 or not ref_digest:
        first = (ref["stderr"].strip().splitlines() or [""])[-1]
        return [Outcome("kill-ref", "kills", "run", "reference run", "run", str(session), ref["exit"],
                        round(ref["seconds"], 2), round(ref["peak_kb"] / 1024, 1),
                        [("crash", f"the reference run failed (exit {ref['exit']})")], _clip(first))]
    modes = ["leader"] * (trials // 2) + ["group"] * (trials - trials // 2)
    modes = [modes[i] for i in rng.permutation(trials)]
    for k, mode in enumerate(modes):
        delay = float(rng.uniform(0.3, max(0.6, 0.95 * ref["seconds"])))
        out = root / f"out_{k:02d}"
        shutil.rmtree(out, ignore_errors=True)
        problems: list[tuple[str, str]] = []
        env = dict(os.environ, PYTHONPATH=str(REPO))
        with open(root / f"kill_{k:02d}.log", "wb") as log:
            t0 = time.perf_counter()
            proc = subprocess.Popen(_run_cmd(session, out), stdout=log, stderr=log, stdin=subprocess.DEVNULL,
                                    start_new_session=True, env=env)
            sampler = TreeSampler(proc.pid)
            while proc.poll() is None and time.perf_counter() - t0 < delay:
                time.sleep(0.01)
            ended_first = proc.poll() is not None
            helpers = [p for p in session_processes(proc.pid) if p != proc.pid]
            try:
                (os.kill if mode == "leader" else os.killpg)(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            killed_at = time.perf_counter()
            proc.wait(timeout=30)
            while session_processes(proc.pid) and time.perf_counter() - killed_at < ORPHAN_GRACE_S:
                time.sleep(0.05)
            left = session_processes(proc.pid)
            peak = sampler.stop()
            if left:
                problems.append(("orphan", f"{len(left)} process(es) alive {ORPHAN_GRACE_S:g} s after the kill: "
                                           + "; ".join(_cmdline(p) for p in left[:3])))
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                time.sleep(0.2)
        after = _digest(out) if out.exists() else {}
        wrong = [rel for rel, h in after.items() if ref_digest.get(rel) != h]
        if wrong:
            problems.append(("differs", f"{len(wrong)} file(s) left by the kill are not the reference's: {wrong[0]}"))
        rerun_dir = root / f"rerun_{k:02d}"
        rerun_dir.mkdir(exist_ok=True)
        res = run_command(_run_cmd(session, out), rerun_dir, 300.0, sample_tree=True)
        events, stray = _events(res["stderr"])
        if res["timed_out"]:
            problems.append(("hang", "the rerun did not finish in 300 s"))
        elif res["exit"] != 0:
            msg = next((e.get("message", "") for e in events if e.get("level") == "error"), res["stderr"][-200:])
            problems.append(("crash" if res["exit"] not in OK_EXITS else "differs",
                             f"the rerun exited {res['exit']}: {_clip(msg)}"))
        if re.search("internal error", res["stderr"], re.I):
            problems.append(("internal", "internal error in the rerun"))
        if any(e.get("traceback") for e in events) or stray:
            problems.append(("multiline", "traceback or stray lines in the rerun's log"))
        digest = _digest(out)
        if res["exit"] == 0 and digest != ref_digest:
            diff = sorted(set(digest) ^ set(ref_digest)) or [r for r in digest if digest[r] != ref_digest[r]]
            problems.append(("differs", f"rerun outputs differ from the reference: {len(diff)} file(s), e.g. {diff[0]}"))
        peak = max(peak, res["peak_kb"])
        if peak > MEM_LIMIT_KB:
            problems.append(("mem", f"peak {peak / 1024:.0f} MB"))
        where = ("the run ended before the kill" if ended_first else
                 f"killed ({mode}) {delay:.2f} s in, {len(helpers)} helper process(es)")
        outcomes.append(Outcome(f"kill-{k:02d}", "kills", "run", f"sigkill.{mode}@{delay:.2f}s", "run", str(out),
                                res["exit"], round(killed_at - t0, 2), round(peak / 1024, 1), problems, where))
        if not problems:
            shutil.rmtree(out, ignore_errors=True)
            shutil.rmtree(rerun_dir, ignore_errors=True)
            (root / f"kill_{k:02d}.log").unlink(missing_ok=True)
    return outcomes


# ================================================================================================ full disk

#: (tmpfs size in MB, MB left free by a filler file beside OUT or None, executor): the small-session run
#: (about 3 MB of outputs) hits the full disk at different moments: take files, datasets, the QC report
DISK_CASES = ((2, None, "serial"), (2, None, "process"), (20, None, "serial"), (20, 0.4, "process"),
              (20, 1.2, "serial"), (20, 2.5, "process"))


def disk_family(work: Path, bases: dict[str, Path]) -> tuple[list[Outcome], str | None]:
    """The kills session run onto small tmpfs mounts (:data:`DISK_CASES`). Returns the outcomes, or none and
    the reason the family was skipped."""
    if os.geteuid() != 0:
        return [], "not running as root (mounting a tmpfs needs root)"
    root = work / "disk"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    outcomes = []
    for k, (size_mb, free_mb, executor) in enumerate(DISK_CASES):
        name = f"tmpfs_{size_mb}MB" + (f"_free_{free_mb:g}MB" if free_mb is not None else "") + f".{executor}"
        mnt = root / f"tmpfs_{k}"
        mnt.mkdir()
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(mnt)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            shutil.rmtree(root, ignore_errors=True)
            return outcomes, f"mount -t tmpfs failed: {r.stderr.strip() or r.returncode}"
        try:
            if free_mb is not None:
                (mnt / "filler").write_bytes(bytes(int((size_mb - free_mb) * (1 << 20))))
            logs = root / f"log_{k}"
            logs.mkdir()
            res = run_command(_run_cmd(bases["kills"], mnt / "out", executor), logs, 300.0, sample_tree=True)
            outcomes.append(_classify_disk(f"disk-{k}", name, res, mnt))
        finally:
            subprocess.run(["umount", "-l", str(mnt)], capture_output=True)
    return outcomes, None


def _classify_disk(cid: str, mutation: str, res: dict, mnt: Path) -> Outcome:
    problems: list[tuple[str, str]] = []
    rc = res["exit"]
    events, stray = _events(res["stderr"])
    errors = [e for e in events if e.get("level") == "error" and e.get("event") != "run_end"]
    if res["timed_out"]:
        problems.append(("hang", "no exit in 300 s"))
    elif rc not in OK_EXITS:
        problems.append(("crash", f"exit {rc}"))
    if stray:
        kind = "crash" if any("Traceback" in s for s in stray) else "multiline"
        problems.append((kind, f"{len(stray)} line(s) not JSON events: {_clip(stray[0])}"))
    if any(e.get("traceback") for e in events):
        problems.append(("crash", "traceback in the JSON log"))
    if re.search("internal error", res["stderr"], re.I):
        problems.append(("internal", _clip(next(e["message"] for e in events
                                                  if "internal error" in str(e.get("message", "")).lower())
                                             if events else "internal error")))
    if rc == 0 and errors:
        problems.append(("unnamed", f"exit 0 with {len(errors)} error line(s)"))
    if rc in (1, 2):
        unnamed = [e["message"] for e in errors if str(mnt) not in str(e.get("message", ""))]
        if not errors:
            problems.append(("unnamed", f"exit {rc} without an error line"))
        elif unnamed:
            problems.append(("unnamed", f"{len(unnamed)} of {len(errors)} error line(s) name no file under OUT: "
                                        f"{_clip(unnamed[0])}"))
        multi = [e["message"] for e in errors if _UNCLEAN.search(str(e.get("message", "")))]
        if multi:
            problems.append(("multiline", _clip(multi[0])))
        msgs = [str(e.get("message", "")) for e in errors]
        if len(msgs) != len(set(msgs)):
            problems.append(("multiline", "the same failure reported more than once"))
    if not events or events[-1].get("event") != "run_end":
        problems.append(("multiline", "no final run_end summary line"))
    if res["peak_kb"] > MEM_LIMIT_KB:
        problems.append(("mem", f"peak {res['peak_kb'] / 1024:.0f} MB"))
    first = errors[0]["message"] if errors else (events[-1].get("message", "") if events else "")
    return Outcome(cid, "disk", "run", mutation, "run", str(mnt / "out"), rc, round(res["seconds"], 2),
                   round(res["peak_kb"] / 1024, 1), problems, _clip(str(first), 240))


# ================================================================================================ report

def table(outcomes: list[Outcome], skipped: dict[str, str]) -> str:
    cols = ["cases", "ok", *[COLUMN.get(p, p) for p in PROBLEMS]]
    rows: list[tuple[str, list[int]]] = []

    def counts(group: list[Outcome]) -> list[int]:
        return [len(group), sum(o.ok for o in group),
                *[sum(any(k == p for k, _ in o.problems) for o in group) for p in PROBLEMS]]

    for fam in FAMILIES:
        group = [o for o in outcomes if o.family == fam]
        if not group:
            continue
        rows.append((fam, counts(group)))
        if fam in ("mutations", "bombs"):
            for reader in dict.fromkeys(o.reader for o in group):
                rows.append((f"  {reader}", counts([o for o in group if o.reader == reader])))
    rows.append(("total", counts(outcomes)))
    w = max([len(r[0]) for r in rows] + [10])
    lines = ["family".ljust(w) + "".join(c.rjust(10) for c in cols)]
    for name, vals in rows:
        if name == "total":
            lines.append("-" * len(lines[0]))
        lines.append(name.ljust(w) + "".join(str(v).rjust(10) for v in vals))
    for fam, why in skipped.items():
        lines.append(f"{fam}: skipped ({why})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=24, help="seed of every family's cases (default 24)")
    ap.add_argument("--cases", type=int, default=None, help="at most N mutation cases (a seeded subset)")
    ap.add_argument("--families", default=",".join(FAMILIES),
                    help=f"comma-separated subset of {', '.join(FAMILIES)} (default all)")
    ap.add_argument("--work", type=Path, default=REPO / "bench" / "_work" / "faults", help="work folder")
    ap.add_argument("-j", "--jobs", type=int, default=2, help="mutation cases run at once (default 2)")
    args = ap.parse_args(argv)
    families = [f.strip() for f in args.families.split(",") if f.strip()]
    unknown = set(families) - set(FAMILIES)
    if unknown:
        ap.error(f"unknown families: {', '.join(sorted(unknown))}")
    work = args.work.resolve()
    shutil.rmtree(work / "cases", ignore_errors=True)
    shutil.rmtree(work / "baselines", ignore_errors=True)
    work.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    runner = Runner(work)
    outcomes: list[Outcome] = []
    skipped: dict[str, str] = {}
    timings: dict[str, float] = {}
    if "mutations" in families:
        t0 = time.perf_counter()
        cases = mutation_cases(args.seed, runner.bases)
        if args.cases is not None and args.cases < len(cases):
            keep = set(int(i) for i in rng_for(args.seed, "cap").permutation(len(cases))[: args.cases])
            cases = [c for i, c in enumerate(cases) if i in keep]
        print(f"mutations: {len(cases)} cases ({sum(c.mode == 'run' for c in cases)} runs, "
              f"{sum(c.mode == 'inspect' for c in cases)} inspects), -j {args.jobs}", file=sys.stderr, flush=True)
        outcomes += run_cases(runner, cases, args.jobs)
        timings["mutations"] = time.perf_counter() - t0
    if "kills" in families:
        t0 = time.perf_counter()
        print(f"kills: {KILL_TRIALS} trials", file=sys.stderr, flush=True)
        outcomes += kill_family(args.seed, work, runner.bases)
        timings["kills"] = time.perf_counter() - t0
    if "disk" in families:
        t0 = time.perf_counter()
        print(f"disk: {len(DISK_CASES)} runs onto a 2 MB or 20 MB tmpfs", file=sys.stderr, flush=True)
        got, why = disk_family(work, runner.bases)
        outcomes += got
        if why:
            skipped["disk"] = why
        timings["disk"] = time.perf_counter() - t0
    if "bombs" in families:
        t0 = time.perf_counter()
        bombs = bomb_cases(args.seed, runner.bases)
        print(f"bombs: {len(bombs)} cases, one at a time", file=sys.stderr, flush=True)
        outcomes += run_cases(runner, bombs, 1, progress=False)
        timings["bombs"] = time.perf_counter() - t0
    total_s = time.perf_counter() - t_all

    print(f"\nbench_faults: seed {args.seed}, {len(outcomes)} cases in {total_s:.0f} s ("
          + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ")\n")
    print(table(outcomes, skipped))
    peaks = [o.peak_mb for o in outcomes if o.family in ("mutations", "bombs")]
    if peaks:
        worst = max((o for o in outcomes if o.family in ("mutations", "bombs")), key=lambda o: o.peak_mb)
        print(f"\npeak memory: max {worst.peak_mb:.0f} MB ({worst.case_id} {worst.mutation}), median "
              f"{float(np.median(peaks)):.0f} MB; slowest case "
              + max(((o.seconds, o.case_id, o.mutation) for o in outcomes if o.family != "kills"),
                    default=(0.0, "-", "-")).__repr__())
    bad = [o for o in outcomes if not o.ok]
    if bad:
        print(f"\nfailing cases ({len(bad)}):")
        for o in bad:
            kinds = ",".join(dict.fromkeys(k for k, _ in o.problems))
            print(f"  [{kinds}] {o.family}/{o.reader} {o.case_id} {o.mutation} ({o.mode} {Path(o.file).name}, "
                  f"exit {o.exit}, {o.seconds:.1f} s, {o.peak_mb:.0f} MB)")
            for k, detail in o.problems:
                print(f"      {k}: {detail}")
            print(f"      first line: {o.first_line}")
    (work / "results.json").write_text(json.dumps(
        {"seed": args.seed, "seconds": round(total_s, 1), "timings": timings, "skipped": skipped,
         "outcomes": [dataclasses.asdict(o) for o in outcomes]}, indent=1))
    n_problems = sum(len(o.problems) for o in outcomes)
    note = f" (skipped: {', '.join(skipped)})" if skipped else ""
    print(f"\nALL CLEAN{note}" if n_problems == 0 else f"\n{len(bad)} failing case(s), {n_problems} problem(s){note}")
    return 0


if __name__ == "__main__":
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))   # a crashing case leaves no core file
    sys.exit(main())
