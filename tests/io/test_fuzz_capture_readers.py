"""Fuzzing the capture readers: truncated, random and byte-mutated C3D, CSV and TSV files.

Every input must give either valid Markers or an InputError whose one-line message names the file. C3D cases
run in child processes, a batch per process, so that a crash inside ezc3d (a signal) or a hang (the timeout)
fails the test instead of killing or blocking the test run.
"""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gazepipe.errors import InputError
from gazepipe.io.c3d_meta import MetaError, parse_c3d_meta
from gazepipe.io.capture import read_markers
from gazepipe.model import Markers
from tests.helpers import REPO

CORPUS = REPO / "tests" / "data" / "corpus" / "c3d"
C3D_FILES = sorted(CORPUS.glob("*.c3d"))
C3D_BYTES = [p.read_bytes() for p in C3D_FILES]

BATCH = 25          # C3D cases per child process
C3D_BATCHES = 8     # hypothesis examples of the C3D test: 200 C3D cases in all
TEXT_CASES = 150    # CSV/TSV cases, run in-process (pure Python and pandas: no native crash risk)
CHILD_TIMEOUT_S = 60

_CHILD = r"""
import json, sys
from gazepipe.errors import InputError
from gazepipe.io.c3d_meta import MetaError, parse_c3d_meta
from gazepipe.io.capture import read_markers
from gazepipe.model import Markers
for p in sys.argv[1:]:
    try:
        m = read_markers(p)
        ok = isinstance(m, Markers) and m.valid.shape == m.xyz.shape[:2]
        out = "ok" if ok else "bad-markers"
    except InputError as e:
        s = str(e)
        out = "input-error" if (p in s and "\n" not in s) else "bad-message: " + s[:200]
    except BaseException as e:
        out = "escaped %s: %s" % (type(e).__name__, str(e)[:200])
    print(json.dumps([p, out]), flush=True)
"""


def _mutate_c3d(src: bytes, kind: str, cut: float, edits: list[tuple[float, int]]) -> bytes:
    if kind == "truncate":
        return src[: int(cut * len(src))]
    b = bytearray(src)
    param_start = (b[0] - 1) * 512
    param_end = min(len(b), param_start + 512 * max(b[param_start + 2], 1))
    lo, hi = {"header": (0, 512), "params": (param_start, param_end), "anywhere": (0, len(b))}[kind]
    for pos, val in edits:
        b[lo + int(pos * (hi - lo - 1))] = val
    return bytes(b)


c3d_case = st.one_of(
    st.tuples(st.integers(0, len(C3D_BYTES) - 1),
              st.sampled_from(["truncate", "header", "params", "params", "anywhere"]),
              st.floats(0, 1),
              st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=8)),
    st.binary(min_size=0, max_size=3000),
)


@settings(max_examples=C3D_BATCHES, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                 HealthCheck.data_too_large])
@given(cases=st.lists(c3d_case, min_size=BATCH, max_size=BATCH))
def test_fuzz_c3d_in_child_process(tmp_path_factory, cases):
    folder = tmp_path_factory.mktemp("c3d")
    paths = []
    for i, case in enumerate(cases):
        data = case if isinstance(case, bytes) else _mutate_c3d(C3D_BYTES[case[0]], *case[1:])
        p = folder / f"case_{i:03d}.c3d"
        p.write_bytes(data)
        paths.append(str(p))
    env = dict(os.environ, PYTHONPATH=str(REPO))
    try:
        r = subprocess.run([sys.executable, "-c", _CHILD, *paths], capture_output=True, env=env,
                           timeout=CHILD_TIMEOUT_S)
    except subprocess.TimeoutExpired as e:
        done = len((e.stdout or b"").decode().splitlines())
        raise AssertionError(f"reader hung on {paths[min(done, len(paths) - 1)]}") from None
    results = [json.loads(line) for line in r.stdout.decode().splitlines() if line.startswith("[")]
    if r.returncode != 0:
        crashed = paths[len(results)] if len(results) < len(paths) else "?"
        raise AssertionError(f"reader process died (code {r.returncode}) on {crashed}: {r.stderr.decode()[-500:]}")
    assert len(results) == len(paths)
    bad = [(p, out) for p, out in results if out not in ("ok", "input-error")]
    assert not bad, bad[:5]


# ------------------------------------------------------------------------------------------------ text

VICON = (
    "Trajectories\n100\n,,S:A,,,S:B,,\nFrame,Sub Frame,X,Y,Z,X,Y,Z\n,,mm,mm,mm,mm,mm,mm\n"
    + "".join(f"{k + 1},0,{k * 1.5},{-k},{1000 + k},,,\n" if k % 7 == 3 else
              f"{k + 1},0,{k * 1.5},{-k},{1000 + k},{k},{2 * k},{3 * k}\n" for k in range(30))
)
QTM = (
    "NO_OF_FRAMES\t30\nNO_OF_CAMERAS\t8\nNO_OF_MARKERS\t2\nFREQUENCY\t120\nNO_OF_ANALOG\t0\n"
    "ANALOG_FREQUENCY\t0\nDESCRIPTION\t--\nTIME_STAMP\t2019-11-28, 13:43:42.715\t1476252.89\n"
    "DATA_INCLUDED\t3D\nMARKER_NAMES\tA\tB\nTRAJECTORY_TYPES\tMeasured\tMeasured\n"
    "Frame\tTime\tA X\tA Y\tA Z\tB X\tB Y\tB Z\n"
    + "".join(f"{k + 1}\t{k / 120:.5f}\t{k}.000\t1.000\t2.000\t0.000\t0.000\t0.000\n" if k % 5 == 0 else
              f"{k + 1}\t{k / 120:.5f}\t{k}.000\t1.000\t2.000\t{k}.5\t3.000\t4.000\n" for k in range(30))
)
WIDE = "frame,time,A_x,A_y,A_z,B_x,B_y,B_z\n" + "".join(
    f"{k + 10},{k / 60!r},{k}.25,{-k},{k * 2},{'' if k % 4 == 0 else k},{k},{k}\n" for k in range(30))
# Nexus 1.x: Title header, TRAJECTORIES, "100,Hz", Field #, no units row, a model angle and an unlabeled trajectory
VICON1X = (
    'Title\nDate:\nTime:\nType:\nDescription:,""\nNotes:,""\n\nTRAJECTORIES\n100,Hz\n'
    ",LFHD,,,*12,,,LHipAngles,,\nField #,X,Y,Z,X,Y,Z,X,Y,Z\n"
    + "".join(f"{k + 1},{k * 1.5},{-k},{1000 + k},{k},{2 * k},{3 * k},1.5,-2.25E-14,{k}\n" for k in range(30))
)
# Nexus 2 with trajectory magnitudes and a Trajectory Count column
VICON_MAG = (
    "Trajectories\n100\n,,Trajectory Count,S:A,,,| S:A |\nFrame,Sub Frame,Count,X,Y,Z,Magnitude( X )\n"
    ",,,mm,mm,mm,mm\n" + "".join(f"{k + 1},0,1,{k}.5,{-k},{1000 + k},{1000.5 + k}\n" for k in range(30))
)
TEXTS = [("vicon.csv", VICON), ("qtm.tsv", QTM), ("wide.csv", WIDE), ("vicon1x.csv", VICON1X),
         ("viconmag.csv", VICON_MAG)]


class _Timeout(Exception):
    pass


def _alarm(signum, frame):  # pragma: no cover - only runs on a hang
    raise _Timeout()


def test_text_fixtures_read():
    """The fixtures the text fuzzing mutates are valid to begin with."""
    for name, text in TEXTS:
        assert read_markers_from_text(name, text, Path(os.environ.get("TMPDIR", "/tmp"))).n_frames == 30


def read_markers_from_text(name: str, text: str, folder: Path) -> Markers:
    p = folder / f"fixture_{os.getpid()}_{name}"
    p.write_text(text)
    try:
        return read_markers(p)
    finally:
        p.unlink()


text_case = st.one_of(
    st.tuples(st.integers(0, len(TEXTS) - 1), st.sampled_from(["truncate", "bytes", "insert", "delete"]),
              st.floats(0, 1), st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1,
                                        max_size=6)),
    st.tuples(st.sampled_from(["x.csv", "x.tsv"]), st.binary(max_size=2000)),
)


@settings(max_examples=TEXT_CASES, deadline=2000, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(case=text_case)
def test_fuzz_text_exports(tmp_path_factory, case):
    folder = tmp_path_factory.mktemp("txt", numbered=True)
    if isinstance(case[1], bytes):
        name, data = case
    else:
        idx, kind, cut, edits = case
        name, text = TEXTS[idx]
        b = bytearray(text.encode())
        if kind == "truncate":
            b = b[: int(cut * len(b))]
        for pos, val in edits if kind != "truncate" else []:
            i = int(pos * max(len(b) - 1, 0))
            if kind == "bytes" and b:
                b[i] = val
            elif kind == "insert":
                b[i:i] = bytes([val]) * (1 + val % 3)
            elif kind == "delete" and b:
                del b[i: i + 1 + val % 5]
        data = bytes(b)
    p = folder / name
    p.write_bytes(data)
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(10)
    try:
        m = read_markers(p, rate_hz=None)
        assert isinstance(m, Markers) and m.valid.shape == m.xyz.shape[:2]
        assert np.isnan(m.xyz[~m.valid]).all()
    except InputError as e:
        assert str(p) in str(e) and "\n" not in str(e)
    except _Timeout:  # pragma: no cover
        raise AssertionError(f"reader hung on {p}") from None
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _records(data: bytes):
    """(start, name_end, group id, name) of every record of an Intel file's parameter section."""
    p = (data[0] - 1) * 512 + 4
    out = []
    while True:
        nlen, gid = struct.unpack_from("bb", data, p)
        if nlen == 0:
            break
        ne = p + 2 + abs(nlen)
        out.append((p, ne, gid, data[p + 2: ne].decode()))
        off = struct.unpack_from("<h", data, ne)[0]
        if off == 0:
            break
        p = ne + off
    return out


def test_files_that_crash_ezc3d_are_kept_from_it(tmp_path):
    """Mutations that made ezc3d 1.7.2 crash (SIGSEGV) or hang: the reader must not hand them to it."""
    src = (CORPUS / "Eb015pi.c3d").read_bytes()
    recs = _records(src)
    gid = {name: -g for _, _, g, name in recs if g < 0}
    find = {(g, name): (p, ne) for p, ne, g, name in recs if g > 0}
    cases = {}
    p, ne = find[(gid["ANALOG"], "SCALE")]
    b = bytearray(src)
    b[p + 2] = ord("#")                          # ANALOG:SCALE absent
    cases["no_analog_scale"] = b
    p, ne = find[(gid["POINT"], "DESCRIPTIONS")]
    b = bytearray(src)
    b[p + 1] = (-6) & 0xFF                       # a parameter record read as a group (description length 255)
    cases["param_as_group"] = b
    p, ne = find[(gid["SUBJECT"], "NUMBER")]
    b = bytearray(src)
    b[ne + 2] = 0xFF                             # an int16 scalar retyped as a character scalar
    cases["char_scalar"] = b
    p, ne = find[(gid["ANALOG"], "DESCRIPTIONS")]
    ndim = src[ne + 3]
    dims = src[ne + 4: ne + 4 + ndim]
    desc_at = ne + 4 + ndim + int(np.prod(list(dims))) * 1
    b = bytearray(src)
    b[desc_at] = 132                             # description length read as negative
    cases["desc_len_132"] = b
    paths = []
    for name, data in cases.items():
        path = tmp_path / f"{name}.c3d"
        path.write_bytes(bytes(data))
        meta = parse_c3d_meta(bytes(data))
        try:
            assert not meta.layout(len(data)).ezc3d_safe, name
        except MetaError:
            pass
        paths.append(str(path))
    r = subprocess.run([sys.executable, "-c", _CHILD, *paths], capture_output=True, timeout=CHILD_TIMEOUT_S,
                       env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert r.returncode == 0, r.stderr.decode()[-500:]
    results = dict(json.loads(line) for line in r.stdout.decode().splitlines() if line.startswith("["))
    assert set(results.values()) <= {"ok", "input-error"} and len(results) == len(paths)
