"""Bounded reading and clean errors on hostile inputs: TOML nesting and size, over-long ids, CSV files cut inside
their header, C3D rates out of range, declared sizes checked before allocating, bounded C3D decoding, over-long
text lines refused in bounded memory, bytes from files escaped in error lines, and floats read back exactly."""

from __future__ import annotations

import re
import struct
import textwrap
import tracemalloc
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.errors import ConfigError, InputError, printable
from gazepipe.io import limits
from gazepipe.io.c3d import read_c3d, write_c3d
from gazepipe.io.capture import read_markers
from gazepipe.io.livelinkface import read_livelinkface
from gazepipe.io.marker_csv import read_vicon_csv, read_wide_csv
from gazepipe.io.openface import read_openface
from gazepipe.io.session_toml import load_session, validate_session
from gazepipe.model import Markers
from tests.helpers import SAMPLE, make_tiny_session

CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def one_line(err: Exception, path) -> str:
    s = str(err)
    assert str(path) in s and "\n" not in s and not CONTROL.search(s), s
    return s


def run_cli(*args: str):
    return CliRunner().invoke(cli, list(args))


# ------------------------------------------------------------------------------------------------ TOML

def _session_text(extra: str = "", take_id: str = "t0", session_id: str = "tiny") -> str:
    return textwrap.dedent(f"""\
        schema = 1
        [session]
        id = "{session_id}"
        subject = "p01"
        markerset = "markerset.toml"
        {extra}
        [[takes]]
        id = "{take_id}"
        kind = "gaze_follow"
        pose = "standing"
        mocap = "mocap/t0.csv"
        """)


@pytest.fixture
def session(tmp_path):
    return make_tiny_session(tmp_path / "s", n_takes=1)


def test_deeply_nested_toml_is_a_configuration_error(session, tmp_path):
    toml = session / "session.toml"
    toml.write_text(_session_text().replace("schema = 1", "schema = 1\nx = " + "[" * 5000 + "]" * 5000))
    errors = validate_session(session)
    assert len(errors) == 1 and "nested too deep" in one_line(errors[0], toml)
    res = run_cli("run", str(session), "--out", str(tmp_path / "out"), "--executor", "serial")
    assert res.exit_code == 2 and "nested too deep" in res.output and "internal error" not in res.output
    # below the parser's recursion limit, the depth check itself refuses it
    toml.write_text(_session_text().replace("schema = 1", "schema = 1\nx = " + "[" * 40 + "]" * 40))
    assert "nested too deep" in validate_session(session)[0].problem
    # what the files need is far below the bound: an unknown key, not a nesting error
    toml.write_text(_session_text().replace("schema = 1", "schema = 1\nx = " + "[" * 10 + "]" * 10))
    assert [(e.key, e.problem) for e in validate_session(session)] == [("x", "unknown key 'x'")]


def test_toml_over_the_size_limit_is_refused_before_it_is_read(session, monkeypatch):
    toml = session / "session.toml"
    toml.write_text(_session_text() + "# " + "x" * (limits.MAX_TOML_BYTES + 10) + "\n")
    real_open = open

    def guarded_open(file, *args, **kwargs):
        assert str(file) != str(toml), "the over-size file was opened"
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr("builtins.open", guarded_open)
    errors = validate_session(session)
    monkeypatch.undo()
    assert len(errors) == 1 and "at most 1 MiB" in one_line(errors[0], toml)
    toml.write_text(_session_text() + "# " + "x" * (limits.MAX_TOML_BYTES - 1000) + "\n")
    assert validate_session(session) == []


@pytest.mark.parametrize("which", ["take", "session"])
def test_over_long_ids_are_refused_at_validation(session, tmp_path, which):
    long = "a" * 300
    toml = session / "session.toml"
    toml.write_text(_session_text(take_id=long) if which == "take" else _session_text(session_id=long))
    with pytest.raises(ConfigError) as e:
        load_session(session)
    msg = one_line(e.value, toml)
    assert ("takes[0].id" if which == "take" else "session.id") in msg and "300 characters" in msg
    res = run_cli("run", str(session), "--out", str(tmp_path / "out"), "--executor", "serial")
    assert res.exit_code == 2 and "at most 100" in res.output and "file name too long" not in res.output.lower()
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*.parquet"))


def test_ids_of_100_characters_are_accepted(session):
    (session / "session.toml").write_text(_session_text(take_id="t" * 100, session_id="s" * 100))
    s = load_session(session)
    assert s.id == "s" * 100 and s.takes[0].id == "t" * 100


def test_folder_name_too_long_for_a_default_session_id(tmp_path):
    root = make_tiny_session(tmp_path / ("f" * 120), n_takes=1)
    (root / "session.toml").write_text(_session_text().replace('id = "tiny"\n', ""))
    errors = validate_session(root)
    assert len(errors) == 1 and errors[0].key == "session.id" and "120 characters" in str(errors[0])


# ----------------------------------------------------------------------------------- cut CSV headers

@pytest.mark.parametrize("src, read", [
    (SAMPLE / "eyes" / "follow_sitting_01.csv", read_openface),
    (SAMPLE / "face" / "face_01_tracked.csv", lambda p: read_livelinkface(p, rate_hz=60)),
])
def test_track_csv_cut_just_after_its_header_is_one_clean_line(tmp_path, src, read):
    data = src.read_bytes()
    header_end = data.index(b"\n") + 1
    p = tmp_path / src.name
    for cut in (header_end + 1, header_end + 3):
        p.write_bytes(data[:cut])
        with pytest.raises(InputError, match="data row 1 has") as e:
            read(p)
        assert "file cut short" in one_line(e.value, p)
    res = run_cli("inspect", str(p))
    assert res.exit_code == 1 and "internal error" not in res.output and str(p) in res.output


# -------------------------------------------------------------------------------------------- C3D

def _param_data(data: bytes, group: str, name: str) -> int:
    """Byte offset of a parameter's data in an Intel file."""
    return next(d for g, n, _, d in _records(data) if (g, n) == (group, name))


def _records(data: bytes) -> list[tuple[str, str, int, int]]:
    """(group, name, record start, data offset) of every parameter of an Intel file."""
    p = (data[0] - 1) * 512 + 4
    groups, out = {}, []
    while True:
        nlen, gid = struct.unpack_from("bb", data, p)
        if nlen == 0:
            break
        ne = p + 2 + abs(nlen)
        name = data[p + 2: ne].decode("latin-1")
        if gid < 0:
            groups[-gid] = name
        else:
            out.append((gid, name, p, ne + 4 + data[ne + 3]))
        off = struct.unpack_from("<h", data, ne)[0]
        if off == 0:
            break
        p = ne + off
    return [(groups.get(g, "?"), n, p, d) for g, n, p, d in out]


@pytest.mark.parametrize("rate", [1e30, 1e-30, 0.5, 20000.0])
def test_c3d_point_rate_outside_1hz_10khz_is_refused(tmp_path, rate):
    b = bytearray((SAMPLE / "mocap" / "neutral.c3d").read_bytes())
    struct.pack_into("<f", b, _param_data(b, "POINT", "RATE"), rate)
    p = tmp_path / "rate.c3d"
    p.write_bytes(bytes(b))
    with pytest.raises(InputError, match="outside 1 Hz - 10 kHz") as e:
        read_c3d(p)
    assert "POINT:RATE" in one_line(e.value, p)
    res = run_cli("inspect", str(p))
    assert res.exit_code == 1 and res.output.count("\n") == 1 and "outside 1 Hz - 10 kHz" in res.output


@pytest.mark.parametrize("rate", [1.0, 10000.0])
def test_c3d_rates_at_the_bounds_are_read(tmp_path, rate):
    b = bytearray((SAMPLE / "mocap" / "neutral.c3d").read_bytes())
    struct.pack_into("<f", b, _param_data(b, "POINT", "RATE"), rate)
    struct.pack_into("<f", b, 20, rate)                    # the header's rate agrees
    p = tmp_path / "rate.c3d"
    p.write_bytes(bytes(b))
    assert read_c3d(p).rate_hz == rate


def test_c3d_parameter_name_bytes_are_escaped(tmp_path):
    b = bytearray((SAMPLE / "mocap" / "neutral.c3d").read_bytes())
    group, name, start, data_at = next(r for r in _records(b) if r[1] == "USED")
    b[start + 3: start + 5] = b"\x1b\x00"                  # U\x1b\x00D: an escape sequence and a NUL
    b[start + 4 + len(name)] = 9                           # its type byte: unknown
    p = tmp_path / "names.c3d"
    p.write_bytes(bytes(b))
    with pytest.raises(InputError, match="unknown type") as e:
        read_c3d(p)
    assert "U\\x1b\\x00D" in one_line(e.value, p)
    res = run_cli("inspect", str(p))
    assert res.exit_code == 1 and "U\\x1b\\x00D" in res.output and not CONTROL.search(res.output.rstrip("\n"))


def test_printable_escapes_what_would_break_a_line():
    assert printable("a\x00b\x1b[2Jc\x9bd") == "a\\x00b\\x1b[2Jc\\x9bd"
    assert printable("right\u202eleft\u2028") == "right\\u202eleft\\u2028"
    assert printable("/data/caf\udce9.c3d") == "/data/caf\\xe9.c3d"            # an undecodable byte
    assert printable("Ünïcode µm 3°") == "Ünïcode µm 3°"
    err = InputError("/data/x\udcff.c3d", "label 'A\x07B'", key="POINT:LABELS")
    assert str(err) == "/data/x\\xff.c3d: POINT:LABELS: label 'A\\x07B'"


@contextmanager
def traced_peak() -> Iterator[dict[str, int]]:
    """The peak of the memory traced inside the block, bytes (``mem["peak"]`` once it ends, raising or not)."""
    mem: dict[str, int] = {}
    tracemalloc.start()
    try:
        yield mem
    finally:
        mem["peak"] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()


def test_c3d_frame_count_beyond_the_file_is_refused_before_allocating(tmp_path):
    b = bytearray((SAMPLE / "mocap" / "neutral.c3d").read_bytes())
    struct.pack_into("<H", b, 8, 65535)                     # last frame: 65,535 frames of 35 points claimed
    p = tmp_path / "claims.c3d"
    p.write_bytes(bytes(b))
    with traced_peak() as mem, pytest.raises(InputError, match="truncated") as e:
        read_c3d(p)
    one_line(e.value, p)
    assert mem["peak"] < 2 << 20                                   # the 37 MB the header claims are never allocated


def test_c3d_point_blocks_are_decoded_in_bounded_memory(tmp_path):
    rng = np.random.default_rng(2)
    t, m = 6000, 100
    xyz = rng.uniform(-900, 900, (t, m, 3)).astype(np.float32).astype(np.float64)
    valid = rng.random((t, m)) > 0.1
    xyz[~valid] = np.nan
    p = tmp_path / "large.c3d"
    write_c3d(p, Markers(labels=[f"M{i}" for i in range(m)], xyz=xyz, valid=valid, rate_hz=100.0))
    with traced_peak() as mem:
        back = read_c3d(p)
    peak = mem["peak"]
    np.testing.assert_array_equal(back.valid, valid)
    np.testing.assert_array_equal(back.xyz, xyz)
    # the result plus a bounded buffer (reading the file whole and decoding it at once took 4x the result)
    assert peak < back.xyz.nbytes + (10 << 20), (peak, back.xyz.nbytes)


# ----------------------------------------------------------------------------------------- long lines

def test_over_long_text_line_is_refused_in_bounded_memory(tmp_path):
    p = tmp_path / "v.csv"
    head = "Trajectories\n100\n,,A,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n1,0,1,2,3\n2,0,"
    with open(p, "w") as fh:
        fh.write(head)
        for _ in range(40):
            fh.write("9" * (1 << 20))                       # a 40 MB line 7
    with traced_peak() as mem, pytest.raises(InputError, match="line 7 is longer than 1 MiB") as e:
        read_markers(p)
    one_line(e.value, p)
    assert mem["peak"] < 16 << 20, mem


def test_line_just_under_the_limit_is_read(tmp_path):
    p = tmp_path / "w.csv"
    pad = "0" * (limits.MAX_LINE_BYTES - 20)
    p.write_text(f"frame,time,A_x,A_y,A_z\n1,0,{pad}1,2,3\n2,0.01,1,2,3\n")
    assert read_wide_csv(p).xyz[0, 0].tolist() == [1.0, 2.0, 3.0]


@pytest.mark.parametrize("src, read, where", [
    (SAMPLE / "eyes" / "follow_sitting_01.csv", read_openface, "header"),
    (SAMPLE / "eyes" / "follow_sitting_01.csv", read_openface, "row"),
    (SAMPLE / "face" / "face_01_tracked.csv", lambda p: read_livelinkface(p, rate_hz=60), "header"),
    (SAMPLE / "face" / "face_01_tracked.csv", lambda p: read_livelinkface(p, rate_hz=60), "row"),
])
def test_over_long_lines_in_track_csvs(tmp_path, src, read, where):
    lines = src.read_text().splitlines(keepends=True)
    i = 0 if where == "header" else 3
    lines[i] = lines[i].rstrip("\n") + " " * (2 << 20) + "\n"
    p = tmp_path / src.name
    p.write_text("".join(lines))
    with pytest.raises(InputError, match=f"line {i + 1}.* is longer than 1 MiB") as e:
        read(p)
    one_line(e.value, p)


# ------------------------------------------------------------------------------------------- floats

HARD = ["0.1", "2.2250738585072011e-308", "9007199254740993", "1.7976931348623157e308", "5e-324",
        "0.30000000000000004", "123456.78901234567", "-0.0", "1.0000000000000002", "8.41e21"]


def _values(n: int, seed: int) -> np.ndarray:
    """Doubles of 17 significant digits from 1e-12 to 1e5 (inside the physical bound on coordinates)."""
    rng = np.random.default_rng(seed)
    return rng.normal(0, 1, n) * 10.0 ** rng.integers(-12, 6, n)


def test_wide_csv_values_written_with_repr_read_back_identical(tmp_path):
    hard = [float(x) for x in HARD if abs(float(x)) <= limits.MAX_ABS_MM]
    v = np.concatenate([hard, _values(3 * 400 - len(hard), 0)]).reshape(-1, 3)
    rows = "".join(f"{k + 1},{k / 100!r},{a!r},{b!r},{c!r}\n" for k, (a, b, c) in enumerate(v.tolist()))
    p = tmp_path / "w.csv"
    p.write_text("frame,time,A_x,A_y,A_z\n" + rows)
    back = read_wide_csv(p)
    assert back.valid.all() and np.array_equal(back.xyz[:, 0], v)


def test_slow_path_and_track_csv_values_read_back_identical(tmp_path):
    v = _values(300, 1).reshape(-1, 3)
    rows = "".join(f"{k + 1},0,{a!r},{b!r},{c!r}\n" for k, (a, b, c) in enumerate(v.tolist()))
    p = tmp_path / "v.csv"
    # a NAN token sends the block to the string path, whose numbers must be as exact
    p.write_text("Trajectories\n100\n,,A,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n" + rows + "101,0,NAN,NAN,NAN\n")
    back = read_vicon_csv(p)
    assert back.valid[:100].all() and np.array_equal(back.xyz[:100, 0], v) and not back.valid[100, 0]

    src = SAMPLE / "eyes" / "follow_sitting_01.csv"
    df = pd.read_csv(src, skipinitialspace=True)
    g = _values(len(df), 2)
    g[: len(HARD)] = [float(x) for x in HARD]
    df["confidence"] = g
    q = tmp_path / "of.csv"
    q.write_text(",".join(df.columns) + "\n" + "".join(
        ",".join(repr(float(x)) for x in row) + "\n" for row in df.to_numpy(dtype=float)))
    assert np.array_equal(read_openface(q).confidence, g)


def test_round_trip_parser_asked_for_where_pandas_needs_it(monkeypatch):
    limits.exact_floats.cache_clear()
    try:
        for version, expected in [("2.1.4", "round_trip"), ("3.0.6", "round_trip"), ("3.1.1", None),
                                  ("4.0.0.dev0+123", None)]:
            monkeypatch.setattr(pd, "__version__", version)
            limits.exact_floats.cache_clear()
            assert limits.exact_floats().get("float_precision") == expected, version
    finally:
        monkeypatch.undo()
        limits.exact_floats.cache_clear()


@pytest.mark.parametrize("src, read, column", [
    (SAMPLE / "eyes" / "follow_sitting_01.csv", read_openface, "gaze_0_x"),
    (SAMPLE / "face" / "face_01_tracked.csv", lambda p: read_livelinkface(p, rate_hz=60), "JawOpen"),
])
def test_infinite_values_in_track_csvs_are_refused(tmp_path, src, read, column):
    lines = src.read_text().splitlines(keepends=True)
    head = [c.strip() for c in lines[0].split(",")]
    j = [h.lower() for h in head].index(column.lower())
    cells = lines[5].split(",")
    cells[j] = " inf" if j < len(cells) - 1 else "inf\n"
    lines[5] = ",".join(cells)
    p = tmp_path / src.name
    p.write_text("".join(lines))
    with pytest.raises(InputError, match="infinite value inf in data row 5") as e:
        read(p)
    one_line(e.value, p)
