"""The frame column of Vicon CSV, QTM TSV and wide CSV exports, and coordinates no capture can hold: reordered,
repeated or absurd frame numbers are refused with the line they are on; dropped frames become gap rows with a
warning; infinite, partial and absurd samples become gaps with a warning (C3D too)."""

from __future__ import annotations

import shutil
import struct

import numpy as np
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.errors import InputError
from gazepipe.io.c3d import read_c3d, write_c3d
from gazepipe.io.capture import read_markers
from gazepipe.io.filled_text import write_filled_text
from gazepipe.io.marker_csv import read_qtm_tsv, read_text_export, read_vicon_csv, read_wide_csv
from gazepipe.model import Markers

HEAD = "Trajectories\n100\n,,S:A,,,S:B,,\nFrame,Sub Frame,X,Y,Z,X,Y,Z\n,,mm,mm,mm,mm,mm,mm\n"
FIRST_DATA_LINE = 6


def vicon_rows(frames, t=None) -> list[str]:
    return [f"{f},0,{k + 0.5},{-k},{1000 + k},{k},{2 * k},{3 * k}" for k, f in enumerate(frames)]


def vicon(tmp_path, rows: list[str], name="v.csv"):
    p = tmp_path / name
    p.write_text(HEAD + "\n".join(rows) + "\n")
    return p


def qtm(tmp_path, frames, name="q.tsv"):
    head = (f"NO_OF_FRAMES\t{len(frames)}\nNO_OF_CAMERAS\t8\nNO_OF_MARKERS\t1\nFREQUENCY\t100\nMARKER_NAMES\tA\n"
            "Frame\tTime\tA X\tA Y\tA Z\n")
    rows = [f"{f}\t{(f - 1) / 100:.5f}\t{k}.5\t1.0\t2.0" for k, f in enumerate(frames)]
    p = tmp_path / name
    p.write_text(head + "\n".join(rows) + "\n")
    return p


def refused(p, match: str, reader=read_markers) -> str:
    with pytest.raises(InputError, match=match) as e:
        reader(p)
    msg = str(e.value)
    assert str(p) in msg and "\n" not in msg
    return msg


# ------------------------------------------------------------------------------------------ refusals

def test_reversed_vicon_rows_are_refused_with_the_line(tmp_path):
    p = vicon(tmp_path, list(reversed(vicon_rows(range(123, 153)))))
    msg = refused(p, "not strictly increasing")
    assert f"line {FIRST_DATA_LINE + 1}:" in msg and "frame 152 then 151" in msg
    # `inspect` refuses it too (it used to say "first frame 123")
    res = CliRunner().invoke(cli, ["inspect", str(p)])
    assert res.exit_code == 1 and "not strictly increasing" in res.output and "first frame" not in res.output


def test_duplicate_frame_is_refused(tmp_path):
    frames = list(range(1, 31))
    frames[10] = frames[9]
    msg = refused(vicon(tmp_path, vicon_rows(frames)), "repeated")
    assert f"line {FIRST_DATA_LINE + 10}:" in msg


@pytest.mark.parametrize("value", ["1e12", "1000000000000", "-3", "2147483648"])
def test_frame_number_out_of_range_is_refused(tmp_path, value):
    rows = vicon_rows(range(1, 31))
    rows[20] = value + rows[20][rows[20].index(","):]
    msg = refused(vicon(tmp_path, rows), "out of range")
    assert f"line {FIRST_DATA_LINE + 20}:" in msg


def test_every_frame_1e18_is_refused(tmp_path):
    rows = [("1e18" + r[r.index(","):]) for r in vicon_rows(range(30))]
    refused(vicon(tmp_path, rows), "out of range")


@pytest.mark.parametrize("value, match", [("", "no frame number"), ("7.5", "not a whole number")])
def test_empty_or_fractional_frame_is_refused(tmp_path, value, match):
    rows = vicon_rows(range(1, 31))
    rows[6] = value + rows[6][rows[6].index(","):]
    msg = refused(vicon(tmp_path, rows), match)
    assert f"line {FIRST_DATA_LINE + 6}:" in msg


def test_jump_leaving_more_frames_missing_than_rows_is_refused(tmp_path):
    frames = list(range(1, 21)) + list(range(100, 110))     # 79 missing for 30 rows
    msg = refused(vicon(tmp_path, vicon_rows(frames)), "frames missing")
    assert "from 20 to 100" in msg and f"line {FIRST_DATA_LINE + 20}:" in msg


def test_qtm_and_wide_frame_columns_are_checked(tmp_path):
    refused(qtm(tmp_path, [1, 2, 3, 5, 4, 6]), "not strictly increasing", read_qtm_tsv)
    p = tmp_path / "w.csv"
    p.write_text("frame,time,A_x,A_y,A_z\n5,0.00,1,2,3\n5,0.01,1,2,3\n")
    refused(p, "repeated", read_wide_csv)


def test_qtm_counts_must_be_counts(tmp_path):
    p = qtm(tmp_path, [1, 2, 3])
    p.write_text(p.read_text().replace("NO_OF_FRAMES\t3", "NO_OF_FRAMES\t-3"))
    refused(p, "NO_OF_FRAMES reads '-3', not a count", read_qtm_tsv)


# ------------------------------------------------------------------------------------- dropped frames

def test_dropped_frames_become_gap_rows_with_a_warning(tmp_path):
    frames = [10, 11, 12, 15, 16, 17, 18, 20]              # 13, 14 and 19 dropped
    p = vicon(tmp_path, vicon_rows(frames))
    m = read_vicon_csv(p)
    assert m.first_frame == 10 and m.n_frames == 11
    assert m.source_frame.tolist() == list(range(10, 21))
    kept = np.isin(m.source_frame, frames)
    assert m.valid[kept].all() and not m.valid[~kept].any() and np.isnan(m.xyz[~kept]).all()
    np.testing.assert_array_equal(m.xyz[kept, 0], [[k + 0.5, -k, 1000 + k] for k in range(len(frames))])
    note = next(w for w in m.warnings if "dropped frame" in w)
    assert note.startswith("v.csv: 3 dropped frame(s) in 2 gap(s)")
    assert f"lines {FIRST_DATA_LINE + 2}-{FIRST_DATA_LINE + 3} (frames 13-14)" in note
    assert f"lines {FIRST_DATA_LINE + 6}-{FIRST_DATA_LINE + 7} (frame 19)" in note


def test_qtm_dropped_frames(tmp_path):
    m = read_qtm_tsv(qtm(tmp_path, [1, 2, 4, 5]))
    assert m.n_frames == 5 and m.valid[:, 0].tolist() == [True, True, False, True, True]
    assert any("1 dropped frame(s)" in w for w in m.warnings)


def test_wide_csv_rate_is_not_lowered_by_dropped_frames(tmp_path):
    frames = [1, 2, 3, 4, 6, 7, 8, 9, 10]
    rows = "".join(f"{f},{(f - 1) / 50!r},{f},0,0\n" for f in frames)
    p = tmp_path / "w.csv"
    p.write_text("frame,time,A_x,A_y,A_z\n" + rows)
    m = read_wide_csv(p)
    assert m.rate_hz == 50.0 and m.n_frames == 10 and not m.valid[4, 0]
    assert not any("uneven" in w for w in m.warnings)


def test_filled_copy_of_a_file_with_dropped_frames(tmp_path):
    frames = [1, 2, 3, 5, 6]
    rows = vicon_rows(frames)
    rows[1] = "2,0,,,,1,2,3"                                # a gap in marker A on frame 2
    src = vicon(tmp_path, rows)
    orig = read_text_export(src, "vicon_csv")
    m = orig[0]
    filled = Markers(labels=m.labels, xyz=np.nan_to_num(m.xyz, nan=7.0), valid=np.ones_like(m.valid),
                     rate_hz=m.rate_hz, first_frame=m.first_frame, units=m.units)
    dest = tmp_path / "filled.csv"
    n = write_filled_text(src, dest, filled, "vicon_csv", original=orig)
    assert n == 1                                           # frame 2's A; frame 4 has no line to write into
    back = read_vicon_csv(dest)
    assert back.n_frames == 6 and back.valid[1].all() and not back.valid[3].any()
    np.testing.assert_array_equal(back.xyz[1, 0], [7.0, 7.0, 7.0])


def test_contiguous_frames_give_the_same_markers_as_before(tmp_path):
    m = read_vicon_csv(vicon(tmp_path, vicon_rows(range(5, 35))))
    assert m.n_frames == 30 and m.first_frame == 5 and m.valid.all() and m.warnings == []


# --------------------------------------------------------------------------------------- coordinates

def test_infinite_partial_and_absurd_samples_become_gaps_with_warnings(tmp_path):
    rows = vicon_rows(range(1, 11))
    rows[2] = "3,0,inf,1,2,1,2,3"           # infinite
    rows[4] = "5,0,1,,2,1,2,3"              # only X and Z of A
    rows[6] = "7,0,1,2,3,5e9,2,3"           # 5,000 km: corrupted
    m = read_vicon_csv(vicon(tmp_path, rows))
    assert m.valid[:, 0].tolist() == [True, True, False, True, False, True, True, True, True, True]
    assert m.valid[:, 1].tolist() == [True] * 6 + [False] + [True] * 3
    assert np.isnan(m.xyz[~m.valid]).all()
    text = " | ".join(m.warnings)
    assert "1 samples with an infinite coordinate" in text
    assert "1 samples with only some of X, Y, Z" in text and "frame 5" in text
    assert "farther than 1,000,000 mm" in text and "S:B" in text


def test_units_count_for_the_physical_bound(tmp_path):
    rows = vicon_rows(range(1, 5))
    rows[1] = "2,0,1,2,3,999,2,3"                            # 999 m: below 1 km
    rows[2] = "3,0,1,2,3,1001,2,3"                           # 1001 m: beyond
    p = tmp_path / "m.csv"
    p.write_text(HEAD.replace("mm", "m") + "\n".join(rows) + "\n")
    m = read_vicon_csv(p)
    assert m.valid[:, 1].tolist() == [True, True, False, True]


def test_c3d_absurd_and_infinite_coordinates_become_gaps(tmp_path):
    rng = np.random.default_rng(4)
    src = Markers(labels=["A", "B"], xyz=rng.uniform(-900, 900, (20, 2, 3)), valid=np.ones((20, 2), bool),
                  rate_hz=100.0)
    p = tmp_path / "f.c3d"
    write_c3d(p, src)
    b = bytearray(p.read_bytes())
    start = (struct.unpack_from("<H", b, 16)[0] - 1) * 512
    frame = 4 * 4 * 2                                       # two points of four float words
    struct.pack_into("<f", b, start + 5 * frame + 16, 3e9)    # frame 6, point B, x: 3,000 km
    struct.pack_into("<f", b, start + 7 * frame, float("inf"))  # frame 8, point A, x
    p.write_bytes(bytes(b))
    m = read_c3d(p)
    assert not m.valid[5, 1] and not m.valid[7, 0] and m.valid.sum() == 38
    assert np.isnan(m.xyz[5, 1]).all()
    text = " | ".join(m.warnings)
    assert "1 samples farther than 1,000,000 mm" in text and "B" in text
    assert "1 samples with an infinite coordinate" in text


def test_sample_capture_has_nothing_beyond_the_bound(tmp_path):
    from tests.helpers import SAMPLE

    shutil.copy(SAMPLE / "mocap" / "neutral.c3d", tmp_path / "n.c3d")
    assert not any("farther" in w or "infinite" in w for w in read_c3d(tmp_path / "n.c3d").warnings)
