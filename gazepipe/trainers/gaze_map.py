"""The ``gaze_map`` trainer: Pejsa's parametric gaze map (5.2.2.2, 5.2.3) from a ``gaze_map`` dataset.

The map keeps every training example's gaze displacement motion G = {P+, l, T, t_β, β} at its requested
(yaw, pitch). For a requested (yaw, pitch) it blends the nearest examples (Kovar and Gleicher's k-nearest
scheme, as Pejsa uses: weights 1/d_i − 1/d_k over the k + 1 nearest, d in degrees of (yaw, pitch), the
(k + 1)-th getting weight 0, normalised; an exact hit is that example): the quaternions of P+ are linearly
interpolated (signs aligned, then normalised) and the 7 motion numbers linearly (Pejsa 5.2.2.2).

The displacement curve of joint j at normalised time u ∈ [0, 1] (Pejsa 5.2.3) scales P+_j's rotation angle by

    0                                   u < t_j
    (1 + β) · e((u − t_j) / (t_β − t_j))       t_j ≤ u ≤ t_β
    1 + (1 − e((u − t_β) / (1 − t_β))) · β     t_β < u

with e the ease-in/ease-out e(s) = (1 − cos πs) / 2 (zero slope at both ends, so the curve is C¹ where the
linear form has corners). The eyes start at u = 0. A joint that starts after the overshoot peak eases from 0 to
P+_j over [t_j, 1] without overshoot. Time in seconds is u · l.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.errors import ConfigError
from gazepipe.trainers.base import TrainOptions, npz_bytes, read_model_json, save_model_json, write_atomic

WEIGHTS = "gaze_map.npz"


def ease(s: np.ndarray) -> np.ndarray:
    """Ease-in/ease-out on [0, 1]: (1 − cos πs) / 2, clipped outside."""
    return 0.5 * (1.0 - np.cos(np.pi * np.clip(s, 0.0, 1.0)))


def blend_quaternions(q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted linear blend of unit quaternions (E, J, 4) w, x, y, z with weights (E,): each example's sign
    aligned with the heaviest one's, summed, normalised → (J, 4)."""
    ref = q[int(np.argmax(w))]
    sign = np.where(np.einsum("ejc,jc->ej", q, ref) < 0, -1.0, 1.0)
    s = np.einsum("e,ej,ejc->jc", w, sign, q)
    return s / np.linalg.norm(s, axis=-1, keepdims=True)


def knn_weights(points: np.ndarray, query: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Kovar–Gleicher k-nearest weights: (indices, weights) of the examples ``points`` (E, 2) for ``query`` (2,).

    The k + 1 nearest are taken (all when fewer); w_i = 1/d_i − 1/d_(k+1), normalised. An example at the query
    (d < 1e-9) gets weight 1; equal distances give equal weights.
    """
    d = np.linalg.norm(points - query[None, :], axis=1)
    order = np.argsort(d, kind="stable")
    if d[order[0]] < 1e-9:
        return order[:1], np.ones(1)
    take = order[: min(k + 1, len(order))]
    dd = d[take]
    if len(take) == 1:
        return take, np.ones(1)
    w = 1.0 / dd[:-1] - 1.0 / dd[-1]
    idx = take[:-1]
    if w.sum() <= 0:
        w = np.ones(len(idx))
    return idx, w / w.sum()


@dataclass
class GazeMotion:
    """A gaze displacement motion G = {P+, l, T, t_β, β} (Pejsa 5.1.2).

    Attributes
    ----------
    names : the joints of ``p_plus``: the segments, root first, then ``eyes``.
    p_plus : (S + 1, 4) w, x, y, z parent-relative displacement of each joint at the end of the shift.
    duration_s : l, seconds.
    start_times : (S,) start of each segment as a fraction of l (the eyes start at 0).
    overshoot_time : t_β as a fraction of l; overshoot : β, a multiplier of the final displacement.
    """

    yaw_deg: float
    pitch_deg: float
    names: list[str]
    p_plus: np.ndarray
    duration_s: float
    start_times: np.ndarray
    overshoot_time: float
    overshoot: float

    def scale(self, u: np.ndarray) -> np.ndarray:
        """Scale factor of each joint's displacement angle at normalised times ``u`` (T,) → (T, S + 1)."""
        u = np.asarray(u, dtype=np.float64)[:, None]
        tj = np.clip(np.append(self.start_times, 0.0), 0.0, 1.0 - 1e-6)[None, :]
        tb = float(np.clip(self.overshoot_time, 0.0, 1.0))
        beta = float(self.overshoot)
        peaked = tj < tb
        span1 = np.where(peaked, tb - tj, 1.0 - tj)
        rise = ease((u - tj) / span1) * np.where(peaked, 1.0 + beta, 1.0)
        settle = 1.0 + (1.0 - ease((u - tb) / max(1.0 - tb, 1e-9))) * beta
        s = np.where(peaked & (u > tb), settle, rise)
        return np.where(u >= 1.0, 1.0, s)

    def at(self, u: np.ndarray) -> np.ndarray:
        """Displacement quaternions (T, S + 1, 4) w, x, y, z at normalised times ``u`` (T,)."""
        s = self.scale(u)
        rv = Rotation.from_quat(self.p_plus[:, [1, 2, 3, 0]]).as_rotvec()
        q = Rotation.from_rotvec((s[:, :, None] * rv[None]).reshape(-1, 3)).as_quat()[:, [3, 0, 1, 2]]
        return q.reshape(s.shape[0], s.shape[1], 4)

    def curve(self, fps: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
        """The displacement curve sampled at ``fps`` from 0 to l inclusive: (times s (T,), quats (T, S + 1, 4))."""
        n = max(2, int(np.floor(self.duration_s * fps)) + 1)
        t = np.arange(n) / fps
        if t[-1] < self.duration_s:
            t = np.append(t, self.duration_s)
        return t, self.at(t / self.duration_s)


class GazeMap:
    """Pejsa's parametric gaze map: the examples' gaze displacement motions indexed by (yaw, pitch), degrees."""

    def __init__(self, segments: list[str], yaw: np.ndarray, pitch: np.ndarray, p_plus: np.ndarray,
                 duration: np.ndarray, start_times: np.ndarray, overshoot_time: np.ndarray, overshoot: np.ndarray,
                 k: int = 4) -> None:
        self.segments = list(segments)
        self.yaw = np.asarray(yaw, np.float64)
        self.pitch = np.asarray(pitch, np.float64)
        self.p_plus = np.asarray(p_plus, np.float64).reshape(len(self.yaw), len(self.segments) + 1, 4)
        self.duration = np.asarray(duration, np.float64)
        self.start_times = np.asarray(start_times, np.float64).reshape(len(self.yaw), len(self.segments))
        self.overshoot_time = np.asarray(overshoot_time, np.float64)
        self.overshoot = np.asarray(overshoot, np.float64)
        self.k = int(k)
        if len(self.yaw) == 0:
            raise ConfigError(None, "a gaze map needs at least one example")

    @classmethod
    def from_table(cls, table, segments: list[str], k: int = 4) -> GazeMap:
        """From ``gaze_map`` dataset rows (a pyarrow table)."""
        from gazepipe.datasets import column_array

        return cls(segments, column_array(table, "yaw_deg")[:, 0], column_array(table, "pitch_deg")[:, 0],
                   column_array(table, "p_plus"), column_array(table, "duration_s")[:, 0],
                   column_array(table, "start_times"), column_array(table, "overshoot_time")[:, 0],
                   column_array(table, "overshoot")[:, 0], k)

    def __len__(self) -> int:
        return len(self.yaw)

    def motion(self, yaw_deg: float, pitch_deg: float, exclude: int | None = None) -> GazeMotion:
        """The blended gaze displacement motion for a requested change (degrees); ``exclude`` leaves one example
        out (leave-one-out checks)."""
        keep = np.ones(len(self), bool)
        if exclude is not None:
            keep[exclude] = False
        src = np.flatnonzero(keep)
        pts = np.stack([self.yaw[src], self.pitch[src]], axis=1)
        idx, w = knn_weights(pts, np.array([yaw_deg, pitch_deg], np.float64), self.k)
        idx = src[idx]
        return GazeMotion(
            yaw_deg=float(yaw_deg), pitch_deg=float(pitch_deg), names=[*self.segments, "eyes"],
            p_plus=blend_quaternions(self.p_plus[idx], w), duration_s=float(w @ self.duration[idx]),
            start_times=w @ self.start_times[idx], overshoot_time=float(w @ self.overshoot_time[idx]),
            overshoot=float(w @ self.overshoot[idx]))

    def arrays(self) -> dict[str, np.ndarray]:
        return {"yaw_deg": self.yaw, "pitch_deg": self.pitch, "p_plus": self.p_plus, "duration_s": self.duration,
                "start_times": self.start_times, "overshoot_time": self.overshoot_time, "overshoot": self.overshoot,
                "segments": np.array(self.segments), "k": np.array(self.k)}

    @classmethod
    def load(cls, model_dir: str | Path) -> GazeMap:
        """A saved map (``model_dir`` as written by ``gazepipe train gaze_map``)."""
        meta = read_model_json(model_dir)
        path = Path(model_dir) / meta.get("weights", WEIGHTS)
        try:
            with np.load(path, allow_pickle=False) as z:
                a = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise ConfigError(path, f"not a readable gaze map ({exc})") from None
        return cls([str(s) for s in a["segments"]], a["yaw_deg"], a["pitch_deg"], a["p_plus"], a["duration_s"],
                   a["start_times"], a["overshoot_time"], a["overshoot"], int(a["k"]))


def pose_error_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees between quaternions (…, 4) w, x, y, z (sign-insensitive)."""
    dot = np.abs(np.sum(a * b, axis=-1)) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.rad2deg(2.0 * np.arccos(np.clip(dot, 0.0, 1.0)))


def evaluate(gmap: GazeMap, held: GazeMap | None = None) -> dict[str, Any]:
    """Final-pose errors (degrees, per joint then the worst joint) of the map's motions against examples:
    ``held`` (examples not in the map) or, when ``None``, each of the map's own left out in turn."""
    ref = held if held is not None else gmap
    errs, dur = [], []
    for i in range(len(ref)):
        m = gmap.motion(ref.yaw[i], ref.pitch[i], exclude=None if held is not None else i)
        errs.append(pose_error_deg(m.p_plus, ref.p_plus[i]))
        dur.append(abs(m.duration_s - ref.duration[i]))
    e = np.array(errs)
    worst = e.max(axis=1)
    return {"examples": len(ref), "final_pose_error_deg_mean": float(worst.mean()),
            "final_pose_error_deg_max": float(worst.max()),
            "final_pose_error_deg_per_joint_mean": dict(zip(ref.segments + ["eyes"],
                                                            [float(v) for v in e.mean(axis=0)], strict=True)),
            "duration_error_s_mean": float(np.mean(dur))}


class GazeMapTrainer:
    """Builds the parametric gaze map from the training rows (mirrored copies included) and saves it."""

    name = "gaze_map"
    dataset = "gaze_map"
    schema_version = 2
    required_columns = ("yaw_deg", "pitch_deg", "duration_s", "start_times", "overshoot_time", "overshoot", "p_plus")
    knobs: tuple[str, ...] = ()
    options = {"k": "neighbours blended per request (Kovar-Gleicher k; default 4)",
               "train_split": "the split whose rows form the map (default train)"}

    def train(self, data, out_dir: Path, options: TrainOptions) -> dict[str, Any]:
        k = int(options.get("k", 4))
        if k < 1:
            raise ConfigError(None, f"option k must be at least 1, got {k}")
        split = str(options.get("train_split", "train"))
        segments = list(data.features["start_times"])
        train = data.table(split=split)
        if train.num_rows == 0:
            raise ConfigError(data.path, f"no {split!r} rows to build a gaze map from")
        gmap = GazeMap.from_table(train, segments, k)
        metrics: dict[str, Any] = {"examples": len(gmap), "leave_one_out": evaluate(gmap) if len(gmap) > 1 else None}
        for s in ("val", "test"):
            rows = data.table(split=s)
            if rows.num_rows:
                metrics[s] = evaluate(gmap, GazeMap.from_table(rows, segments, k))
        out = Path(out_dir)
        write_atomic(out / WEIGHTS, npz_bytes(gmap.arrays()))
        save_model_json(out, self.name, {"k": k, "train_split": split, "segments": segments}, metrics, data,
                        WEIGHTS)
        return metrics
