"""A marker CSV/TSV data row with fewer or more fields than its header is an error naming the file, the line
and the counts, never gaps to fill; trailing empty fields and blank lines stay allowed."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.errors import InputError
from gazepipe.io.capture import read_markers
from gazepipe.io.marker_csv import read_qtm_tsv, read_vicon_csv, read_wide_csv
from tests.helpers import write_wide_csv
from tests.helpers.captures import QTM, QTM_OLD
from tests.helpers.captures import VICON as NEXUS

# the readers' own Nexus fixture (Devices, Trajectories, Model Outputs), cut before its Model Outputs block
_CUT = NEXUS.index("\nModel Outputs")
VICON, VICON_AFTER = NEXUS[:_CUT], NEXUS[_CUT:]

def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_bytes(text.encode())
    return p


@pytest.fixture
def wide(tmp_path):
    """A wide CSV of 38 markers (116 fields: frame, time, 3 per marker), 500 rows, one short gap."""
    rng = np.random.default_rng(3)
    xyz = 1000 + np.cumsum(rng.normal(0, 1, (500, 38, 3)), axis=0)
    xyz[100:110, 3] = np.nan
    p = tmp_path / "full.csv"
    write_wide_csv(p, [f"M{i:02d}" for i in range(38)], xyz, 100.0)
    return p


def _cut_row(line: str, fields: int) -> str:
    return ",".join(line.split(",")[:fields])


def test_wide_csv_cut_mid_row_is_a_truncation(tmp_path, wide):
    lines = wide.read_text().splitlines()
    cut = _write(tmp_path, "cut.csv", "\n".join(lines[:411] + [_cut_row(lines[411], 36)]))
    with pytest.raises(InputError) as err:
        read_wide_csv(cut)
    assert str(err.value) == f"{cut}: line 412: 36 fields, header has 116 (file truncated?)"
    with pytest.raises(InputError, match="line 412: 36 fields"):    # also with its newline, via dispatch
        read_markers(_write(tmp_path, "cut2.csv", "\n".join(lines[:411] + [_cut_row(lines[411], 36)]) + "\n"))


def test_fill_refuses_a_truncated_csv(tmp_path, wide):
    lines = wide.read_text().splitlines()
    cut = _write(tmp_path, "cut.csv", "\n".join(lines[:411] + [_cut_row(lines[411], 36)]))
    out = tmp_path / "out.csv"
    res = CliRunner().invoke(cli, ["fill", str(cut), str(out)])
    assert res.exit_code == 1
    assert res.stderr.strip() == f"error: {cut}: line 412: 36 fields, header has 116 (file truncated?)"
    assert not out.exists()


def test_wide_csv_short_row_in_the_middle(tmp_path, wide):
    lines = wide.read_text().splitlines()
    lines[57] = _cut_row(lines[57], 36)
    p = _write(tmp_path, "mid.csv", "\n".join(lines) + "\n")
    with pytest.raises(InputError) as err:
        read_wide_csv(p)
    assert str(err.value) == f"{p}: line 58: 36 fields, header has 116"


def test_wide_csv_row_with_an_extra_value(tmp_path, wide):
    lines = wide.read_text().splitlines()
    lines[9] += ",7"
    p = _write(tmp_path, "extra.csv", "\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"extra.csv: line 10: 117 fields, header has 116 \(the row does not "
                                         r"fit 116 columns\)"):
        read_wide_csv(p)


def test_wide_csv_trailing_separators_blank_lines_and_crlf_still_read(tmp_path, wide):
    ref = read_wide_csv(wide)
    lines = wide.read_text().splitlines()
    trailing = _write(tmp_path, "trailing.csv", "\n".join(ln + "," for ln in lines) + "\n\n\n")
    header_only = _write(tmp_path, "header_comma.csv", "\n".join([lines[0] + ","] + lines[1:]) + "\n")
    crlf = _write(tmp_path, "crlf.csv", "\r\n".join(lines) + "\r\n\r\n")
    for p in (trailing, header_only, crlf):
        back = read_wide_csv(p)
        assert back.labels == ref.labels
        np.testing.assert_array_equal(back.xyz, ref.xyz)
    lines[57] = _cut_row(lines[57], 36)
    with pytest.raises(InputError, match="line 58: 36 fields, header has 116$"):
        read_wide_csv(_write(tmp_path, "crlf_mid.csv", "\r\n".join(lines) + "\r\n"))


def test_vicon_truncated_last_row(tmp_path):
    p = _write(tmp_path, "v.csv", VICON[:VICON.rindex("1,0,1602")])   # "14,0,103.5,-20.75,952,231.125,25.5,949,"
    with pytest.raises(InputError) as err:
        read_vicon_csv(p)
    assert str(err.value) == f"{p}: line 15: 9 fields, header has 11 (file truncated?)"


def test_vicon_short_row_before_the_next_block(tmp_path):
    text = VICON.replace("13,0,102.5,-20.5,951,230.125,25,948.5,0.5,0,1601", "13,0,102.5,-20.5,951")
    p = _write(tmp_path, "v.csv", text + VICON_AFTER)
    with pytest.raises(InputError) as err:
        read_vicon_csv(p)
    assert str(err.value) == f"{p}: line 14: 5 fields, header has 11"
    p = _write(tmp_path, "v2.csv", VICON.replace(",0,1602\n", ",0\n") + VICON_AFTER)
    with pytest.raises(InputError, match=r"line 15: 10 fields, header has 11$"):   # more blocks follow
        read_vicon_csv(p)


def test_vicon_trailing_empty_fields_blank_lines_and_blocks_still_read(tmp_path):
    ref = read_vicon_csv(_write(tmp_path, "ref.csv", VICON + VICON_AFTER))
    assert ref.n_frames == 3
    body = VICON.split("Trajectories")[1]
    padded = VICON.split("Trajectories")[0] + "Trajectories" + "\n".join(
        ln + ",," if ln[:2].isdigit() or ln.startswith(",,") else ln for ln in body.split("\n"))
    for text in (padded + VICON_AFTER, VICON + "\n\n\n", (VICON + VICON_AFTER).replace("\n", "\r\n"),
                 VICON.replace("X,Y,Z\n,,mm", "X,Y,Z,\n,,mm")):
        m = read_vicon_csv(_write(tmp_path, "v.csv", text))
        assert m.labels == ref.labels
        np.testing.assert_array_equal(m.xyz, ref.xyz)


def test_qtm_short_and_long_rows(tmp_path):
    p = _write(tmp_path, "q.tsv", QTM[:QTM.rindex("\t21.000")])
    with pytest.raises(InputError) as err:
        read_qtm_tsv(p)
    assert str(err.value) == f"{p}: line 15: 6 fields, header has 8 (file truncated?)"
    p = _write(tmp_path, "q2.tsv", QTM.replace("\t1700.500\t", "\t1700.500\t5\t"))
    with pytest.raises(InputError, match=r"q2.tsv: line 14: 9 fields, header has 8 \(the row does not fit 8"):
        read_qtm_tsv(p)
    tabbed = "\n".join(ln + "\t" if ln[:1].isdigit() else ln for ln in QTM.splitlines()) + "\n\n"
    np.testing.assert_array_equal(read_qtm_tsv(_write(tmp_path, "tab.tsv", tabbed)).xyz,
                                  read_qtm_tsv(_write(tmp_path, "ok.tsv", QTM)).xyz)


def test_qtm_old_layout_short_row(tmp_path):
    assert read_qtm_tsv(_write(tmp_path, "ok.tsv", QTM_OLD)).n_frames == 2
    p = _write(tmp_path, "old.tsv", QTM_OLD.replace("1.25\t2.25\t3.25", "1.25\t2.25"))
    with pytest.raises(InputError) as err:
        read_qtm_tsv(p)
    assert str(err.value) == f"{p}: line 12: 2 fields, expected 3 (3 per marker) (file truncated?)"
