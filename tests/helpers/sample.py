"""Read what ``gazepipe run`` wrote for the sample session and compare it with the session's ground truth
(sample_data/session01/truth): the end-to-end acceptance tests and the dataset tests."""

from __future__ import annotations

import json
import tomllib
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from scipy.spatial.transform import Rotation

from gazepipe.io.dataset_files import read_dataset
from gazepipe.schemas.joints import joints_arrays
from gazepipe.schemas.markers import table_to_markers
from gazepipe.stages.build.summary import feature_values
from gazepipe.synth import load_truth
from tests.helpers import SAMPLE

SESSION_ID = "session01"
FILL_MEASURED, FILL_UNFILLED = "measured", "unfilled"
#: what a run with nothing to do must leave byte for byte as it was
PRODUCT_PARTS = ("takes", "datasets", ".gazepipe/units", ".gazepipe/datasets")


def session_takes() -> list[dict[str, Any]]:
    """The ``[[takes]]`` entries of the sample session's session.toml."""
    return tomllib.loads((SAMPLE / "session.toml").read_text())["takes"]


def markerset() -> dict[str, Any]:
    return tomllib.loads((SAMPLE / "markerset.toml").read_text())


def take_ids(kind: str) -> list[str]:
    return [t["id"] for t in session_takes() if t["kind"] == kind]


@cache
def truth(take: str) -> dict[str, Any]:
    return load_truth(SAMPLE, take)


class Output:
    """Read access to one output folder of ``gazepipe run`` on the sample session."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self._cache: dict[Any, Any] = {}

    def take_dir(self, take: str) -> Path:
        return self.root / "takes" / SESSION_ID / take

    def table(self, take: str, name: str):
        key = ("table", take, name)
        if key not in self._cache:
            self._cache[key] = pq.read_table(self.take_dir(take) / f"{name}.parquet")
        return self._cache[key]

    def unit(self, take: str, stage: str) -> dict[str, Any]:
        return json.loads((self.root / ".gazepipe" / "units" / SESSION_ID / take / f"{stage}.json").read_text())

    def dataset_record(self, name: str) -> dict[str, Any]:
        return json.loads((self.root / ".gazepipe" / "datasets" / f"{name}.json").read_text())

    def markers(self, take: str, name: str = "markers"):
        """``(Markers, frames, fill codes or None, meta)`` of a take's markers or markers_raw table."""
        key = ("markers", take, name)
        if key not in self._cache:
            self._cache[key] = table_to_markers(self.table(take, name))
        return self._cache[key]

    def fill_names(self, take: str) -> np.ndarray:
        """Fill method of every sample of the markers table as strings, (T, M)."""
        t = self.table(take, "markers")
        m, _, _, _ = self.markers(take)
        col = t.column("fill").combine_chunks()
        names = np.asarray(col.dictionary.to_pylist(), dtype=object)
        codes = col.indices.to_numpy(zero_copy_only=False)
        return names[codes].reshape(len(m.labels), -1).T

    def joints(self, take: str) -> dict[str, Any]:
        key = ("joints", take)
        if key not in self._cache:
            self._cache[key] = joints_arrays(self.table(take, "joints"))
        return self._cache[key]

    def eyes(self, take: str) -> dict[str, np.ndarray]:
        key = ("eyes", take)
        if key not in self._cache:
            t = self.table(take, "eyes")
            self._cache[key] = {
                "frame": t.column("frame").to_numpy().astype(np.int64),
                "valid": t.column("valid").to_numpy(zero_copy_only=False),
                "eye_dir_char": feature_values(t, "eye_dir_char").astype(np.float64),
            }
        return self._cache[key]

    def dataset(self, name: str):
        """``(table, info)`` of a dataset folder, read with the schema checks of read_dataset."""
        key = ("dataset", name)
        if key not in self._cache:
            self._cache[key] = read_dataset(self.root / "datasets" / name)
        return self._cache[key]


def angle_deg(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """Angle of the rotation between two quaternion arrays (..., 4) ``w, x, y, z``, degrees."""
    a = Rotation.from_quat(np.asarray(q_a, float).reshape(-1, 4), scalar_first=True)
    b = Rotation.from_quat(np.asarray(q_b, float).reshape(-1, 4), scalar_first=True)
    return np.degrees((a * b.inv()).magnitude()).reshape(np.shape(q_a)[:-1])


def vec_angle_deg(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between direction vectors (..., 3), degrees (inputs need not be unit length)."""
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    return np.degrees(np.arctan2(cross, np.einsum("...i,...i->...", u, v)))


def json_events(text: str) -> list[dict[str, Any]]:
    """The JSON-line log events in a command's output (other lines ignored)."""
    events = []
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("{"):
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return events


def invalid_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True in a boolean mask as half-open (start, stop) index pairs."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(np.int8))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def mirror_rnn(v: np.ndarray) -> np.ndarray:
    """Expected mirror of gaze_rnn x or y rows (N, 3k) when every segment is central: negate X of every
    3-vector (target and eye directions, forward and up of each 6-number rotation)."""
    out = np.array(v, copy=True)
    out[:, 0::3] = -out[:, 0::3]
    return out


def frame_rows(frames: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Row index of each wanted frame number in a sorted frame column (asserts they are all present)."""
    idx = np.searchsorted(frames, wanted)
    assert np.all(idx < len(frames)) and np.array_equal(frames[idx], wanted), "frames missing from the table"
    return idx


def peak_speeds(tr: dict, rate_hz: float, filter_hz: float | None = None) -> dict[str, float]:
    """Each segment's noise-free parent-relative peak angular speed in the crop, deg/s (the root: its turn in
    the character frame held fixed at the crop start); with ``filter_hz``, of the rotations low-passed as the
    gaze_map start rule does (:func:`gazepipe.stages.build.gaze.smooth_rotations`)."""
    from gazepipe.stages.build.gaze import angular_speed, smooth_rotations
    from gazepipe.stages.geometry import from_wxyz

    c0, c1 = tr["scalars"]["crop"]
    c = from_wxyz(tr["char_quat_lab"][c0:c1])
    out = {}
    for k, s in enumerate(tr["segments"]):
        if k == 0:
            r = c[0].inv() * c * from_wxyz(tr["seg_quat_char"][c0:c1, 0].astype(np.float64))
        else:
            r = from_wxyz(tr["seg_quat_local"][c0:c1, k].astype(np.float64))
        out[s] = float(np.degrees(angular_speed(smooth_rotations(r, rate_hz, filter_hz), rate_hz).max()))
    return out


def near_threshold(tr: dict, rate_hz: float, thr_deg_s: float = 18.0, margin_deg_s: float = 2.5) -> tuple[str, ...]:
    """Segments whose noise-free parent-relative peak speed in the crop lies within ``margin_deg_s`` of the
    gaze_map start threshold (the root: its turn in the character frame held fixed at the crop start). With
    a few deg/s of speed noise left after the low-pass, whether such a segment "starts" cannot be decided."""
    return tuple(s for s, w in peak_speeds(tr, rate_hz).items() if abs(w - thr_deg_s) < margin_deg_s)


def overshoot_amplitude_deg(tr: dict) -> float:
    """How far (deg) the head's noise-free displacement in the crop (character frame held fixed at the crop
    start) passes its final value along the final axis: β times the final angle. Below the head's orientation
    noise (a few tenths of a degree from 0.5 mm marker noise) the overshoot's instant cannot be resolved."""
    from gazepipe.stages.geometry import from_wxyz

    c0, c1 = tr["scalars"]["crop"]
    head = list(tr["segments"]).index("head")
    c = from_wxyz(tr["char_quat_lab"][c0:c1])
    g = c[0].inv() * c * from_wxyz(tr["seg_quat_char"][c0:c1, head].astype(np.float64))
    rv = (g * g[0].inv()).as_rotvec()
    axis = rv[-1] / np.linalg.norm(rv[-1])
    theta = rv @ axis
    return float(np.degrees(theta.max() - theta[-1]))


def truth_joints(tr: dict, frames: np.ndarray):
    """A joints table of a take's true rotations on ``frames`` (rows of the uncropped take), for dataset tests."""
    from gazepipe.schemas.joints import joints_to_table
    from gazepipe.stages.frames.stage import Joints
    from gazepipe.stages.geometry import from_wxyz, six_from_rotation

    q = tr["seg_quat_char"][frames].astype(np.float64)
    n, s = q.shape[:2]
    six = six_from_rotation(from_wxyz(q.reshape(-1, 4))).reshape(n, s, 6)
    j = Joints(segments=list(tr["segments"]), parents=np.arange(-1, s - 1), quat=q,
               quat_local=tr["seg_quat_local"][frames].astype(np.float64), six=six,
               head_centre=tr["head_centre_char"][frames].astype(np.float64),
               target_dir=tr["target_dir_char"][frames].astype(np.float64),
               char_origin=tr["char_origin_lab"][frames].astype(np.float64),
               char_rot=tr["char_quat_lab"][frames].astype(np.float64),
               valid=np.ones(n, bool), rate_hz=float(tr["scalars"]["rate_hz"]))
    return joints_to_table(j, frames)
