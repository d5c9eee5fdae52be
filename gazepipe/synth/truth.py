"""Ground truth of a synthetic take: character frame, segment rotations, rests and crop, gaze-map parameters.

Every quantity is derived from the NOISE-FREE kinematics with the rules of SPEC §2, §3.2 and §3.6, so the
pipeline's output on the noisy files can be compared with it. Quaternions are ``w, x, y, z`` with ``w >= 0``.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.synth.markers import Kinematics
from gazepipe.synth.motion import HEAD, TakeMotion, gaze_rotation
from gazepipe.synth.skeleton import HEAD_CENTRE_MARKER, ROOT_MARKER, SEGMENT_MARKERS, SEGMENTS, TARGET_MARKER

REST_SPEED_MM_S = 6.0
REST_MERGE_S = 1.0 / 6.0
REST_MIN_S = 0.25
START_SPEED_DEG_S = 18.0
OVERSHOOT_WINDOW_S = 0.1


def quat_wxyz(r: Rotation) -> np.ndarray:
    """(T, 4) quaternions w, x, y, z with w >= 0."""
    q = np.atleast_2d(r.as_quat())[:, [3, 0, 1, 2]]
    return np.where(q[:, :1] < 0, -q, q)


def character_frame(markers: np.ndarray, labels: list[str]) -> tuple[Rotation, np.ndarray]:
    """SPEC §2 character frame per frame from (noise-free) markers in a Z-up lab.

    Returns the rotation from character axes to lab axes (T stack) and the origin (the root marker), (T, 3) mm.
    left = horizontal part of (PEL_L − PEL_R), up = lab Z, forward = left × up.
    """
    first, second = list(SEGMENT_MARKERS["pelvis"])[:2]
    d = markers[:, labels.index(first)] - markers[:, labels.index(second)]
    left = d * np.array([1.0, 1.0, 0.0])
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), left.shape)
    fwd = np.cross(left, up)
    return Rotation.from_matrix(np.stack([left, up, fwd], axis=2)), markers[:, labels.index(ROOT_MARKER)]


def subject_columns(labels: list[str]) -> list[int]:
    """Columns of the subject's markers (not the target, not the clapper)."""
    return [i for i, lab in enumerate(labels) if lab != TARGET_MARKER and not lab.startswith("CLAP")]


def rest_periods(xyz: np.ndarray, rate_hz: float, speed_mm_s: float = REST_SPEED_MM_S,
                 merge_s: float = REST_MERGE_S, min_s: float = REST_MIN_S) -> np.ndarray:
    """Rest periods (R, 2) as half-open frame ranges (SPEC §3.2) from subject positions (T, M, 3) in mm.

    Speed by central differences (one-sided at the ends) on the given positions; no low-pass here since the
    truth uses noise-free positions.
    """
    speed = np.linalg.norm(np.gradient(xyz, axis=0), axis=2).mean(axis=1) * rate_hz
    still = np.concatenate([[0], (speed < speed_mm_s).astype(np.int8), [0]])
    d = np.diff(still)
    runs = [[int(a), int(b)] for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True)]
    merged: list[list[int]] = []
    for r in runs:
        if merged and (r[0] - merged[-1][1]) / rate_hz < merge_s:
            merged[-1][1] = r[1]
        else:
            merged.append(r)
    keep = [r for r in merged if (r[1] - r[0]) / rate_hz >= min_s]
    return np.array(keep, dtype=np.int64).reshape(-1, 2)


def crop_bounds(rests: np.ndarray, kind: str) -> tuple[int, int] | None:
    """gaze_shift: [end of first rest, end of second rest); other kinds: [end of first rest, start of last)."""
    if len(rests) < 2:
        return None
    if kind == "gaze_shift":
        return int(rests[0, 1]), int(rests[1, 1])
    return int(rests[0, 1]), int(rests[-1, 0])


def _local(rots: list[Rotation]) -> list[Rotation]:
    return [rots[0]] + [rots[k - 1].inv() * rots[k] for k in range(1, len(rots))]


def _angular_speed(r: Rotation, rate_hz: float) -> np.ndarray:
    """|ω| in rad/s by central differences (one-sided at the ends), (T,)."""
    n = len(r)
    w = np.zeros(n)
    if n < 3:
        return w
    w[1:-1] = np.linalg.norm((r[2:] * r[:-2].inv()).as_rotvec(), axis=1) * rate_hz / 2.0
    w[0] = np.linalg.norm((r[1] * r[0].inv()).as_rotvec()) * rate_hz
    w[-1] = np.linalg.norm((r[n - 1] * r[n - 2].inv()).as_rotvec()) * rate_hz
    return w


def _overshoot(rot: Rotation, c0: int, c1: int, rate_hz: float, l_s: float) -> tuple[float, float, int]:
    """SPEC §3.6 overshoot of a rotation stack over the crop [c0, c1): (t_β as a fraction of l, β, frame).

    θ(t) = rotvec(R(t)·R(c0)⁻¹) · n, n the unit axis of the final displacement; velocity by central
    differences; the first + to − sign change inside the crop whose mean velocity over ``OVERSHOOT_WINDOW_S``
    before is > 0 and after is < 0, placed by linear interpolation; β = θ(t_β)/θ(last) − 1.
    Returns (1, 0, −1) when there is none.
    """
    last = c1 - 1
    disp = rot * rot[c0].inv()
    axis = disp[last].as_rotvec()
    theta = disp.as_rotvec() @ (axis / max(float(np.linalg.norm(axis)), 1e-12))
    omega = np.gradient(theta) * rate_hz
    win = max(1, int(round(OVERSHOOT_WINDOW_S * rate_hz)))
    for i in range(max(c0 + 1, win), min(c1, len(omega) - win)):
        if omega[i - 1] > 0 >= omega[i] and omega[i - win:i].mean() > 0 and omega[i:i + win].mean() < 0:
            frac = omega[i - 1] / (omega[i - 1] - omega[i])
            tc = (i - 1 + frac - c0) / rate_hz
            th = theta[i - 1] + frac * (theta[i] - theta[i - 1])
            return float(tc / l_s), float(th / theta[last] - 1.0), int(i)
    return 1.0, 0.0, -1


def gaze_map_truth(seg_fixed: list[Rotation], crop: tuple[int, int], rests: np.ndarray, rate_hz: float,
                   yaw_deg: float, pitch_deg: float) -> dict[str, Any]:
    """SPEC §3.6 gaze_map quantities from segment rotations in the character frame fixed at the crop's first
    frame (T stacks), the crop and the rests."""
    c0, c1 = crop
    last = c1 - 1
    l_s = (int(rests[1, 0]) - c0) / rate_hz
    loc = _local(seg_fixed)
    start = []
    for r in loc:
        w = np.rad2deg(_angular_speed(r, rate_hz))[c0:c1]
        hit = np.flatnonzero(w > START_SPEED_DEG_S)
        start.append(float(hit[0] / rate_hz / l_s) if len(hit) else 0.0)
    p_plus = [quat_wxyz(r[last] * r[c0].inv())[0] for r in loc]
    d_head = seg_fixed[HEAD][last] * seg_fixed[HEAD][c0].inv()
    eyes = d_head.inv() * gaze_rotation(np.deg2rad(yaw_deg), np.deg2rad(pitch_deg))
    p_plus.append(quat_wxyz(eyes)[0])

    t_beta, beta, t_beta_frame = _overshoot(seg_fixed[HEAD], c0, c1, rate_hz, l_s)
    local_head = _overshoot(loc[HEAD], c0, c1, rate_hz, l_s)
    return {"l_s": l_s, "start_frac": dict(zip(SEGMENTS, start, strict=True)), "t_beta_frac": float(t_beta),
            "t_beta_frame": int(t_beta_frame), "beta": beta,
            "overshoot_head_local": {"t_beta_frac": local_head[0], "beta": local_head[1],
                                     "t_beta_frame": local_head[2]},
            "p_plus": {name: q.tolist() for name, q in zip((*SEGMENTS, "eyes"), p_plus, strict=True)}}


def take_truth(kind: str, motion: TakeMotion, kin: Kinematics, gap_mask: np.ndarray, gaps: np.ndarray,
               rate_hz: float, target: tuple[float, float] | None) -> tuple[dict[str, np.ndarray], dict]:
    """Arrays for the take's .npz and scalars for truth.json."""
    labels = kin.labels
    x = kin.markers_true
    c, origin = character_frame(x, labels)
    seg_lab = [kin.h_lab * q for q in kin.q_char0]
    seg_char = [c.inv() * g for g in seg_lab]
    to_char = c.inv() * kin.h_lab
    hc = x[:, labels.index(HEAD_CENTRE_MARKER)]
    if motion.target_lab is not None:
        tgt = motion.target_lab
    elif motion.sign_lab is not None:
        tgt = np.broadcast_to(motion.sign_lab, hc.shape)
    else:
        tgt = motion.fixation_lab
    tdir = c.inv().apply(tgt - hc)
    tdir /= np.linalg.norm(tdir, axis=1, keepdims=True)
    rests = rest_periods(x[:, subject_columns(labels)], rate_hz)
    crop = crop_bounds(rests, kind)
    f32 = np.float32
    arrays: dict[str, np.ndarray] = {
        "time_s": motion.time_s.astype(np.float64),
        "labels": np.array(labels),
        "segments": np.array(SEGMENTS),
        "markers_true": x.astype(f32),
        "gap_mask": gap_mask,
        "gaps": gaps,
        "seg_quat_char": np.stack([quat_wxyz(r) for r in seg_char], axis=1).astype(f32),
        "seg_quat_local": np.stack([quat_wxyz(r) for r in _local(seg_char)], axis=1).astype(f32),
        "seg_quat_lab": np.stack([quat_wxyz(r) for r in seg_lab], axis=1).astype(f32),
        "joints_lab": kin.joints_lab.astype(f32),
        "char_quat_lab": quat_wxyz(c).astype(np.float64),
        "char_origin_lab": origin.astype(np.float64),
        "head_centre_char": c.inv().apply(hc - origin).astype(f32),
        "target_dir_char": tdir.astype(f32),
        "eye_dir_char": to_char.apply(kin.eye_dir_char0).astype(f32),
        "eye_dir_head": kin.eye_in_head.astype(f32),
        "eye_left_dir_char": to_char.apply(kin.eye_left_char0).astype(f32),
        "eye_right_dir_char": to_char.apply(kin.eye_right_char0).astype(f32),
        "fixation_lab": motion.fixation_lab.astype(f32),
        "clap_times_s": np.asarray(motion.clap_times_s, dtype=np.float64),
        "rest_periods": rests,
        "crop": np.array(crop if crop else (-1, -1), dtype=np.int64),
    }
    scalars: dict[str, Any] = {
        "n_frames": int(len(motion.time_s)),
        "clap_times_s": [float(v) for v in motion.clap_times_s],
        "rest_periods": rests.tolist(),
        "crop": list(crop) if crop else None,
        "design": motion.design,
    }
    if kind == "gaze_shift" and crop is not None and target is not None:
        fixed = [c[crop[0]].inv() * g for g in seg_lab]
        scalars.update(gaze_map_truth(fixed, crop, rests, rate_hz, *target))
        scalars["target"] = {"yaw_deg": target[0], "pitch_deg": target[1]}
    return arrays, scalars


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` as a compressed .npz with fixed zip timestamps (byte-identical for equal input)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            body = io.BytesIO()
            np.lib.format.write_array(body, np.ascontiguousarray(arrays[name]), allow_pickle=False)
            zf.writestr(info, body.getvalue())
    path.write_bytes(buf.getvalue())


def load_truth(session_dir: str | Path, take_id: str) -> dict[str, Any]:
    """Read the truth of one take: every array of ``truth/<take_id>.npz`` plus its entry of truth.json.

    Returns a dict of numpy arrays (``labels`` and ``segments`` as lists of str) with the take's scalars
    under ``"scalars"`` and the session-level entries (seed, camera rotation, …) under ``"session"``.
    """
    root = Path(session_dir) / "truth"
    meta = json.loads((root / "truth.json").read_text())
    out: dict[str, Any] = {}
    with np.load(root / f"{take_id}.npz", allow_pickle=False) as z:
        for k in z.files:
            out[k] = z[k]
    for key in ("labels", "segments", "face_names"):
        if key in out:
            out[key] = [str(s) for s in out[key]]
    out["scalars"] = meta["takes"][take_id]
    out["session"] = {k: v for k, v in meta.items() if k != "takes"}
    return out
