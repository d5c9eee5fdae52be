"""`gazepipe export` and `gazepipe fill`: files users open in their own viewers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.io.c3d import read_c3d
from gazepipe.io.capture import read_markers
from gazepipe.io.export import write_markers
from gazepipe.model import FILL_CODES
from gazepipe.schemas.markers import table_to_markers
from tests.conftest import CORPUS, SAMPLE


def invoke(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


@pytest.fixture(scope="module")
def cleaned(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("out")
    res = invoke("clean", str(SAMPLE), "--out", str(out), "--executor", "serial")
    assert res.exit_code == 0, res.stderr
    return out


def test_exported_c3d_reingests_with_same_coordinates_and_gap_mask(cleaned, tmp_path):
    take = "follow_standing_01"
    table = pq.read_table(cleaned / "takes" / "session01" / take / "markers.parquet")
    markers, frames, fill, _ = table_to_markers(table)
    assert (fill == FILL_CODES["unfilled"]).any()  # the take has gaps longer than max_gap_s: the mask matters
    dest = tmp_path / "t.c3d"
    res = invoke("export", str(cleaned), take, "--to", str(dest))
    assert res.exit_code == 0, res.stderr
    for reader in ("ezc3d", "c3d"):
        back = read_c3d(dest) if reader == "ezc3d" else _read_with_py_c3d(dest)
        assert back.labels == markers.labels
        np.testing.assert_array_equal(back.valid, markers.valid)
        # C3D float storage is float32: compare at its precision (values are up to ~3000 mm)
        np.testing.assert_allclose(back.xyz[back.valid], markers.xyz[markers.valid], atol=5e-4)
        assert back.first_frame == markers.first_frame + frames[0]


def _read_with_py_c3d(path: Path):
    """Decode with the pure-Python `c3d` reader, independently of gazepipe's reader."""
    import c3d as pyc3d

    with open(path, "rb") as fh:
        reader = pyc3d.Reader(fh)
        labels = [s.strip() for s in reader.point_labels]
        pts = np.stack([p for _, p, _ in reader.read_frames()])
        first = reader.first_frame
    from gazepipe.model import Markers
    valid = pts[:, :, 3] >= 0
    xyz = np.where(valid[..., None], pts[:, :, :3], np.nan)
    return Markers(labels=labels, xyz=xyz, valid=valid, rate_hz=1.0, first_frame=first)


def test_export_csv_round_trip(cleaned, tmp_path):
    dest = tmp_path / "t.csv"
    assert invoke("export", str(cleaned), "shift_y036_p12", "--to", str(dest)).exit_code == 0
    back = read_markers(dest)
    table = pq.read_table(cleaned / "takes" / "session01" / "shift_y036_p12" / "markers.parquet")
    markers, _, _, _ = table_to_markers(table)
    np.testing.assert_array_equal(back.valid, markers.valid)
    np.testing.assert_allclose(back.xyz[back.valid], markers.xyz[markers.valid], rtol=0, atol=1e-9)


def test_export_unknown_take_is_one_line(cleaned, tmp_path):
    res = invoke("export", str(cleaned), "nope", "--to", str(tmp_path / "x.c3d"))
    assert res.exit_code == 1 and "nope" in res.stderr and "Traceback" not in res.stderr


def test_fill_command_fills_hidden_samples_of_real_data(tmp_path):
    """Hide samples of a gap-free real capture, fill with the stand-alone filler, compare with the truth."""
    src = read_c3d(CORPUS / "c3d" / "Walking_Hybrid_2.c3d")
    # de-duplicate bit-identical trajectories (PROVENANCE: each is stored 2-3 times)
    _, keep = np.unique(np.nan_to_num(src.xyz).transpose(1, 0, 2).reshape(src.n_markers, -1), axis=0,
                        return_index=True)
    keep = np.sort(keep)
    full = src.valid[:, keep].all(axis=0)
    keep = keep[full]
    truth = src.xyz[:, keep]
    labels = [src.labels[i] for i in keep]
    valid = np.ones(truth.shape[:2], bool)
    rng = np.random.default_rng(3)
    for m in rng.choice(len(keep), 6, replace=False):
        start = int(rng.integers(30, truth.shape[0] - 60))
        valid[start:start + 24, m] = False
    from gazepipe.model import Markers
    holed = Markers(labels=labels, xyz=np.where(valid[..., None], truth, np.nan), valid=valid,
                    rate_hz=src.rate_hz, first_frame=src.first_frame)
    inp, out = tmp_path / "in.c3d", tmp_path / "out.c3d"
    write_markers(inp, holed)
    res = invoke("fill", str(inp), str(out), "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["gaps"]["total"] == 6 and summary["gaps"]["filled"] == 6
    back = read_c3d(out)
    assert back.valid.all()
    err = np.linalg.norm(back.xyz[~valid] - truth[~valid], axis=-1)
    assert err.mean() < 10.0          # 0.1 s gaps in gait at 240 Hz: a few mm expected; 10 mm is a loose bound
    np.testing.assert_allclose(back.xyz[valid], truth[valid], atol=5e-4)  # measured samples untouched (float32)


def test_fill_refuses_a_different_output_format(tmp_path):
    res = invoke("fill", str(CORPUS / "c3d" / "gait-raw.c3d"), str(tmp_path / "x.csv"))
    assert res.exit_code == 2 and "x.csv" in res.stderr
