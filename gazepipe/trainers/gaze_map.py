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

Null parameters (the dataset's ``known`` mask: a segment's P+, the eyes' P+, the overshoot; its
``start_known`` mask: a segment's start time) are never blended: each joint's P+, each start time, and the
overshoot, is blended from the k nearest examples that know it (its own neighbours and weights), so a NaN never
enters a blend or an error; a joint whose P+ no example knows is NaN in the motion (and stays still in its
curve), a start time none knows is 0 (Pejsa: the joint starts with the shift), an overshoot none knows is none
(t_β = 1, β = 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.errors import ConfigError
from gazepipe.trainers.base import (
    Option,
    TrainOptions,
    check_options,
    npz_bytes,
    options_table,
    read_model_json,
    save_model_json,
    write_atomic,
)

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
        """Scale factor of each joint's displacement angle at normalised times ``u`` (T,) → (T, S + 1); an
        unknown (NaN) overshoot is none (t_β = 1, β = 0)."""
        u = np.asarray(u, dtype=np.float64)[:, None]
        tj = np.clip(np.append(self.start_times, 0.0), 0.0, 1.0 - 1e-6)[None, :]
        known = np.isfinite(self.overshoot_time) and np.isfinite(self.overshoot)
        tb = float(np.clip(self.overshoot_time, 0.0, 1.0)) if known else 1.0
        beta = float(self.overshoot) if known else 0.0
        peaked = tj < tb
        span1 = np.where(peaked, tb - tj, 1.0 - tj)
        rise = ease((u - tj) / span1) * np.where(peaked, 1.0 + beta, 1.0)
        settle = 1.0 + (1.0 - ease((u - tb) / max(1.0 - tb, 1e-9))) * beta
        s = np.where(peaked & (u > tb), settle, rise)
        return np.where(u >= 1.0, 1.0, s)

    def at(self, u: np.ndarray) -> np.ndarray:
        """Displacement quaternions (T, S + 1, 4) w, x, y, z at normalised times ``u`` (T,); a joint whose P+
        is unknown (NaN) stays still (identity)."""
        s = np.nan_to_num(self.scale(u))
        ok = np.isfinite(self.p_plus).all(axis=1)
        rv = np.zeros((len(self.p_plus), 3))
        if ok.any():
            rv[ok] = Rotation.from_quat(self.p_plus[ok][:, [1, 2, 3, 0]]).as_rotvec()
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
    """Pejsa's parametric gaze map: the examples' gaze displacement motions indexed by (yaw, pitch), degrees.

    ``known`` (E, S + 2) bool: per example, which joints' P+ (each segment's, the eyes') and whether the
    overshoot are known (the dataset's ``known`` mask); ``start_known`` (E, S) which segments' start times are
    (its ``start_known``; without it, those that are finite). Both are also False wherever those values are not
    finite, so NaN values are never used whatever the masks say.
    """

    def __init__(self, segments: list[str], yaw: np.ndarray, pitch: np.ndarray, p_plus: np.ndarray,
                 duration: np.ndarray, start_times: np.ndarray, overshoot_time: np.ndarray, overshoot: np.ndarray,
                 k: int = 4, known: np.ndarray | None = None, start_known: np.ndarray | None = None) -> None:
        self.segments = list(segments)
        self.yaw = np.asarray(yaw, np.float64)
        self.pitch = np.asarray(pitch, np.float64)
        e, ns = len(self.yaw), len(self.segments)
        self.p_plus = np.asarray(p_plus, np.float64).reshape(e, ns + 1, 4)
        self.duration = np.asarray(duration, np.float64)
        self.start_times = np.asarray(start_times, np.float64).reshape(e, ns)
        self.overshoot_time = np.asarray(overshoot_time, np.float64)
        self.overshoot = np.asarray(overshoot, np.float64)
        self.k = int(k)
        if e == 0:
            raise ConfigError(None, "a gaze map needs at least one example")
        finite = np.concatenate([
            np.isfinite(self.p_plus).all(axis=2),
            (np.isfinite(self.overshoot_time) & np.isfinite(self.overshoot))[:, None]], axis=1)
        given = np.ones((e, ns + 2), bool) if known is None else np.asarray(known, bool).reshape(e, ns + 2)
        self.known = finite & given
        self.start_known = np.isfinite(self.start_times) & (
            True if start_known is None else np.asarray(start_known, bool).reshape(e, ns))
        if not (np.isfinite(self.yaw).all() and np.isfinite(self.pitch).all() and np.isfinite(self.duration).all()):
            raise ConfigError(None, "a gaze map's requested angles and durations must be finite")

    @classmethod
    def from_table(cls, table, segments: list[str], k: int = 4) -> GazeMap:
        """From ``gaze_map`` dataset rows (a pyarrow table); its ``known`` and ``start_known`` masks when it has
        them."""
        from gazepipe.datasets import column_array

        def mask(name: str) -> np.ndarray | None:
            return column_array(table, name) if name in table.column_names else None

        return cls(segments, column_array(table, "yaw_deg")[:, 0], column_array(table, "pitch_deg")[:, 0],
                   column_array(table, "p_plus"), column_array(table, "duration_s")[:, 0],
                   column_array(table, "start_times"), column_array(table, "overshoot_time")[:, 0],
                   column_array(table, "overshoot")[:, 0], k, mask("known"), mask("start_known"))

    def __len__(self) -> int:
        return len(self.yaw)

    def neighbours(self, yaw_deg: float, pitch_deg: float, usable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(example indices, weights) of the Kovar–Gleicher blend among the examples where ``usable`` (E,) is
        True; empty when none is."""
        src = np.flatnonzero(usable)
        if not len(src):
            return src, np.zeros(0)
        pts = np.stack([self.yaw[src], self.pitch[src]], axis=1)
        idx, w = knn_weights(pts, np.array([yaw_deg, pitch_deg], np.float64), self.k)
        return src[idx], w

    def motion(self, yaw_deg: float, pitch_deg: float, exclude: int | None = None) -> GazeMotion:
        """The blended gaze displacement motion for a requested change (degrees); ``exclude`` leaves one example
        out (leave-one-out checks). Each joint's P+, each start time and the overshoot are blended from the
        nearest examples that know them (a start time none knows is 0); the duration from the nearest
        examples."""
        keep = np.ones(len(self), bool)
        if exclude is not None:
            keep[exclude] = False
        ns = len(self.segments)
        idx, w = self.neighbours(yaw_deg, pitch_deg, keep)
        p_plus = np.full((ns + 1, 4), np.nan)
        start = np.full(ns, np.nan)
        for j in range(ns + 1):
            jdx, jw = self.neighbours(yaw_deg, pitch_deg, keep & self.known[:, j])
            if len(jdx):
                p_plus[j] = blend_quaternions(self.p_plus[jdx, j:j + 1], jw)[0]
            if j < ns:
                sdx, sw = self.neighbours(yaw_deg, pitch_deg, keep & self.start_known[:, j])
                start[j] = sw @ self.start_times[sdx, j] if len(sdx) else 0.0
        odx, ow = self.neighbours(yaw_deg, pitch_deg, keep & self.known[:, ns + 1])
        return GazeMotion(
            yaw_deg=float(yaw_deg), pitch_deg=float(pitch_deg), names=[*self.segments, "eyes"],
            p_plus=p_plus, duration_s=float(w @ self.duration[idx]), start_times=start,
            overshoot_time=float(ow @ self.overshoot_time[odx]) if len(odx) else float("nan"),
            overshoot=float(ow @ self.overshoot[odx]) if len(odx) else float("nan"))

    def arrays(self) -> dict[str, np.ndarray]:
        return {"yaw_deg": self.yaw, "pitch_deg": self.pitch, "p_plus": self.p_plus, "duration_s": self.duration,
                "start_times": self.start_times, "overshoot_time": self.overshoot_time, "overshoot": self.overshoot,
                "segments": np.array(self.segments), "k": np.array(self.k), "known": self.known,
                "start_known": self.start_known}

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
                   a["start_times"], a["overshoot_time"], a["overshoot"], int(a["k"]), a.get("known"),
                   a.get("start_known"))


def pose_error_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees between quaternions (…, 4) w, x, y, z (sign-insensitive)."""
    dot = np.abs(np.sum(a * b, axis=-1)) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.rad2deg(2.0 * np.arccos(np.clip(dot, 0.0, 1.0)))


#: the baselines the map is compared with (:func:`evaluate`), as the verdicts name them
BASELINES = {"mean_shift": "the mean shift", "fixed_shares": "fixed shares of the requested rotation"}


def mean_shift(gmap: GazeMap, use: np.ndarray) -> np.ndarray:
    """Baseline: every joint's P+ (J, 4) is the mean of the examples ``use`` (E,) bool that know it, whatever
    the request (NaN for a joint none of them knows)."""
    out = np.full((len(gmap.segments) + 1, 4), np.nan)
    for j in range(len(out)):
        rows = np.flatnonzero(use & gmap.known[:, j])
        if len(rows):
            out[j] = blend_quaternions(gmap.p_plus[rows, j:j + 1], np.full(len(rows), 1.0 / len(rows)))[0]
    return out


def fit_shares(gmap: GazeMap, use: np.ndarray) -> np.ndarray:
    """Baseline: the requested rotation split among the joints by fixed shares: each joint's rotation vector
    (radians) a fixed linear function of the requested yaw and pitch (radians), A_j (3, 2), fitted by least
    squares on the examples ``use`` that know the joint → (J, 3, 2), NaN for a joint with fewer than two."""
    yp = np.deg2rad(np.stack([gmap.yaw, gmap.pitch], axis=1))
    shares = np.full((len(gmap.segments) + 1, 3, 2), np.nan)
    for j in range(len(shares)):
        rows = np.flatnonzero(use & gmap.known[:, j])
        if len(rows) >= 2:
            rv = Rotation.from_quat(gmap.p_plus[rows, j][:, [1, 2, 3, 0]]).as_rotvec()
            shares[j] = np.linalg.lstsq(yp[rows], rv, rcond=None)[0].T
    return shares


def shares_pose(shares: np.ndarray, yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """The fixed-shares baseline's P+ (J, 4) w, x, y, z for a request (degrees)."""
    rv = shares @ np.deg2rad([yaw_deg, pitch_deg])
    out = np.full((len(shares), 4), np.nan)
    ok = np.isfinite(rv).all(axis=1)
    out[ok] = Rotation.from_rotvec(rv[ok]).as_quat()[:, [3, 0, 1, 2]]
    return out


def evaluate(gmap: GazeMap, held: GazeMap | None = None) -> dict[str, Any]:
    """Final-pose errors (degrees, per joint then the worst joint) of the map's motions against examples:
    ``held`` (examples not in the map) or, when ``None``, each of the map's own left out in turn; and the same
    for the :data:`BASELINES` (built from the same examples the map uses for each request). Only the joints
    an example knows, and the map and both baselines can give, are compared (``compared`` counts them), so
    the three figures are over the same joints; an example with none counts for the duration only."""
    ref = held if held is not None else gmap
    n_joints = len(ref.segments) + 1
    names = ["map", *BASELINES]
    errs = {k: np.full((len(ref), n_joints), np.nan) for k in names}
    dur = []
    everyone = np.ones(len(gmap), bool)
    fixed = None if held is None else (mean_shift(gmap, everyone), fit_shares(gmap, everyone))
    for i in range(len(ref)):
        m = gmap.motion(ref.yaw[i], ref.pitch[i], exclude=None if held is not None else i)
        if fixed is None:
            use = everyone.copy()
            use[i] = False
            mean_i, shares_i = mean_shift(gmap, use), fit_shares(gmap, use)
        else:
            mean_i, shares_i = fixed
        poses = {"map": m.p_plus, "mean_shift": mean_i, "fixed_shares": shares_pose(shares_i, ref.yaw[i],
                                                                                    ref.pitch[i])}
        ok = ref.known[i, :n_joints].copy()
        for pose in poses.values():
            ok &= np.isfinite(pose).all(axis=1)
        for k, pose in poses.items():
            errs[k][i, ok] = pose_error_deg(pose[ok], ref.p_plus[i, ok])
        dur.append(abs(m.duration_s - ref.duration[i]))
    seen = np.isfinite(errs["map"])
    per_joint = [float(errs["map"][seen[:, j], j].mean()) if seen[:, j].any() else None for j in range(n_joints)]
    worst = {k: np.array([e[i, seen[i]].max() for i in range(len(ref)) if seen[i].any()]) for k, e in errs.items()}
    out: dict[str, Any] = {
        "examples": len(ref), "compared": int(seen.sum()), "not_compared": int((~seen).sum()),
        "final_pose_error_deg_mean": float(worst["map"].mean()) if worst["map"].size else None,
        "final_pose_error_deg_max": float(worst["map"].max()) if worst["map"].size else None,
        "final_pose_error_deg_per_joint_mean": dict(zip(ref.segments + ["eyes"], per_joint, strict=True)),
        "duration_error_s_mean": float(np.mean(dur))}
    for k in BASELINES:
        out[f"{k}_final_pose_error_deg_mean"] = float(worst[k].mean()) if worst[k].size else None
    return out


def summary(metrics: dict[str, Any]) -> list[str]:
    """One line per evaluation (leave-one-out, each held-out split): the map's final-pose error against each
    baseline's, degrees."""
    lines = []
    for key, what in (("leave_one_out", "leave-one-out"), ("val", "val split"), ("test", "test split")):
        ev = metrics.get(key)
        if not ev:
            continue
        mine = ev["final_pose_error_deg_mean"]
        head = (f"{what} ({ev['examples']} examples): final-pose error (worst joint per example, mean), "
                "degrees: ")
        if mine is None:
            lines.append(head + "no joint could be compared")
            continue
        parts = [_against(mine, ev[f"{k}_final_pose_error_deg_mean"], name) for k, name in BASELINES.items()]
        lines.append(head + f"{mine:.3g} for the map; " + "; ".join(parts))
    return lines or ["no example to evaluate against (one training example and no val or test rows)"]


def _against(mine: float, theirs: float | None, name: str) -> str:
    if theirs is None:
        return f"{name}: none"
    if theirs <= 0:
        return f"{theirs:.3g} for {name} ({'the same' if mine <= 0 else 'worse: the baseline is exact'})"
    if abs(theirs - mine) / theirs < 0.005:
        return f"{theirs:.3g} for {name} (the same, within 0.5 %)"
    change = (theirs - mine) / theirs * 100.0
    word = f"{change:.0f} % better" if change > 0 else f"{-change:.0f} % worse"
    return f"{theirs:.3g} for {name} ({word})"


class GazeMapTrainer:
    """Builds the parametric gaze map from the training rows (mirrored copies included) and saves it."""

    name = "gaze_map"
    dataset = "gaze_map"
    schema_version = 3
    required_columns = ("yaw_deg", "pitch_deg", "duration_s", "start_times", "overshoot_time", "overshoot", "p_plus")
    knobs: tuple[str, ...] = ()
    options = options_table(
        Option("k", int, 4, "neighbours blended per request (Kovar-Gleicher k)", min=1),
        Option("train_split", str, "train", "the split whose rows form the map", choices=("train", "val", "test")),
    )

    def train(self, data, out_dir: Path, options: TrainOptions) -> dict[str, Any]:
        check_options(self, options)
        k = int(options.get("k", 4))
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
        metrics["summary"] = summary(metrics)
        out = Path(out_dir)
        write_atomic(out / WEIGHTS, npz_bytes(gmap.arrays()))
        save_model_json(out, self.name, {"k": k, "train_split": split, "segments": segments}, metrics, data,
                        WEIGHTS)
        return metrics
