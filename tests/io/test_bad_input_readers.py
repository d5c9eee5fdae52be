"""Bad text exports and C3D files the marker readers must not take silently: a blank line inside a Nexus
CSV's data rows, implausible rates in every text export and session.toml, implausible scales and spans, and
byte-order marks."""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np
import pytest

from gazepipe.errors import ConfigError, InputError
from gazepipe.io.c3d import read_c3d
from gazepipe.io.c3d_summary import summarise_c3d
from gazepipe.io.capture import inspect_capture, read_markers
from gazepipe.io.marker_csv import read_qtm_tsv, read_vicon_csv, read_wide_csv
from gazepipe.io.session_toml import load_session
from tests.helpers import SAMPLE, TESTS

CORPUS = TESTS / "data" / "corpus" / "c3d"


def _vicon(rows: int = 20, rate: str = "100", extra: str = "", units: str = "mm", scale: float = 1.0) -> list[str]:
    """Lines of a Nexus CSV with two markers moving over a metre."""
    lines = ["Trajectories", rate, ",,S:A,,,S:B,,", "Frame,Sub Frame,X,Y,Z,X,Y,Z",
             ",," + ",".join([units] * 6)]
    for i in range(rows):
        a = np.array([100.0 + 10 * i, 200.0, 1000.0, -300.0, 50.0 * i, 900.0]) * scale
        lines.append(f"{i + 1},0," + ",".join(f"{v:.6g}" for v in a))
    return lines + ([extra] if extra else [])


def _write(path: Path, lines: list[str], eol: str = "\n") -> Path:
    path.write_text(eol.join(lines) + eol)
    return path


# --------------------------------------------------------------------------------------- blank lines (Nexus)

@pytest.mark.parametrize("eol", ["\n", "\r\n"])
def test_a_blank_line_inside_the_data_rows_is_skipped_with_a_warning(tmp_path, eol):
    lines = _vicon(20)
    lines.insert(5 + 7, "")                      # after the 7th data row, on line 13
    lines[5 + 14: 5 + 14] = ["", ""]             # two more, lines 20-21
    m = read_vicon_csv(_write(tmp_path / "blank.csv", lines, eol))
    assert m.n_frames == 20 and m.valid.all()
    np.testing.assert_allclose(m.xyz[-1, 0], [290.0, 200.0, 1000.0])
    note = next(w for w in m.warnings if "blank line" in w)
    assert "blank.csv" in note and "lines 13, 20-21" in note and "3 blank line(s)" in note


def test_a_blank_line_before_the_next_block_ends_the_data(tmp_path):
    lines = _vicon(10) + ["", "Devices", "1000", ",,Force", "Frame,Sub Frame,Fx", ",,N", "1,0,5.0", "1,1,5.5"]
    m = read_vicon_csv(_write(tmp_path / "blocks.csv", lines))
    assert m.n_frames == 10 and not any("blank line" in w for w in m.warnings)
    lines = _vicon(10) + ["", "", "Model Outputs", "100"]
    assert read_vicon_csv(_write(tmp_path / "blocks2.csv", lines)).n_frames == 10
    assert read_vicon_csv(_write(tmp_path / "trailing.csv", _vicon(10) + ["", "", " "])).n_frames == 10


def test_a_row_of_empty_cells_inside_the_data_rows_is_refused(tmp_path):
    lines = _vicon(10)
    lines.insert(5 + 4, ",,,,,,,")
    p = _write(tmp_path / "commas.csv", lines)
    with pytest.raises(InputError) as ei:
        read_vicon_csv(p)
    assert str(p) in str(ei.value) and "line 10" in str(ei.value)


def test_the_layout_of_a_file_with_a_blank_line_fills_in_place(tmp_path):
    from gazepipe.io.filled_text import write_filled_text
    from gazepipe.io.marker_csv import read_text_export

    lines = _vicon(12)
    lines[5 + 3] = "4,0,,,,-300,150,900"         # a gap in marker A
    lines.insert(5 + 6, "")
    p = _write(tmp_path / "gap.csv", lines)
    original = read_text_export(p, "vicon_csv")
    m = original[0]
    filled = m.xyz.copy()
    filled[3, 0] = [130.0, 200.0, 1000.0]
    done = dataclasses.replace(m, xyz=filled, valid=np.ones_like(m.valid))
    n = write_filled_text(p, tmp_path / "out.csv", done, "vicon_csv", original=original)
    assert n == 1
    back = read_vicon_csv(tmp_path / "out.csv", strip_prefix=False)
    assert back.valid.all() and back.n_frames == 12
    assert (tmp_path / "out.csv").read_text().split("\n")[5 + 6] == ""


# --------------------------------------------------------------------------------------------------- rates

def test_an_implausible_nexus_rate_is_refused(tmp_path):
    p = _write(tmp_path / "fast.csv", _vicon(10, rate="1e9"))
    with pytest.raises(InputError) as ei:
        read_vicon_csv(p)
    msg = str(ei.value)
    assert str(p) in msg and "1e+09 Hz" in msg and "rate line" in msg and "\n" not in msg


@pytest.mark.parametrize("freq", ["1e12", "0.001", "0", "inf"])
def test_an_implausible_qtm_frequency_is_refused(tmp_path, freq):
    labels = ["A", "B"]
    rows = ["NO_OF_FRAMES\t5", "NO_OF_MARKERS\t2", f"FREQUENCY\t{freq}", "MARKER_NAMES\t" + "\t".join(labels),
            "Frame\tTime\tA X\tA Y\tA Z\tB X\tB Y\tB Z"]
    rows += [f"{i + 1}\t{i / 100:.2f}\t{100 + i}\t200\t1000\t-300\t{50 * i}\t900" for i in range(5)]
    p = _write(tmp_path / "fast.tsv", rows)
    with pytest.raises(InputError) as ei:
        read_qtm_tsv(p)
    assert str(p) in str(ei.value) and "FREQUENCY" in str(ei.value) and "Hz" in str(ei.value)


def test_an_implausible_rate_from_a_wide_csv_time_column_is_refused(tmp_path):
    rows = ["frame,time,A_x,A_y,A_z"] + [f"{i + 1},{i * 1e-6:.7f},{100 + i},200,1000" for i in range(5)]
    p = _write(tmp_path / "fast_wide.csv", rows)
    with pytest.raises(InputError) as ei:
        read_wide_csv(p)
    assert str(p) in str(ei.value) and "1e+06 Hz" in str(ei.value)


def test_an_implausible_given_rate_is_refused(tmp_path):
    rows = ["frame,A_x,A_y,A_z"] + [f"{i + 1},{100 + i},200,1000" for i in range(5)]
    p = _write(tmp_path / "norate.csv", rows)
    assert read_wide_csv(p, rate_hz=100).rate_hz == 100
    with pytest.raises(InputError) as ei:
        read_wide_csv(p, rate_hz=1e9)
    assert str(p) in str(ei.value) and "1e+09 Hz" in str(ei.value)


@pytest.mark.parametrize("key", ["rate_hz", "timecode_fps"])
def test_an_implausible_rate_in_session_toml_is_refused(tmp_path, key):
    root = tmp_path / "s"
    (root / "face").mkdir(parents=True)
    (root / "session.toml").write_text(
        'schema = 1\n[session]\nid = "s"\nsubject = "p"\n\n[[takes]]\nid = "f"\nkind = "face"\n'
        'tracked = "face/t.csv"\nclean = "face/c.csv"\nrate_hz = 60\ntimecode_fps = 60\n'.replace(
            f"{key} = 60", f"{key} = 1e9"))
    with pytest.raises(ConfigError) as ei:
        load_session(root)
    msg = str(ei.value)
    assert "session.toml" in msg and key in msg and "1e+09 Hz" in msg


# ------------------------------------------------------------------------------------------- scale and span

def _param_at(data: bytes, group: str, name: str) -> int:
    """Byte offset of a parameter's data in an Intel C3D file."""
    p = (data[0] - 1) * 512 + 4
    groups: dict[int, str] = {}
    found: dict[tuple[int, str], int] = {}
    while True:
        nlen, gid = struct.unpack_from("bb", data, p)
        if nlen == 0:
            break
        ne = p + 2 + abs(nlen)
        pname = data[p + 2: ne].decode("latin-1")
        nxt = struct.unpack_from("<h", data, ne)[0]
        if gid < 0:
            groups[-gid] = pname
        else:
            ndim = data[ne + 3]
            found[(gid, pname)] = ne + 4 + ndim
        if nxt == 0:
            break
        p = ne + nxt
    gid = next(k for k, v in groups.items() if v == group)
    return found[(gid, name)]


@pytest.mark.parametrize("source", ["Eb015pi.c3d", "ART-Human_2persons_integer.c3d"])
def test_a_tiny_point_scale_of_an_integer_c3d_is_refused(tmp_path, source):
    b = bytearray((CORPUS / source).read_bytes())
    struct.pack_into("<f", b, _param_at(b, "POINT", "SCALE"), 1e-30)
    p = tmp_path / "tiny.c3d"
    p.write_bytes(bytes(b))
    for read in (read_c3d, summarise_c3d):
        with pytest.raises(InputError) as ei:
            read(p)
        msg = str(ei.value)
        assert str(p) in msg and "POINT:SCALE" in msg and "1e-30" in msg and "\n" not in msg


def test_a_huge_span_is_warned_of_naming_the_scale(tmp_path):
    b = bytearray((CORPUS / "Eb015pi.c3d").read_bytes())
    at = _param_at(b, "POINT", "SCALE")
    scale = struct.unpack_from("<f", b, at)[0]
    struct.pack_into("<f", b, at, scale * 100)
    p = tmp_path / "huge.c3d"
    p.write_bytes(bytes(b))
    full = read_c3d(p).warnings
    streamed = summarise_c3d(p)["warnings"]
    for notes in (full, streamed):
        assert any("POINT:SCALE" in w and "span" in w for w in notes), notes


def test_text_exports_all_within_a_millimetre_of_the_origin_are_refused(tmp_path):
    p = _write(tmp_path / "tiny.csv", _vicon(10, scale=1e-6))
    with pytest.raises(InputError) as ei:
        read_vicon_csv(p)
    assert str(p) in str(ei.value) and "within" in str(ei.value) and "'mm'" in str(ei.value)
    rows = ["frame,time,A_x,A_y,A_z"] + [f"{i + 1},{i / 100:.2f},{(i + 1) * 1e-3},0.0002,0.0001" for i in range(5)]
    with pytest.raises(InputError):
        read_wide_csv(_write(tmp_path / "tiny_wide.csv", rows))


def test_text_exports_spanning_kilometres_are_warned_of(tmp_path):
    m = read_vicon_csv(_write(tmp_path / "km.csv", _vicon(10, units="m")))   # mm values labelled metres
    assert any("span" in w and "'m'" in w for w in m.warnings), m.warnings


def test_the_c3d_corpus_reads_without_span_problems():
    files = sorted(CORPUS.glob("*.c3d")) + sorted((SAMPLE / "mocap").glob("*.c3d"))[:2]
    assert len(files) >= 9
    for f in files:
        summary = inspect_capture(f)
        assert summary["frames"] > 0
        assert not any("span" in w or "within" in w for w in summary["warnings"]), (f, summary["warnings"])


# ----------------------------------------------------------------------------------------- byte-order marks

def test_a_utf8_bom_before_a_nexus_csv_is_read(tmp_path):
    plain = _write(tmp_path / "plain.csv", _vicon(10))
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = read_markers(plain), read_markers(bom)
    assert b.source_format == "vicon_csv" and b.labels == a.labels
    np.testing.assert_array_equal(a.xyz, b.xyz)


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-be"])
def test_a_utf16_export_gets_a_clear_error(tmp_path, encoding):
    p = tmp_path / "wide16.csv"
    text = "\n".join(_vicon(10)) + "\n"
    p.write_bytes(("\ufeff" if encoding == "utf-16-be" else "").encode(encoding) + text.encode(encoding))
    with pytest.raises(InputError) as ei:
        read_markers(p)
    assert str(p) in str(ei.value) and "UTF-16" in str(ei.value)


@pytest.mark.parametrize("kind", ["eyes", "face"])
def test_utf16_track_files_get_a_clear_error(tmp_path, kind):
    from gazepipe.io.livelinkface import read_livelinkface
    from gazepipe.io.openface import read_openface

    src = SAMPLE / ("eyes/follow_standing_03.csv" if kind == "eyes" else "face/face_04_tracked.csv")
    p = tmp_path / "t16.csv"
    p.write_bytes(src.read_text().encode("utf-16"))
    with pytest.raises(InputError) as ei:
        read_openface(p) if kind == "eyes" else read_livelinkface(p, rate_hz=30)
    assert str(p) in str(ei.value) and "UTF-16" in str(ei.value)
