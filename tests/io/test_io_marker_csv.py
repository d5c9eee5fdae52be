"""Vicon Nexus CSV, QTM TSV and wide CSV readers; wide CSV round trip; format dispatch."""

from __future__ import annotations

import numpy as np
import pytest

from gazepipe.errors import InputError
from gazepipe.io.capture import inspect_capture, read_markers, sniff_format
from gazepipe.io.marker_csv import (
    read_qtm_tsv,
    read_vicon_csv,
    read_wide_csv,
    strip_subject_prefix,
    write_wide_csv,
)
from gazepipe.model import Markers
from tests.helpers.captures import QTM, QTM_OLD, VICON


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_vicon_csv_reads_trajectories_block(tmp_path):
    m = read_vicon_csv(_write(tmp_path, "t.csv", VICON))
    assert m.labels == ["Ann:LASI", "Ann:RASI", "Ann:HEADC"]
    assert m.rate_hz == 100.0 and m.first_frame == 12 and m.n_frames == 3
    assert m.units == "mm" and m.source_format == "vicon_csv"
    assert m.valid.tolist() == [[True, False, True], [True, True, True], [True, True, True]]
    np.testing.assert_array_equal(m.xyz[1, 1], [230.125, 25, 948.5])
    np.testing.assert_array_equal(m.xyz[0, 0], [101.5, -20.25, 950])
    assert np.isnan(m.xyz[0, 1]).all()
    # an explicit 0 in a Vicon export is a coordinate, not a gap (Nexus leaves gaps empty)
    np.testing.assert_array_equal(m.xyz[0, 2], [0, 0, 1600])


def test_vicon_prefix_stripping(tmp_path):
    p = _write(tmp_path, "t.csv", VICON)
    assert read_vicon_csv(p, strip_prefix=True).labels == ["LASI", "RASI", "HEADC"]
    assert read_vicon_csv(p, strip_prefix=["LASI", "HEADC"]).labels == ["LASI", "Ann:RASI", "HEADC"]
    # two subjects with the same marker name: stripping would merge them, so it is not done
    assert strip_subject_prefix(["A:X", "B:X", "A:Y"]) == ["A:X", "B:X", "Y"]


def test_vicon_units_in_metres_are_converted(tmp_path):
    text = VICON.replace(",,mm,mm,mm,mm,mm,mm,mm,mm,mm", ",,m,m,m,m,m,m,m,m,m")
    m = read_vicon_csv(_write(tmp_path, "t.csv", text))
    assert m.units == "m"
    np.testing.assert_allclose(m.xyz[0, 0], [101500, -20250, 950000])


def test_vicon_rate_from_argument_when_missing(tmp_path):
    text = VICON.replace("Trajectories\n100\n", "Trajectories\n\n".replace("\n\n", "\n,\n"))
    p = _write(tmp_path, "t.csv", text)
    with pytest.raises(InputError, match="rate"):
        read_vicon_csv(p)
    assert read_vicon_csv(p, rate_hz=59.94).rate_hz == pytest.approx(60000 / 1001, abs=0)


def test_qtm_tsv_reads_with_frame_time_columns(tmp_path):
    m = read_qtm_tsv(_write(tmp_path, "t.tsv", QTM))
    assert m.labels == ["HFL", "HFR"] and m.rate_hz == 120.0 and m.first_frame == 1 and m.n_frames == 3
    # HFR at (0, 0, 0) while elsewhere non-zero: QTM's missing-marker zero; empty HFL cells: a gap
    assert m.valid.tolist() == [[True, False], [True, True], [False, True]]
    np.testing.assert_array_equal(m.xyz[1, 1], [60, 20, 1699])
    np.testing.assert_array_equal(m.xyz[0, 0], [10, 20, 1700])


def test_qtm_tsv_old_layout_without_frame_column(tmp_path):
    m = read_qtm_tsv(_write(tmp_path, "old.tsv", QTM_OLD))
    assert m.labels == ["TOP"] and m.rate_hz == 100.0 and m.n_frames == 2 and m.first_frame == 1
    np.testing.assert_array_equal(m.xyz[:, 0], [[1.5, 2.5, 3.5], [1.25, 2.25, 3.25]])


def test_qtm_marker_count_mismatch_is_an_error(tmp_path):
    p = _write(tmp_path, "bad.tsv", QTM.replace("NO_OF_MARKERS\t2", "NO_OF_MARKERS\t3"))
    with pytest.raises(InputError, match="NO_OF_MARKERS") as e:
        read_qtm_tsv(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)


def _markers(rate=240.0, first=330, t=50, m=4, seed=0):
    rng = np.random.default_rng(seed)
    xyz = rng.normal(0, 500, (t, m, 3))
    valid = rng.random((t, m)) > 0.2
    xyz[~valid] = np.nan
    labels = [f"M{i}" for i in range(m - 1)] + ["Head:HTOP"]
    return Markers(labels=labels, xyz=xyz, valid=valid, rate_hz=rate, first_frame=first, units="mm")


@pytest.mark.parametrize("rate", [240.0, 30000 / 1001, 100.0])
def test_wide_csv_round_trip(tmp_path, rate):
    src = _markers(rate=rate)
    p = tmp_path / "w.csv"
    write_wide_csv(p, src)
    back = read_wide_csv(p)
    assert back.labels == src.labels and back.first_frame == src.first_frame
    assert back.rate_hz == rate
    np.testing.assert_array_equal(back.valid, src.valid)
    np.testing.assert_array_equal(back.xyz, src.xyz)  # shortest round-trip floats: exact
    write_wide_csv(tmp_path / "w2.csv", back)
    assert (tmp_path / "w2.csv").read_bytes() == p.read_bytes()


def test_wide_csv_without_time_needs_rate(tmp_path):
    p = _write(tmp_path, "w.csv", "frame,A_x,A_y,A_z\n5,1,2,3\n6,,,\n")
    with pytest.raises(InputError, match="rate"):
        read_wide_csv(p)
    m = read_wide_csv(p, rate_hz=50)
    assert m.first_frame == 5 and m.rate_hz == 50 and m.valid[:, 0].tolist() == [True, False]


def test_wide_csv_garbage_cell_is_an_error(tmp_path):
    p = _write(tmp_path, "w.csv", "frame,time,A_x,A_y,A_z\n1,0,1,2,3\n2,0.01,1,oops,3\n")
    with pytest.raises(InputError, match="oops"):
        read_wide_csv(p)


def test_dispatch_and_inspect(tmp_path):
    v = _write(tmp_path, "v.csv", VICON)
    q = _write(tmp_path, "q.tsv", QTM)
    w = tmp_path / "w.csv"
    write_wide_csv(w, _markers())
    assert [sniff_format(x) for x in (v, q, w)] == ["vicon_csv", "qtm_tsv", "wide_csv"]
    assert read_markers(v).source_format == "vicon_csv"
    assert read_markers(q).source_format == "qtm_tsv"
    assert read_markers(w).source_format == "wide_csv"
    info = inspect_capture(q)
    assert info["frames"] == 3 and info["n_markers"] == 2 and info["rate_hz"] == 120.0
    assert [d["label"] for d in info["markers"]] == ["HFL", "HFR"]
    assert [d["gap_fraction"] for d in info["markers"]] == pytest.approx([1 / 3, 1 / 3])
    assert info["units"] is None and info["format"] == "qtm_tsv"
    with pytest.raises(InputError, match="not found"):
        read_markers(tmp_path / "missing.csv")
    with pytest.raises(InputError, match="unknown capture format"):
        read_markers(_write(tmp_path, "x.bin", "hello"))


def test_crlf_and_trailing_separators(tmp_path):
    crlf = read_vicon_csv(_write(tmp_path, "crlf.csv", VICON.replace("\n", "\r\n")))
    ref = read_vicon_csv(_write(tmp_path, "lf.csv", VICON))
    assert crlf.labels == ref.labels
    np.testing.assert_array_equal(crlf.xyz, ref.xyz)
    # QTM rows ending in a tab: an empty trailing cell, not an extra column
    tabbed = "\n".join(ln + "\t" if ln[:1].isdigit() else ln for ln in QTM.splitlines()) + "\n"
    np.testing.assert_array_equal(read_qtm_tsv(_write(tmp_path, "tab.tsv", tabbed)).xyz,
                                  read_qtm_tsv(_write(tmp_path, "q.tsv", QTM)).xyz)


def test_row_with_extra_values_is_an_error(tmp_path):
    p = _write(tmp_path, "w.csv", "frame,time,A_x,A_y,A_z\n1,0,1,2,3\n2,0.01,1,2,3,99\n")
    with pytest.raises(InputError, match="does not fit 5 columns"):
        read_wide_csv(p)


def test_qtm_old_layout_with_frame_time_and_trailing_tab(tmp_path):
    text = QTM_OLD.replace("1.5\t2.5\t3.5\n", "7\t0.00\t1.5\t2.5\t3.5\t\n").replace(
        "1.25\t2.25\t3.25\n", "8\t0.01\t\t\t\t\n")
    m = read_qtm_tsv(_write(tmp_path, "old2.tsv", text))
    assert m.first_frame == 7 and m.n_frames == 2
    np.testing.assert_array_equal(m.xyz[0, 0], [1.5, 2.5, 3.5])
    assert m.valid[:, 0].tolist() == [True, False]


def _qtm_rows(times: list[str], rate: str = "120") -> str:
    """A QTM export with a Frame and a Time column: frames 1.. with the given Time cells."""
    head = QTM.split("Frame\tTime")[0].replace("FREQUENCY\t120", f"FREQUENCY\t{rate}").replace(
        "NO_OF_FRAMES\t3", f"NO_OF_FRAMES\t{len(times)}")
    rows = [f"{i + 1}\t{t}\t{i}.0\t1.0\t1700.0\t5.0\t6.0\t7.0" for i, t in enumerate(times)]
    return head + "Frame\tTime\tHFL X\tHFL Y\tHFL Z\tHFR X\tHFR Y\tHFR Z\n" + "\n".join(rows) + "\n"


@pytest.mark.parametrize("bad, found", [("-1", "goes back"), ("nan", "no time value"), ("inf", "no time value"),
                                        ("", "no time value")])
def test_qtm_time_column_beside_frames_is_checked(tmp_path, bad, found):
    times = [f"{i / 120:.5f}" for i in range(8)]
    times[4] = bad
    p = _write(tmp_path, "t.tsv", _qtm_rows(times))
    with pytest.raises(InputError) as ei:
        read_qtm_tsv(p)
    msg = str(ei.value)
    assert str(p) in msg and found in msg and "line 17" in msg and "\n" not in msg, msg


def test_qtm_reversed_time_column_is_refused(tmp_path):
    times = [f"{i / 120:.5f}" for i in range(8)][::-1]
    with pytest.raises(InputError, match="goes back"):
        read_qtm_tsv(_write(tmp_path, "t.tsv", _qtm_rows(times)))


def test_qtm_time_jump_and_rate_disagreement_are_noted_with_the_line(tmp_path):
    times = [f"{i / 120:.5f}" for i in range(8)]
    times[-1] = "1e12"
    m = read_qtm_tsv(_write(tmp_path, "t.tsv", _qtm_rows(times)))
    jump = [w for w in m.warnings if "time column steps" in w]
    assert jump and jump[0].startswith("line 20:"), m.warnings
    assert m.rate_hz == 120 and m.n_frames == 8   # the frame numbers and FREQUENCY stand
    slow = read_qtm_tsv(_write(tmp_path, "s.tsv", _qtm_rows([f"{i / 100:.5f}" for i in range(8)])))
    assert any("100 Hz" in w and "120 Hz" in w for w in slow.warnings), slow.warnings


def test_qtm_times_with_too_few_decimals_for_the_rate_are_read(tmp_path):
    """QTM writes Time with 3 decimals: at 2 kHz consecutive frames can share a time. That is noted, not
    refused (the frame numbers place the rows)."""
    times = [f"{i / 2000:.3f}" for i in range(40)]
    m = read_qtm_tsv(_write(tmp_path, "t.tsv", _qtm_rows(times, rate="2000")))
    assert m.n_frames == 40 and m.rate_hz == 2000
    assert any("time column steps" in w for w in m.warnings)
    clean = read_qtm_tsv(_write(tmp_path, "c.tsv", _qtm_rows([f"{i / 120:.5f}" for i in range(40)])))
    assert not any("time column" in w for w in clean.warnings), clean.warnings


@pytest.mark.parametrize("fmt", ["vicon", "qtm_tabbed", "wide_shuffled"])
def test_rows_parsed_in_chunks_read_as_in_one_piece(tmp_path, monkeypatch, fmt):
    """Long exports are parsed a chunk of rows at a time into one array (and the coordinates are a view of
    it when their columns are consecutive): chunks of 7 rows give the same markers, gaps and warnings as one
    chunk, across trailing separators, gaps and a non-numeric fallback."""
    import gazepipe.io.marker_csv as mc

    rng = np.random.default_rng(3)
    n, labels = 50, ["A", "B", "C"]
    xyz = np.round(rng.normal(0, 400, (n, 3, 3)), 3)
    xyz[rng.random((n, 3)) < 0.1] = np.nan
    cell = lambda v: "" if np.isnan(v) else f"{v:.3f}"   # noqa: E731
    if fmt == "vicon":
        rows = ["Trajectories", "120", ",," + ",".join(f"S:{lab},," for lab in labels),
                "Frame,Sub Frame," + ",".join("X,Y,Z" for _ in labels), ",," + ",".join("mm,mm,mm" for _ in labels)]
        rows += [f"{t + 1},0," + ",".join(cell(v) for v in xyz[t].ravel()) for t in range(n)]
        path, read = tmp_path / "v.csv", read_vicon_csv
    elif fmt == "qtm_tabbed":
        rows = [f"NO_OF_FRAMES\t{n}", "NO_OF_MARKERS\t3", "FREQUENCY\t120", "MARKER_NAMES\t" + "\t".join(labels),
                "Frame\tTime\t" + "\t".join(f"{lab} {a}" for lab in labels for a in "XYZ")]
        rows += [f"{t + 1}\t{t / 120:.5f}\t" + "\t".join(cell(v) for v in xyz[t].ravel()) + "\t" for t in range(n)]
        path, read = tmp_path / "q.tsv", read_qtm_tsv
    else:   # columns in another order than marker by marker: the coordinates are gathered, not viewed
        names = [f"{lab}_{a}" for a in "xyz" for lab in labels]
        rows = ["frame,time," + ",".join(names)]
        rows += [f"{t},{t / 120:.6f}," + ",".join(cell(xyz[t, j, "xyz".index(a)]) for a in "xyz"
                                                  for j in range(3)) for t in range(n)]
        rows[9] = rows[9] + " "            # a stray space: still numbers
        path, read = tmp_path / "w.csv", read_wide_csv
    path.write_text("\n".join(rows) + "\n")
    whole = read(path)
    monkeypatch.setattr(mc, "_CHUNK_ROWS", 7)
    chunked = read(path)
    assert chunked.labels == whole.labels and chunked.warnings == whole.warnings
    np.testing.assert_array_equal(chunked.valid, whole.valid)
    np.testing.assert_array_equal(chunked.xyz, whole.xyz)
    np.testing.assert_array_equal(whole.xyz[whole.valid], xyz[~np.isnan(xyz).any(axis=2)])
