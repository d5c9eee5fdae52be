"""One name per marker across a session's takes, whatever program exported each (issue 46): the ``Subject:``
prefix is stripped from every label when the markerset's names lack it; collisions are reported, never merged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.errors import InputError
from gazepipe.io.session_toml import load_markerset, session_labels
from tests.helpers import TINY_MARKERSET, make_tiny_session, tiny_motion


def _markerset(tmp_path: Path):
    p = tmp_path / "markerset.toml"
    p.write_text(TINY_MARKERSET)
    return load_markerset(p)


def test_prefix_stripped_from_every_label_listed_or_not(tmp_path):
    ms = _markerset(tmp_path)
    labels = ["p19:SACR", "p19:PL", "p19:PR", "p19:PB", "p19:H1", "p19:H2", "p19:H3", "Pole:POLE", "p19:LSHO",
              "RSHO", "*12"]
    new, notes = session_labels(ms, labels, "a.csv", "t")
    assert new == ["SACR", "PL", "PR", "PB", "H1", "H2", "H3", "POLE", "LSHO", "RSHO", "*12"] and notes == []


def test_collisions_after_stripping_are_reported_not_merged(tmp_path):
    ms = _markerset(tmp_path)
    base = ["SACR", "PL", "PR", "PB", "H1", "H2", "H3", "POLE"]
    # two subjects' shoulder markers: both kept, and said
    new, notes = session_labels(ms, [*base, "p19:LSHO", "p20:LSHO"], "a.csv", "t")
    assert new == [*base, "p19:LSHO", "p20:LSHO"]
    assert len(notes) == 1 and "'p19:LSHO', 'p20:LSHO'" in notes[0] and "'LSHO'" in notes[0]
    # a markerset marker under two names: the exact label is the marker, the prefixed one stays as it is
    new, notes = session_labels(ms, [*base, "p19:SACR"], "a.csv", "t")
    assert new == [*base, "p19:SACR"] and len(notes) == 1 and "'SACR'" in notes[0]
    # only prefixed ones: which is the marker cannot be told
    with pytest.raises(InputError, match="ambiguous"):
        session_labels(ms, [*base[1:], "a:SACR", "b:SACR"], "a.csv", "t")


def test_prefixed_markerset_names_match_as_written(tmp_path):
    p = tmp_path / "markerset.toml"
    p.write_text(TINY_MARKERSET.replace('"SACR"', '"p19:SACR"'))
    ms = load_markerset(p)
    labels = ["p19:SACR", "PL", "PR", "PB", "H1", "H2", "H3", "POLE", "p19:LSHO"]
    new, notes = session_labels(ms, labels, "a.csv", "t")
    assert new == labels and notes == []


def _nexus_csv(path: Path, labels: list[str], xyz: np.ndarray, rate_hz: float) -> None:
    """A Vicon Nexus 2 CSV export (Trajectories block) of ``labels``."""
    rows = ["Trajectories", f"{rate_hz:g}", ",," + ",".join(f"{lab},," for lab in labels),
            "Frame,Sub Frame," + ",".join("X,Y,Z" for _ in labels), ",," + ",".join("mm,mm,mm" for _ in labels)]
    rows += [f"{t + 1},0," + ",".join(f"{v:.6g}" for v in xyz[t].ravel()) for t in range(xyz.shape[0])]
    path.write_text("\r\n".join(rows) + "\r\n")


def test_a_session_of_csv_and_nexus_takes_names_each_marker_once(tmp_path):
    """The same shoulder marker is ``LSHO`` in the session's wide-CSV take and ``p19:LSHO`` in its Nexus CSV
    take: after ingest both takes call it ``LSHO``, as they call the markerset's markers."""
    root = make_tiny_session(tmp_path / "s", n_takes=2)
    labels, xyz = tiny_motion(7)
    extra = np.concatenate([xyz, xyz[:, :1] + [200.0, 0.0, 400.0]], axis=1)
    from tests.helpers import write_wide_csv

    write_wide_csv(root / "mocap" / "t0.csv", [*labels, "LSHO"], extra, 30.0)
    _nexus_csv(root / "mocap" / "t1.csv", [f"p19:{n}" for n in [*labels, "LSHO"]], extra, 30.0)
    res = CliRunner().invoke(cli, ["ingest", str(root), "--out", str(tmp_path / "out"), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code == 0, res.output
    names = {}
    for take in ("t0", "t1"):
        table = pq.read_table(tmp_path / "out" / "takes" / "tiny" / take / "markers_raw.parquet")
        names[take] = sorted(set(table.column("marker").to_pylist()))
    assert names["t0"] == names["t1"] == sorted([*labels, "LSHO"])
