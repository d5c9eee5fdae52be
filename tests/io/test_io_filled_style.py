"""``gazepipe fill`` writes a text export's new cells in the source's own style (issue 46): the significant
digits or fixed decimals its numbers carry, and gaps spelled as it spells them."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.io.capture import read_markers
from gazepipe.io.filled_text import write_filled_text
from gazepipe.io.marker_csv import read_text_export
from gazepipe.stages.clean.standalone import fill_capture
from tests.helpers import TESTS

TEXT = TESTS / "data" / "corpus" / "text"


def _changed_cells(before: bytes, after: bytes, sep: bytes) -> list[tuple[int, int, bytes, bytes]]:
    """(line, column, old, new) of every cell that differs between two files of the same lines."""
    out = []
    a_lines, b_lines = before.split(b"\n"), after.split(b"\n")
    assert len(a_lines) == len(b_lines)
    for i, (a, b) in enumerate(zip(a_lines, b_lines, strict=True)):
        if a != b:
            a_cells, b_cells = a.rstrip(b"\r").split(sep), b.rstrip(b"\r").split(sep)
            assert len(a_cells) == len(b_cells)
            out += [(i, j, x, y) for j, (x, y) in enumerate(zip(a_cells, b_cells, strict=True)) if x != y]
    return out


def _significant(cell: bytes) -> int:
    mantissa = re.sub(rb"[eE].*$", b"", cell.lstrip(b"-"))
    return len(mantissa.replace(b".", b"").lstrip(b"0"))


def test_nexus_fill_writes_six_significant_digits(tmp_path):
    """The real Nexus 2 export writes 6 significant digits (``-276.862``, ``44.1628``): its filled cells too,
    each the filled value as Nexus would print it; nothing else changes."""
    out = tmp_path / "filled.csv"
    res = CliRunner().invoke(cli, ["fill", str(TEXT / "pyomeca_markers.csv"), str(out), "--json"])
    assert res.exit_code == 0, res.output
    src = (TEXT / "pyomeca_markers.csv").read_bytes()
    cells = _changed_cells(src, out.read_bytes(), b",")
    orig = read_markers(TEXT / "pyomeca_markers.csv")
    filled, summary, _ = fill_capture(orig)   # the command's default, which is the clean stage's
    assert summary == {k: v for k, v in json.loads(res.stdout).items() if k in summary}
    gaps = ~orig.valid & filled.valid
    assert len(cells) == 3 * int(gaps.sum()) > 0 and all(old == b"" for _, _, old, _ in cells)
    # in file order (frame, then marker, then X, Y, Z): each the filled value as Nexus prints it, %.6g
    assert [new for *_, new in cells] == [f"{v:.6g}".encode() for v in filled.xyz[gaps].ravel()]
    assert max(_significant(new) for *_, new in cells) == 6


def test_nexus1_fill_writes_its_own_ten_digits(tmp_path):
    """The real Nexus 1.x export writes up to 10 significant digits: a gap cut into it is filled with 10."""
    src = (TEXT / "pycgm_Sample_Static_first60.csv").read_bytes()
    lines = src.split(b"\n")
    for i in range(11 + 20, 11 + 26):                     # frames 21-26 of LFHD (columns 1-3) made a gap
        cells = lines[i].split(b",")
        cells[1:4] = [b"", b"", b""]
        lines[i] = b",".join(cells)
    gap = tmp_path / "gap.csv"
    gap.write_bytes(b"\n".join(lines))
    out = tmp_path / "out.csv"
    res = CliRunner().invoke(cli, ["fill", str(gap), str(out)])
    assert res.exit_code == 0, res.output
    cells = _changed_cells(gap.read_bytes(), out.read_bytes(), b",")
    assert len(cells) == 18 and {j for _, j, _, _ in cells} == {1, 2, 3}
    assert max(_significant(new) for *_, new in cells) == 10
    m = read_markers(out)
    np.testing.assert_allclose(m.xyz[20:26, 0], read_markers(TEXT / "pycgm_Sample_Static_first60.csv").xyz[20:26, 0],
                               atol=5.0)


QTM_HEAD = ("NO_OF_FRAMES\t{n}\nNO_OF_CAMERAS\t8\nNO_OF_MARKERS\t2\nFREQUENCY\t100\nNO_OF_ANALOG\t0\n"
            "ANALOG_FREQUENCY\t0\nDESCRIPTION\t--\nTIME_STAMP\t2021-03-04, 10:11:12.000\t0.0\nDATA_INCLUDED\t3D\n"
            "MARKER_NAMES\tA\tB\nTRAJECTORY_TYPES\tMeasured\tMeasured\nFrame\tTime\tA X\tA Y\tA Z\tB X\tB Y\tB Z\n")


@pytest.mark.parametrize("gap", ["nan", "NaN", "", "0.000"])
def test_a_sample_taken_out_is_spelled_as_the_file_spells_gaps(tmp_path, gap):
    """A QTM export that spells its gaps ``nan`` (or empty, or QTM's old zeros) gets a removed spike spelled the
    same way, and a filled sample with its three decimals."""
    n = 60
    t = np.arange(n) / 100.0
    rows = []
    for i in range(n):
        a = [f"{100 + 10 * np.sin(t[i]):.3f}", f"{200 + t[i]:.3f}", f"{1000.0:.3f}"]
        b = [f"{300 + 5 * t[i]:.3f}", "50.250", "990.125"] if not 20 <= i < 24 else [gap] * 3
        rows.append("\t".join([str(i + 1), f"{t[i]:.5f}", *a, *b]))
    p = tmp_path / "q.tsv"
    p.write_text(QTM_HEAD.format(n=n) + "\n".join(rows) + "\n")
    orig, layout, raw = read_text_export(p, "qtm_tsv")
    assert not orig.valid[20:24, 1].any() and orig.valid[:, 0].all()
    removed = np.zeros_like(orig.valid)
    removed[40, 0] = True                                  # a spike taken out of A, left a gap
    filled = dataclasses.replace(orig, xyz=orig.xyz.copy(), valid=orig.valid.copy())
    filled.valid[40, 0] = False
    filled.xyz[40, 0] = np.nan
    filled.valid[20:24, 1] = True
    filled.xyz[20:24, 1] = [300.12345, 50.25, 990.125]
    out = tmp_path / "out.tsv"
    assert write_filled_text(p, out, filled, "qtm_tsv", removed=removed, original=(orig, layout, raw)) == 5
    cells = _changed_cells(raw, out.read_bytes(), b"\t")
    spike = [new for i, j, _, new in cells if j in (2, 3, 4)]
    assert spike == [gap.encode()] * 3
    fills = {new for i, j, _, new in cells if j == 5}
    assert fills == {b"300.123"}
    assert not read_markers(out).valid[40, 0]


def test_a_file_without_gaps_spells_new_gaps_as_empty_cells(tmp_path):
    text = QTM_HEAD.format(n=30) + "".join(f"{i + 1}\t{i / 100:.5f}\t1.000\t2.000\t{i}.500\t4.000\t5.000\t6.000\n"
                                           for i in range(30))
    p = tmp_path / "q.tsv"
    p.write_text(text)
    orig, layout, raw = read_text_export(p, "qtm_tsv")
    removed = np.zeros_like(orig.valid)
    removed[5, 1] = True
    filled = dataclasses.replace(orig, valid=orig.valid & ~removed)
    write_filled_text(p, tmp_path / "o.tsv", filled, "qtm_tsv", removed=removed, original=(orig, layout, raw))
    assert [new for *_, new in _changed_cells(raw, (tmp_path / "o.tsv").read_bytes(), b"\t")] == [b""] * 3


def _mirror_head_swapped(n: int = 660, rate: float = 30.0) -> tuple[np.ndarray, list[str]]:
    """(n, 6, 3) mm at ``rate``: a rigid head of two mirror pairs, a top and a chin marker, turning slowly, with its
    back pair (2, 3) under each other's names over frames 200-260 (22 s: long enough for swaps to be looked for)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    body = np.array([[75, 60, 130], [-75, 60, 130], [75, -80, 130], [-75, -80, 130], [0, -10, 195], [0, 95, 50.0]])
    turns = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.01, (n, 3)), axis=0)).as_matrix()
    xyz = np.einsum("tij,mj->tmi", turns, body) + rng.normal(0, 0.5, (n, 6, 3)) + [0.0, 0.0, 1600.0]
    xyz[200:260, [2, 3]] = xyz[200:260, [3, 2]]
    xyz[400:410, 0] = np.nan                                   # a gap to fill as well
    return xyz, ["HFL", "HFR", "HBL", "HBR", "HTOP", "CHIN"]


@pytest.mark.parametrize("spikes", [False, True])
def test_fill_json_counts_agree(tmp_path, spikes):
    """``fill --json``: every sample counted once under one fill code, the samples put back under their own
    names counted as ``swap_repaired`` there and as ``samples_repaired`` under ``swaps`` (less any then taken out
    as spikes), per marker as in total."""
    from tests.helpers import write_wide_csv

    xyz, labels = _mirror_head_swapped()
    write_wide_csv(tmp_path / "head.csv", labels, xyz, 30.0)
    args = ["fill", str(tmp_path / "head.csv"), str(tmp_path / "out.csv"), "--repair-swaps", "--json"]
    res = CliRunner().invoke(cli, args + (["--remove-spikes"] if spikes else []))
    assert res.exit_code == 0, res.output
    s = json.loads(res.stdout)
    sw = s["swaps"]
    assert sw["looked_for"] and sw["samples_repaired"] == 120 and sw["stretches"][0]["markers"] == ["HBL", "HBR"]
    assert s["samples"]["swap_repaired"] == sw["samples_repaired"] - sw["samples_removed_as_spikes"] > 0
    assert sum(s["samples"].values()) == s["frames"] * s["markers"]
    for name in s["samples"]:
        assert sum(m.get(name, 0) for m in s["per_marker"].values()) == s["samples"][name]
    assert s["gaps"]["filled"] + s["gaps"]["unfilled"] == s["gaps"]["total"] >= 1
