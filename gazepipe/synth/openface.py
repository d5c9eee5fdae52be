"""Synthetic OpenFace FeatureExtraction CSV of the head-camera video: eye gaze in camera axes with noise,
confidence dips, blinks and failed frames, written in the OpenFace 2.x layout or the older ", " style.

Conventions (SPEC §1): ``gaze_0_*`` is the eye on the image's left = the subject's RIGHT eye, ``gaze_1_*`` the
subject's left eye; camera axes x right, y down, z forward (looking into the camera ≈ (0, 0, −1)). With R the
camera-to-head rotation (v_head = R · v_cam), each eye's vector is v_cam = Rᵀ · v_head.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import signal
from scipy.spatial.transform import Rotation

from gazepipe.synth.markers import Kinematics
from gazepipe.synth.motion import HEAD

#: confidence OpenFace reports on good frames, the gating threshold (SPEC §3.5) and the dips' range
CONF_GOOD = (0.90, 0.98)
CONF_THRESHOLD = 0.8
CONF_DIP = (0.30, 0.78)
EYE_NOISE_DEG = 2.0          # RMS angle of each eye's tracking noise
BLINK_S = (0.10, 0.30)
BLINK_EVERY_S = (2.0, 6.0)
DIP_FRAMES = (1, 20)
DIP_EVERY_S = (1.5, 5.0)
#: AUs written besides AU45 (intensity _r, then presence _c), a few landmark columns (68-point eye corners)
OTHER_AUS = ("AU01", "AU04", "AU12", "AU25")
LANDMARKS = (36, 39, 42, 45)


@dataclass
class EyeRows:
    """Per-video-frame eye tracking rows and their truth.

    ``right_cam``/``left_cam``: (N, 3) the vectors written (zeros on failed rows); ``true_*_head``: each eye's
    and the cyclopean true direction in head axes; ``lid``: eyelid closure in [0, 1] for the picture.
    """

    frame: np.ndarray
    timestamp: np.ndarray
    confidence: np.ndarray
    success: np.ndarray
    blink: np.ndarray
    low_conf: np.ndarray
    au45_r: np.ndarray
    right_cam: np.ndarray
    left_cam: np.ndarray
    true_right_head: np.ndarray
    true_left_head: np.ndarray
    true_cyc_head: np.ndarray
    lid: np.ndarray
    in_mocap: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """What gating should keep: success, confidence at or above the threshold, no blink."""
        return self.success & (self.confidence >= CONF_THRESHOLD) & ~self.blink


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _interp_dirs(t: np.ndarray, time_s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Unit vectors (T, 3) at times ``time_s`` interpolated to ``t`` (held at either end), renormalised."""
    return _unit(np.column_stack([np.interp(t, time_s, v[:, j]) for j in range(3)]))


def _runs(rng: np.random.Generator, n: int, fps: float, every_s: tuple[float, float],
          length: tuple[int, int], forbid: np.ndarray | None = None) -> np.ndarray:
    """A (N,) bool mask of runs of ``length`` frames (inclusive range) spaced ``every_s`` seconds apart;
    runs touching ``forbid`` are left out."""
    mask = np.zeros(n, dtype=bool)
    k = int(rng.uniform(*every_s) * fps * 0.5)
    while k < n:
        m = int(rng.integers(length[0], length[1] + 1))
        if forbid is None or not forbid[k:k + m].any():
            mask[k:k + m] = True
        k += m + int(rng.uniform(*every_s) * fps)
    return mask


def _noisy(rng: np.random.Generator, v: np.ndarray, sigma_deg: np.ndarray) -> np.ndarray:
    """``v`` (N, 3) turned by a random small rotation of RMS angle ``sigma_deg`` (N,) about axes ⟂ v."""
    raw = rng.standard_normal(v.shape)
    perp = raw - (raw * v).sum(axis=1, keepdims=True) * v
    rotvec = perp * (np.deg2rad(sigma_deg) / np.sqrt(2.0))[:, None]
    return Rotation.from_rotvec(rotvec).apply(v)


def eye_rows(rng: np.random.Generator, kin: Kinematics, time_s: np.ndarray, t_mocap: np.ndarray, fps: float,
             cam_to_head: Rotation, quiet: np.ndarray, blink_every_s: tuple[float, float] = BLINK_EVERY_S,
             dip_every_s: tuple[float, float] = DIP_EVERY_S) -> EyeRows:
    """Synthesise OpenFace rows for video frames seen at mocap times ``t_mocap`` (N,).

    ``quiet`` (N,) bool: frames where no blink may start or run (around the claps, so the video clap stays
    the only motion there). ``blink_every_s``, ``dip_every_s``: the range of seconds between blinks and between
    confidence dips.
    """
    n = t_mocap.size
    q_head = kin.q_char0[HEAD]
    left_head = q_head.inv().apply(kin.eye_left_char0)
    right_head = q_head.inv().apply(kin.eye_right_char0)
    tl = _interp_dirs(t_mocap, time_s, left_head)
    tr = _interp_dirs(t_mocap, time_s, right_head)
    tc = _interp_dirs(t_mocap, time_s, kin.eye_in_head)
    to_cam = cam_to_head.inv()

    blink = _runs(rng, n, fps, blink_every_s, (int(BLINK_S[0] * fps), int(BLINK_S[1] * fps)), forbid=quiet)
    low = _runs(rng, n, fps, dip_every_s, DIP_FRAMES)
    fail = _runs(rng, n, fps, (4.0, 12.0), (1, 6), forbid=blink)
    free = np.flatnonzero(~blink[n // 2:])
    if not fail.any() and free.size:     # at least one failed row in every file, however short
        fail[n // 2 + free[0]] = True

    # blink intensity: a bump above 1 inside the blink, a shoulder either side, small values elsewhere
    au45 = np.clip(0.15 + 0.1 * rng.standard_normal(n), 0.0, 0.6)
    pad = np.concatenate([[False], blink, [False]]).astype(np.int8)
    starts, stops = np.flatnonzero(np.diff(pad) == 1), np.flatnonzero(np.diff(pad) == -1)
    lid = np.zeros(n)
    for a, b in zip(starts, stops, strict=True):
        u = (np.arange(a, b) - a + 0.5) / (b - a)
        au45[a:b] = 1.0 + float(rng.uniform(0.6, 2.5)) * np.sin(np.pi * u)
        lid[a:b] = np.clip(1.3 * np.sin(np.pi * u), 0.0, 1.0)
        for k in (a - 1, b):
            if 0 <= k < n:
                au45[k] = float(rng.uniform(0.5, 0.9))
                lid[k] = 0.3

    conf = np.clip(0.94 + 0.02 * rng.standard_normal(n), *CONF_GOOD)
    conf[low] = rng.uniform(*CONF_DIP, size=int(low.sum()))
    conf[blink] = np.minimum(conf[blink], rng.uniform(0.86, 0.95, size=int(blink.sum())))
    sigma = np.full(n, EYE_NOISE_DEG)
    sigma[low] = 8.0
    cam_r = _noisy(rng, to_cam.apply(tr), sigma)
    cam_l = _noisy(rng, to_cam.apply(tl), sigma)
    # during a blink OpenFace's eye model follows the lid: the vectors drop (camera +y is down) and scatter
    drop = Rotation.from_euler("x", rng.uniform(15.0, 30.0, size=(int(blink.sum()), 1)), degrees=True)
    cam_r[blink] = _noisy(rng, drop.apply(cam_r[blink]), np.full(int(blink.sum()), 6.0))
    cam_l[blink] = _noisy(rng, drop.apply(cam_l[blink]), np.full(int(blink.sum()), 6.0))

    success = ~fail
    cam_r[fail] = 0.0
    cam_l[fail] = 0.0
    conf[fail] = rng.uniform(0.0, 0.05, size=int(fail.sum()))
    au45[fail] = 0.0
    in_mocap = (t_mocap >= time_s[0]) & (t_mocap <= time_s[-1])
    frame = np.arange(1, n + 1, dtype=np.int64)
    return EyeRows(frame=frame, timestamp=(frame - 1) / fps, confidence=conf, success=success,
                   blink=blink & success, low_conf=low & success, au45_r=au45, right_cam=cam_r, left_cam=cam_l,
                   true_right_head=tr, true_left_head=tl, true_cyc_head=tc, lid=lid, in_mocap=in_mocap)


def _smooth_pos(rng: np.random.Generator, n: int, fps: float, hi: float) -> np.ndarray:
    """A slowly varying AU intensity in [0, hi], mostly low."""
    b, a = signal.butter(2, 0.3, fs=fps)
    x = signal.filtfilt(b, a, rng.standard_normal(n + 400))[200:-200]
    x = (x - x.mean()) / (np.std(x) + 1e-12)
    return np.clip(hi * 0.3 * (x - 0.3), 0.0, hi)


def write_openface_csv(path: Path, rng: np.random.Generator, rows: EyeRows, cam_to_head: Rotation,
                       legacy: bool) -> None:
    """Write ``rows`` as an OpenFace CSV.

    ``legacy`` False: OpenFace 2.x (``frame, face_id, timestamp, confidence, success, gaze_0_*, gaze_1_*,
    gaze_angle_*, pose_*``, landmark and AU columns), "," separators. True: the older layout and style (no
    ``face_id`` or ``gaze_angle_*``; header and values separated by ", ", so every name and value after the
    first carries a leading space).
    """
    n = rows.frame.size
    fps = 1.0 / (rows.timestamp[1] - rows.timestamp[0]) if n > 1 else 60.0
    ok = rows.success
    cols: list[tuple[str, np.ndarray, str]] = [("frame", rows.frame, "d")]
    if not legacy:
        cols.append(("face_id", np.zeros(n, dtype=np.int64), "d"))
    cols += [("timestamp", rows.timestamp, ".3f"), ("confidence", rows.confidence, ".2f" if not legacy else ".6f"),
             ("success", ok.astype(np.int64), "d")]
    for e, v in ((0, rows.right_cam), (1, rows.left_cam)):
        cols += [(f"gaze_{e}_{a}", v[:, j], ".6f") for j, a in enumerate("xyz")]
    if not legacy:
        mean = rows.right_cam + rows.left_cam
        with np.errstate(invalid="ignore", divide="ignore"):
            ax = np.where(ok, np.arctan2(mean[:, 0], -mean[:, 2]), 0.0)
            ay = np.where(ok, np.arctan2(mean[:, 1], -mean[:, 2]), 0.0)
        cols += [("gaze_angle_x", ax, ".3f"), ("gaze_angle_y", ay, ".3f")]
    # the head as OpenFace sees it: about 12 cm in front of the camera, turned by the mount rotation
    pose_t = np.array([4.0, -18.0, 120.0]) + 0.4 * rng.standard_normal((n, 3))
    pose_r = cam_to_head.inv().as_euler("XYZ")[None, :] + 0.01 * rng.standard_normal((n, 3))
    cols += [(f"pose_T{a}", pose_t[:, j] * ok, ".1f") for j, a in enumerate("xyz")]
    cols += [(f"pose_R{a}", pose_r[:, j] * ok, ".3f") for j, a in enumerate("xyz")]
    corners = {36: (37.0, 38.5), 39: (55.0, 38.5), 42: (73.0, 38.5), 45: (91.0, 38.5)}
    cols += [(f"x_{i}", (corners[i][0] + 0.3 * rng.standard_normal(n)) * ok, ".1f") for i in LANDMARKS]
    cols += [(f"y_{i}", (corners[i][1] + 0.3 * rng.standard_normal(n)) * ok, ".1f") for i in LANDMARKS]
    other = {au: _smooth_pos(rng, n, fps, 2.5) * ok for au in OTHER_AUS}
    cols += [(f"{au}_r", other[au], ".2f") for au in OTHER_AUS]
    cols.append(("AU45_r", rows.au45_r * ok, ".2f"))
    cols += [(f"{au}_c", (other[au] >= 1.0).astype(np.float64), ".2f") for au in OTHER_AUS]
    cols.append(("AU45_c", rows.blink.astype(np.float64), ".2f"))

    sep = ", " if legacy else ","
    text_cols = [np.char.mod(f"%{fmt}", arr) for _, arr, fmt in cols]
    body = [sep.join(r) for r in zip(*text_cols, strict=True)]
    header = sep.join(name for name, _, _ in cols)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + "\n" + "\n".join(body) + "\n")
