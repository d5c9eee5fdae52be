"""Shared fixtures: paths to the real corpus and the sample session, and a tiny hand-made session."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "session01"
CORPUS = REPO / "tests" / "data" / "corpus"


def write_wide_csv(path: Path, labels: list[str], xyz: np.ndarray, rate_hz: float) -> None:
    """A plain wide CSV (frame, time, <m>_x, <m>_y, <m>_z); NaN samples become empty cells."""
    T = xyz.shape[0]
    cols = ["frame", "time"] + [f"{m}_{a}" for m in labels for a in "xyz"]
    rows = [",".join(cols)]
    flat = xyz.reshape(T, -1)
    for i in range(T):
        vals = ["" if np.isnan(v) else f"{v:.4f}" for v in flat[i]]
        rows.append(",".join([str(i + 1), f"{i / rate_hz:.6f}", *vals]))
    path.write_text("\n".join(rows) + "\n")


TINY_MARKERSET = """\
schema = 1
up_axis = "z"
units = "mm"
root = "SACR"
target = "POLE"

[segments.pelvis]
markers = ["PL", "PR", "PB"]
[segments.head]
markers = ["H1", "H2", "H3"]
parent = "pelvis"
"""


def tiny_motion(seed: int, T: int = 90, rate_hz: float = 30.0) -> tuple[list[str], np.ndarray]:
    """Smooth, seeded motion of 8 markers: the root, a pelvis and a head triangle, the target (mm)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / rate_hz
    base = np.array([[0, 0, 1000], [100, 0, 1000], [-100, 0, 1000], [0, -80, 1000],
                     [30, 0, 1650], [-30, 0, 1650], [0, 40, 1700], [0, 1500, 1600]], float)
    wobble = 20 * np.sin(2 * np.pi * 0.3 * t + rng.uniform(0, 6))[:, None, None]
    xyz = base[None] + wobble * np.array([1.0, 0.5, 0.0]) + rng.normal(0, 0.3, (T, 8, 3))
    return ["SACR", "PL", "PR", "PB", "H1", "H2", "H3", "POLE"], xyz


def make_tiny_session(root: Path, n_takes: int = 3, kind: str = "gaze_follow") -> Path:
    """A session folder with ``n_takes`` wide-CSV mocap takes and a two-segment markerset."""
    (root / "mocap").mkdir(parents=True, exist_ok=True)
    (root / "markerset.toml").write_text(TINY_MARKERSET)
    takes = []
    for i in range(n_takes):
        labels, xyz = tiny_motion(i)
        write_wide_csv(root / "mocap" / f"t{i}.csv", labels, xyz, 30.0)
        takes.append(textwrap.dedent(f"""\
            [[takes]]
            id = "t{i}"
            kind = "gaze_follow"
            pose = "standing"
            mocap = "mocap/t{i}.csv"
            """))
    (root / "session.toml").write_text(textwrap.dedent("""\
        schema = 1
        [session]
        id = "tiny"
        subject = "p01"
        markerset = "markerset.toml"
        """) + "\n" + "\n".join(takes))
    return root


@pytest.fixture
def tiny_session(tmp_path: Path) -> Path:
    return make_tiny_session(tmp_path / "tiny")


@pytest.fixture
def workdir(datasets, tmp_path, monkeypatch) -> Path:
    """A folder with out/datasets as `gazepipe run ... --out out` leaves it, for the README examples to run from
    (``datasets``: the requesting module's built datasets folder)."""
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "datasets").symlink_to(datasets, target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    return tmp_path
