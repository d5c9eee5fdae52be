"""The reading API (gazepipe.datasets) and the README's loading examples, on datasets built from generated
sessions by the dataset builder (tests/helpers/datasets.py)."""

from __future__ import annotations

import os
import runpy
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from gazepipe.datasets import open_dataset
from gazepipe.errors import ConfigError, InputError

EXAMPLES = Path(__file__).parent / "readme_examples"


@pytest.fixture(scope="module")
def datasets(generated_datasets) -> Path:
    return generated_datasets


@pytest.fixture(scope="module")
def rnn(datasets):
    return open_dataset(datasets / "gaze_rnn")


def _frame(ds) -> pd.DataFrame:
    """The identifier columns of every row, read with pyarrow straight from the files (not through the API)."""
    files = sorted(ds.path.glob("*/*/*.parquet"))
    cols = ["subject", "session", "take", "pose", "split", "mirrored", "segment", "frame"]
    return pd.concat([pq.read_table(f, columns=cols).to_pandas() for f in files], ignore_index=True)


def test_windows_stay_inside_segments(rnn):
    """Every 120-frame window holds consecutive frames of one take, one mirrored state and one segment, and
    the window's rows are the table's rows."""
    w = rnn.windows("train", normalise=False)
    ids = _frame(rnn)
    ids = ids[ids["split"] == "train"].reset_index(drop=True)
    assert len(w) > 100 and w.window == 120
    idx = w.starts[:, None] + np.arange(120)[None, :]
    for col in ("subject", "session", "take", "mirrored", "segment"):
        v = ids[col].to_numpy()[idx]
        assert (v == v[:, :1]).all(), col
    frames = ids["frame"].to_numpy()[idx]
    assert (np.diff(frames, axis=1) == 1).all()
    x_all = rnn.array("x", split="train")
    np.testing.assert_array_equal(w[5][0], x_all[w.starts[5]:w.starts[5] + 120])


def test_window_counts_and_dropped_rows(rnn):
    """Window count per run = (L − W) // S + 1, tails and short runs dropped and counted, recomputed from the
    identifier columns with pandas."""
    for split, window, stride in (("train", 120, 30), ("val", 120, 30), ("train", 200, 77)):
        ids = _frame(rnn)
        ids = ids[ids["split"] == split]
        lengths = ids.groupby(["subject", "session", "take", "mirrored", "segment"], sort=False).size().to_numpy()
        n = np.where(lengths >= window, (lengths - window) // stride + 1, 0)
        covered = np.where(n > 0, (n - 1) * stride + window, 0)
        w = rnn.windows(split, window=window, stride=stride)
        assert len(w) == n.sum()
        assert w.dropped_rows == (lengths - covered).sum() and w.short_runs == (lengths < window).sum()
        assert w.runs == len(lengths)
    assert (rnn.window, rnn.stride) == (120, 30)


def test_face_clean_chunks_default_to_200_by_50(datasets):
    ds = open_dataset(datasets / "face_clean")
    w = ds.windows("train", normalise=False, columns=["tracked", "clean", "dt_s"])
    assert w.window == 200 and np.all(np.diff(w.starts)[np.diff(w.starts) < 200] == 50)
    tracked, clean = w[0]
    assert tracked.shape == (200, 52) and clean.shape == (200, 52)
    assert w.stack("dt_s").shape == (len(w), 200, 1)
    assert ds.features["clean"][0] == "clean.eyeBlinkLeft"


def test_normalisation_uses_training_statistics(rnn):
    """Normalised training rows have mean 0 and standard deviation 1 per element (the statistics are over
    exactly the training rows), and the windows hold (raw − mean) / std."""
    raw = rnn.array("y", split="train").astype(np.float64)
    st = rnn.stats["overall"]["y"]
    z = (raw - np.array(st["mean"])) / np.array(st["std"])
    assert np.abs(z.mean(axis=0)).max() < 1e-9
    assert np.abs(z.std(axis=0) - 1).max() < 1e-9
    mean, std = rnn.mean_std("y")
    w_norm, w_raw = rnn.windows("val"), rnn.windows("val", normalise=False)
    np.testing.assert_allclose(w_norm.y, (w_raw.y - mean) / std, rtol=1e-5, atol=1e-5)


def test_table_selection_and_zero_copy_arrays(rnn):
    ids = _frame(rnn)
    t = rnn.table(split="train", pose="sitting", mirrored=False)
    want = ids[(ids["split"] == "train") & (ids["pose"] == "sitting") & ~ids["mirrored"]]
    assert t.num_rows == len(want) > 0
    assert t.column("take").unique().to_pylist() == sorted(want["take"].unique())
    x = rnn.array("x")
    buf = rnn.table().column("x").chunk(0).values.buffers()[1]
    assert x.shape == (len(ids), 66) and x.dtype == np.float32
    assert x.__array_interface__["data"][0] == buf.address     # a view of the Arrow buffer, not a copy
    assert rnn.features["x"][:3] == ["target_dir.x", "target_dir.y", "target_dir.z"]


def test_errors(datasets, tmp_path):
    gm = open_dataset(datasets / "gaze_map")
    with pytest.raises(ConfigError, match="one row per take"):
        gm.windows("train")
    with pytest.raises(ConfigError, match="no column 'nope'"):
        open_dataset(datasets / "gaze_rnn").windows("train", columns=["nope", "y"])
    with pytest.raises(InputError, match="_dataset.json"):
        open_dataset(tmp_path)


def test_to_torch_without_torch(rnn, monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(ConfigError, match=r"gazepipe\[torch\]"):
        rnn.to_torch("train")


def test_torch_dataloader_reads_windows(rnn):
    torch = pytest.importorskip("torch")
    tds = rnn.to_torch("val")
    w = rnn.windows("val")
    assert isinstance(tds, torch.utils.data.Dataset) and len(tds) == len(w)
    loader = torch.utils.data.DataLoader(tds, batch_size=16, shuffle=False)
    xb, yb = next(iter(loader))
    assert xb.shape == (16, 120, 66) and yb.shape == (16, 120, 63) and xb.dtype == torch.float32
    np.testing.assert_array_equal(xb.numpy(), w.x[:16])
    np.testing.assert_array_equal(yb.numpy(), w.y[:16])


# --------------------------------------------------------------------------------------- README examples

def run_example(name: str) -> dict:
    return runpy.run_path(str(EXAMPLES / f"{name}.py"), run_name="__main__")


def test_readme_pandas(workdir, rnn):
    g = run_example("pandas_example")
    df, train = g["df"], g["train"]
    assert len(df) == rnn.table().num_rows
    assert len(train) == rnn.table(split="train", mirrored=False).num_rows
    assert len(df["x"].iloc[0]) == 66 and list(df.columns) == rnn.table().column_names
    assert df["subject"].dtype.name in ("object", "string", "str")     # plain strings, not categories


def test_readme_pyarrow(workdir, rnn):
    g = run_example("pyarrow_example")
    x = g["x"]
    assert x.shape == (rnn.table(split="train", pose="standing").num_rows, 66) and x.dtype == np.float32
    np.testing.assert_array_equal(np.sort(x[:, 0]), np.sort(rnn.array("x", split="train", pose="standing")[:, 0]))
    assert g["names"] == rnn.features["x"]


def test_readme_windows(workdir):
    g = run_example("windows_example")
    assert g["tracked"].shape == (200, 52) and g["clean"].shape == (200, 52)
    assert g["mean"].shape == (52,)


def test_readme_torch(workdir):
    pytest.importorskip("torch")
    g = run_example("torch_example")
    assert tuple(g["x"].shape) == (64, 120, 66) and tuple(g["y"].shape) == (64, 120, 63)


def test_readme_hf_datasets(workdir, rnn, monkeypatch):
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(workdir / "hf"))
    pytest.importorskip("datasets")
    g = run_example("hf_datasets_example")
    assert {k: v.num_rows for k, v in g["hf"].items()} == {
        "train": rnn.table(split="train").num_rows, "validation": rnn.table(split="val").num_rows}
    assert g["batch"]["x"].shape == (4, 66) and g["batch"]["x"].dtype == np.float32
    first = rnn.table(split="train").slice(0, 4)
    np.testing.assert_array_equal(g["batch"]["x"], np.array(first.column("x").to_pylist(), np.float32))


def test_readme_polars_duckdb(workdir, rnn):
    g = run_example("polars_duckdb_example")
    assert g["df"].shape[0] == rnn.table().num_rows
    assert dict(g["per_split"]) == {s: rnn.table(split=s).num_rows for s in ("train", "val")}


def test_readme_examples_are_the_readme_code():
    """Each example file is, line for line, a Python block of the README (so the README's code is what runs)."""
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    blocks = [b.split("```", 1)[0] for b in readme.split("```python\n")[1:]]
    for f in sorted(EXAMPLES.glob("*_example.py")):
        assert f.read_text() in blocks, f"{f.name} is not a code block of README.md"


def test_readme_gaze_map(workdir):
    from click.testing import CliRunner

    from gazepipe.cli.train import train

    res = CliRunner().invoke(train, ["gaze_map", "--data", "out/datasets/gaze_map", "--out", "models/gaze_map"])
    assert res.exit_code == 0, res.output
    g = run_example("gaze_map_example")
    assert g["q"].shape[1:] == (11, 4) and g["motion"].names[-1] == "eyes"
    assert os.path.exists("models/gaze_map/model.json")
