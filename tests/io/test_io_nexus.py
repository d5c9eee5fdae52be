"""Vicon Nexus text exports as users have them (issue 46): the Nexus 1.x layout (real file), the Nexus CSV and
C3D of one capture (real files), and two Nexus 2 layouts rebuilt around the real CSV's own data (the layouts
described in the issue: trajectory magnitudes and counts in the block; the block after Devices, Joints, Model
Outputs and Segments blocks). Every reading is checked against an independent parse (pandas, ezc3d)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from gazepipe.io.c3d import read_c3d
from gazepipe.io.capture import inspect_capture, read_markers, sniff_format
from gazepipe.io.marker_csv import read_vicon_csv
from tests.helpers import TESTS

TEXT = TESTS / "data" / "corpus" / "text"
NEXUS1 = TEXT / "pycgm_Sample_Static_first60.csv"
NEXUS2 = TEXT / "pyomeca_markers.csv"
NEXUS2_C3D = TEXT.parent / "c3d" / "pyomeca_markers_analogs.c3d"


def _nexus2_parts() -> tuple[list[str], list[str]]:
    """The real Nexus 2 export's 5 header lines (title, rate, names, components, units) and its data rows."""
    lines = NEXUS2.read_bytes().decode().split("\r\n")
    while lines and not lines[-1]:
        lines.pop()
    return lines[:5], lines[5:]


def _floats(table: pd.DataFrame) -> np.ndarray:
    """A table of number strings as float64, each cell by Python's correctly rounded parser (NaN when empty)."""
    return np.vectorize(lambda c: float(c) if isinstance(c, str) else np.nan, otypes=[np.float64])(table.to_numpy())


def _pandas_nexus2() -> tuple[list[str], np.ndarray]:
    """Labels and (T, M, 3) coordinates of the real Nexus 2 CSV, parsed by pandas alone."""
    names = pd.read_csv(NEXUS2, skiprows=2, nrows=1, header=None).iloc[0]
    labels = [str(n) for n in names if isinstance(n, str)]
    data = _floats(pd.read_csv(NEXUS2, skiprows=5, header=None, dtype=str))
    return labels, data[:, 2:2 + 3 * len(labels)].reshape(len(data), len(labels), 3)


# ------------------------------------------------------------------------------------------- Nexus 1.x

def test_nexus1_export_reads_as_pandas_parses_it():
    """The real Nexus 1.x file: ``Title`` header, ``TRAJECTORIES``, ``100,Hz``, ``Field #``, no units row; its
    Plug-in Gait angles are model outputs, left out with a note; its unlabeled ``*N`` trajectories are markers."""
    assert sniff_format(NEXUS1) == "vicon_csv"
    m = read_markers(NEXUS1)
    names = pd.read_csv(NEXUS1, skiprows=9, nrows=1, header=None).iloc[0]
    groups = [(j, str(n)) for j, n in enumerate(names) if isinstance(n, str)]
    angles = [n for _, n in groups if n.endswith(("Angles", "Angle"))]
    markers = [(j, n) for j, n in groups if n not in angles]
    assert len(groups) == 141 and len(angles) == 26
    assert m.labels == [n for _, n in markers] and m.model_outputs == angles
    assert m.labels[-4:] == ["*111", "*112", "*113", "*114"]
    data = _floats(pd.read_csv(NEXUS1, skiprows=11, header=None, dtype=str))
    assert m.n_frames == 60 and m.first_frame == 1 and m.rate_hz == 100.0 and m.units is None
    np.testing.assert_array_equal(data[:, 0], np.arange(1, 61))
    expect = np.stack([data[:, j:j + 3] for j, _ in markers], axis=1)
    assert m.valid.all()
    np.testing.assert_array_equal(m.xyz, expect)
    assert any("26 model output(s)" in w and "LHipAngles" in w for w in m.warnings)
    assert any("4 unlabeled trajectories" in w for w in m.warnings)
    info = inspect_capture(NEXUS1)
    assert info["n_markers"] == 115 and info["model_outputs"] == angles and info["format"] == "vicon_csv"


# ------------------------------------------------------------------------- Nexus 2: CSV and C3D of one capture

def test_nexus2_csv_and_c3d_of_one_capture_agree():
    """Nexus's CSV export and its C3D of the same capture: same labels, frames, rate and gaps; the values agree
    to the CSV's printed precision (6 significant digits) over the C3D's 4-byte reals."""
    csv, c3d = read_markers(NEXUS2), read_c3d(NEXUS2_C3D)
    assert csv.labels == c3d.labels and len(csv.labels) == 51
    assert (csv.n_frames, csv.first_frame, csv.rate_hz) == (c3d.n_frames, c3d.first_frame, c3d.rate_hz) == \
        (580, 1, 100.0)
    np.testing.assert_array_equal(csv.valid, c3d.valid)
    assert 0 < (~csv.valid).sum() < csv.valid.size
    v = c3d.xyz[c3d.valid]
    digit = 10.0 ** (np.floor(np.log10(np.abs(v))) - 5)             # the 6th significant digit's unit
    assert (np.abs(csv.xyz[csv.valid] - v) <= 0.5 * digit * (1 + 1e-6) + 1.2e-7 * np.abs(v)).all()
    labels, xyz = _pandas_nexus2()
    assert labels == csv.labels
    np.testing.assert_array_equal(csv.xyz[csv.valid], xyz[csv.valid])


# ------------------------------------------------------------------- Nexus 2 layouts rebuilt around real data

def _with_magnitudes_and_count(count_first: bool) -> str:
    """The real Nexus 2 export as Nexus writes it with the trajectory-magnitude and count options: each marker's
    X, Y, Z followed by a ``| Subject:Marker |`` group over ``Magnitude( X )`` (mm, 6 significant digits), and a
    ``Trajectory Count`` column (labelled markers with data in the frame), after Sub Frame or at the end."""
    head, rows = _nexus2_parts()
    names = head[2].split(",")
    labels = [n for n in names if n]
    m = len(labels)
    data = [r.split(",") for r in rows]
    out_names, out_comps, out_units = ["", ""], ["Frame", "Sub Frame"], ["", ""]
    count_cols = (["Trajectory Count"], ["Count"], [""])
    if count_first:
        out_names, out_comps, out_units = (a + b for a, b in zip((out_names, out_comps, out_units), count_cols,
                                                                strict=True))
    for lab in labels:
        out_names += [lab, "", "", f"| {lab} |"]
        out_comps += ["X", "Y", "Z", "Magnitude( X )"]
        out_units += ["mm"] * 4
    if not count_first:
        out_names, out_comps, out_units = (a + b for a, b in zip((out_names, out_comps, out_units), count_cols,
                                                                strict=True))
    lines = [head[0], head[1], ",".join(out_names), ",".join(out_comps), ",".join(out_units)]
    for cells in data:
        xyz = cells[2:2 + 3 * m] + [""] * (3 * m - len(cells[2:2 + 3 * m]))
        seen = 0
        body: list[str] = []
        for k in range(m):
            x, y, z = xyz[3 * k: 3 * k + 3]
            mag = f"{math.sqrt(float(x) ** 2 + float(y) ** 2 + float(z) ** 2):.6g}" if x else ""
            seen += bool(x)
            body += [x, y, z, mag]
        row = cells[:2] + ([str(seen)] if count_first else []) + body + ([] if count_first else [str(seen)])
        lines.append(",".join(row))
    return "\r\n".join(lines) + "\r\n"


@pytest.mark.parametrize("count_first", [True, False])
def test_nexus2_block_with_magnitudes_and_trajectory_count(tmp_path, count_first):
    """Magnitude and count columns are no markers: skipped with a note, never the end of the read; the markers
    read exactly as in the export without them."""
    p = tmp_path / "mag.csv"
    p.write_text(_with_magnitudes_and_count(count_first), newline="")
    m, plain = read_markers(p), read_markers(NEXUS2)
    assert m.labels == plain.labels and m.rate_hz == plain.rate_hz and m.first_frame == plain.first_frame
    np.testing.assert_array_equal(m.valid, plain.valid)
    np.testing.assert_array_equal(m.xyz[m.valid], plain.xyz[plain.valid])
    note = [w for w in m.warnings if "without X/Y/Z" in w]
    assert len(note) == 1 and "52 column group(s)" in note[0] and "'Trajectory Count'" in note[0]
    assert "51 trajectory magnitude(s) (| boite:gauche_ext | …)" in note[0] and "(Count)" in note[0]


def _after_other_blocks(title: bool) -> str:
    """The real Nexus 2 export after the blocks Nexus writes before 'Trajectories' (in its alphabetical order:
    Devices at 10 samples a frame, Joints, Model Outputs, Segments), each ended by a blank line; optionally with a
    leading title line."""
    head, rows = _nexus2_parts()
    n = 40
    devices = ["Devices", "1000", ",,Imported AMTI OR6 Series Force Plate #1 - Force,,",
               "Frame,Sub Frame,Fx,Fy,Fz", ",,N,N,N"]
    devices += [f"{1 + i // 10},{i % 10},{0.1 * i:.6g},{-0.2 * i:.6g},{9.81 * i:.6g}" for i in range(10 * n)]
    joints = ["Joints", "100", ",,Daphnee:Thorax_Humerus,,,,,", "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ",
              ",,deg,deg,deg,mm,mm,mm"] + [f"{i + 1},0,1,2,3,4,5,6" for i in range(n)]
    outputs = ["Model Outputs", "100", ",,Daphnee:RShoulderAngles,,", "Frame,Sub Frame,X,Y,Z",
               ",,deg,deg,deg"] + [f"{i + 1},0,10.5,-3.25,{i}" for i in range(n)]
    segments = ["Segments", "100", ",,Daphnee:Humerus,,,,,", "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ",
                ",,deg,deg,deg,mm,mm,mm"] + [f"{i + 1},0,1,2,3,100,200,300" for i in range(n)]
    lines = (["Nexus export"] if title else []) + devices + [""] + joints + [""] + outputs + [""] + segments + [""]
    return "\r\n".join(lines + head + rows) + "\r\n"


@pytest.mark.parametrize("title", [False, True])
def test_nexus2_block_after_other_blocks(tmp_path, title):
    """A Trajectories block hundreds of lines down, after the other blocks, is found whatever the first line
    says: the format is sniffed from the whole header, and the markers read as in the export alone."""
    p = tmp_path / "blocks.csv"
    p.write_text(_after_other_blocks(title), newline="")
    assert sniff_format(p) == "vicon_csv"
    m, plain = read_markers(p), read_markers(NEXUS2)
    assert m.labels == plain.labels and m.n_frames == 580 and m.rate_hz == 100.0
    np.testing.assert_array_equal(m.xyz[m.valid], plain.xyz[plain.valid])
    np.testing.assert_array_equal(m.valid, plain.valid)


@pytest.mark.parametrize("first", ["\r\n", "\ufeff", '"Trajectories"\r\n'])
def test_nexus_first_line_variants_are_sniffed(tmp_path, first):
    """A blank first line, Excel's byte-order mark, a quoted title: still a Nexus export."""
    head, rows = _nexus2_parts()
    text = "\r\n".join(head + rows) + "\r\n"
    if first.startswith('"'):
        text = first + text.split("\r\n", 1)[1]
    else:
        text = first + text
    p = tmp_path / "v.csv"
    p.write_text(text, newline="", encoding="utf-8")
    assert sniff_format(p) == "vicon_csv"
    if not first.startswith('"'):           # a quoted title line is a hand edit the reader does not look for
        assert read_markers(p).labels == read_markers(NEXUS2).labels


def test_trajectories_block_with_only_non_markers_says_so(tmp_path):
    """A block of model outputs and magnitudes alone: refused, saying that none of its groups is a marker."""
    text = ("TRAJECTORIES\n100,Hz\n,LHipAngles,,,| S:A |\nField #,X,Y,Z,Magnitude( X )\n"
            "1,1,2,3,4\n2,1,2,3,4\n")
    p = tmp_path / "a.csv"
    p.write_text(text)
    with pytest.raises(Exception, match="none of them a marker"):
        read_vicon_csv(p)


def test_generated_nexus_export_reads_as_its_c3d(tmp_path):
    """The generator's Nexus CSV export of a take (``SynthConfig.nexus_csv``) against the same take written as
    C3D: labels with the subject's prefix, the same frames, rate and gaps, values to 6 significant digits."""
    from gazepipe.synth import SynthConfig, generate_session

    base = dict(follow_poses=(), shift_targets=((36.0, 12.0),), neutral_s=0.0, head_camera=False, face_takes=())
    as_c3d = generate_session(tmp_path / "c", seed=3, config=SynthConfig(**base))
    as_csv = generate_session(tmp_path / "v", seed=3, config=SynthConfig(**base, nexus_csv=1.0))
    c3d, csv = read_markers(as_c3d / "mocap" / "shift_y036_p12.c3d"), read_markers(as_csv / "mocap" /
                                                                                  "shift_y036_p12.csv")
    assert csv.labels == [f"p01:{lab}" for lab in c3d.labels] and csv.source_format == "vicon_csv"
    assert (csv.n_frames, csv.first_frame, csv.rate_hz) == (c3d.n_frames, c3d.first_frame, 30000 / 1001)
    np.testing.assert_array_equal(csv.valid, c3d.valid)
    v = c3d.xyz[c3d.valid]
    digit = 10.0 ** (np.floor(np.log10(np.abs(v))) - 5)
    assert (np.abs(csv.xyz[csv.valid] - v) <= 0.5 * digit * (1 + 1e-6) + 1.2e-7 * np.abs(v)).all()
