"""Synthetic takes with known truth for the sync and eyes stages, shared by their tests and benchmarks
(``tests/stages/sync/test_sync.py``, ``tests/stages/eyes/test_eyes.py``, ``bench/bench_sync.py``, ``bench/bench_eyes.py``).

Clapper. The model (used for the mocap curves and for the videos alike): shut, opened over 0.3 s, held open, then
closed with constant acceleration over ``closing_s`` so that the arms hit each other at full speed at the contact
instant, and stay shut. Videos are rendered from the same model on the mocap clock, sampled at
t_mocap = offset + ratio · t_video for every frame's timestamp, with motion blur over a half-frame exposure
centred on the timestamp, sensor noise and a slowly moving distractor, and written with OpenCV.

Eyes. A take built from a known truth: a camera rotation, head rotations, a target that jumps between goals (or
keeps moving), eyes that follow it 0.2 s late, OpenFace-like per-eye vectors with angular noise, confidence
dips, blinks with junk gaze, success == 0 rows with junk gaze, and a video clock with an offset and a rate error
against the mocap clock (:func:`make_scene`); or the sample session's own eyes (:func:`sample_scene`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.io.tracks import EyeTrack
from gazepipe.io.video import FrameReader
from gazepipe.stages.geometry import from_wxyz, slerp_vectors, to_wxyz

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "session01"

# ------------------------------------------------------------------------------------------------- clapper
OPEN_MM, SHUT_MM = 150.0, 25.0
W, H, FPS = 160, 120, 60.0


def clapper_distance(t: np.ndarray, contacts: np.ndarray, closing_s: np.ndarray) -> np.ndarray:
    """Distance (mm) between the clapper markers at mocap times t, for claps at ``contacts``."""
    d = np.full(t.shape, SHUT_MM)
    for tc, tcl in zip(contacts, closing_s, strict=True):
        t_open = tc - tcl - 0.6
        x = np.clip((t - t_open) / 0.3, 0.0, 1.0)
        opening = x * x * (3.0 - 2.0 * x)
        u = np.clip((t - (tc - tcl)) / tcl, 0.0, 1.0)
        inside = (t >= t_open) & (t < tc)
        d = np.where(inside, SHUT_MM + (OPEN_MM - SHUT_MM) * opening * (1.0 - u * u), d)
    return d


def clapper_markers(rng: np.random.Generator, n: int, rate: float, contacts, closing_s, noise_mm: float):
    """Two clapper markers (n, 3) mm with Gaussian noise per coordinate, carried slowly around."""
    t = np.arange(n) / rate
    d = clapper_distance(t, np.asarray(contacts), np.asarray(closing_s))
    centre = np.column_stack([300 * np.sin(0.2 * t), 200 * np.cos(0.15 * t), 1500 + 50 * np.sin(0.3 * t)])
    axis = np.array([0.2, 0.3, 0.93])
    axis /= np.linalg.norm(axis)
    a = centre + rng.normal(0, noise_mm, (n, 3))
    b = centre + d[:, None] * axis + rng.normal(0, noise_mm, (n, 3))
    return a, b, np.ones(n, bool), np.ones(n, bool)


def write_clapper_video(path: Path, n_frames: int, contacts_mocap, closing_s, *, offset: float, ratio: float,
                        seed: int = 0, fourcc: str = "mp4v", sensor_noise: float = 1.5,
                        arm_h: float = 40.0) -> Path:
    """A 160x120 video labelled 60 fps whose clapper closes at ``contacts_mocap`` (mocap clock) given
    t_mocap = offset + ratio · t_video, with Gaussian sensor noise of ``sensor_noise`` grey levels; the moving
    arm is ``arm_h`` pixels tall and travels 50 pixels."""
    rng = np.random.default_rng(seed)
    px_per_mm, shut_bottom = 0.4, 85.0
    ns, exposure = 8, 0.5 / FPS
    sub = (np.arange(ns) + 0.5) / ns - 0.5
    yy = np.arange(H, dtype=np.float64)
    bg = cv2.GaussianBlur(rng.uniform(30, 90, (H, W)), (0, 0), 3.0)
    bg[86:96, 30:130] = 200.0  # the lower arm
    noise = rng.normal(0, sensor_noise, (64, H, W)).astype(np.float32)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), FPS, (W, H))
    assert writer.isOpened()
    contacts_mocap, closing_s = np.asarray(contacts_mocap), np.asarray(closing_s)
    for c0 in range(0, n_frames, 256):
        idx = np.arange(c0, min(c0 + 256, n_frames))
        tm = offset + ratio * (idx[:, None] / FPS + sub[None, :] * exposure)  # (F, ns) mocap times
        d = clapper_distance(tm, contacts_mocap, closing_s)
        bottom = shut_bottom - (d - SHUT_MM) * px_per_mm
        top = bottom - arm_h
        cover = np.clip(np.minimum(yy + 1, bottom[..., None]) - np.maximum(yy, top[..., None]), 0, 1).mean(1)
        img = np.repeat(bg[None].astype(np.float32), idx.size, axis=0)
        img[:, :, 30:130] += (230.0 - img[:, :, 30:130]) * cover[:, :, None]
        # a slow distractor (a dark blob drifting across the left edge) and sensor noise (from a pool)
        cx = 12 + 8 * np.sin(idx / FPS * 0.7)
        bx = np.exp(-((np.arange(W)[None, :] - cx[:, None]) ** 2) / 50)
        by = np.exp(-((yy - 60) ** 2) / 50)
        img -= 40 * by[None, :, None] * bx[:, None, :]
        img += noise[rng.integers(0, len(noise), idx.size)]
        for fr in np.clip(np.rint(img), 0, 255).astype(np.uint8):
            writer.write(cv2.cvtColor(fr, cv2.COLOR_GRAY2BGR))
    writer.release()
    return path



class CountingReader:
    """``read_window`` over a file through one :class:`gazepipe.io.video.FrameReader` (as the pipeline reads a
    take's video), recording what was asked for and how many frames came back."""

    def __init__(self, path: Path, timestamps: np.ndarray) -> None:
        self.path, self.ts = path, timestamps
        self.calls: list[tuple[int, int]] = []
        self.frames = 0
        self._reader: FrameReader | None = None

    def __call__(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        self.calls.append((start, stop))
        if self._reader is None:
            self._reader = FrameReader(self.path, timestamps_s=self.ts)
        t, fr = self._reader(start, stop)
        self.frames += len(fr)
        return t, fr

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None


# ------------------------------------------------------------------------------------------------- eyes



MOCAP_HZ = 30000 / 1001
VIDEO_HZ = 60.0
LAG_S = 0.2            # the eyes follow the target this late
IPD_MM = 63.0
JUNK_DOWN_DEG = 25.0   # OpenFace's gaze during a blink drops well below the truth


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)



def true_camera_rotation() -> Rotation:
    """A camera below and in front of the face, looking back at it, tilted up 18°, turned 7°, rolled 3°."""
    facing = Rotation.from_matrix(np.diag([1.0, -1.0, -1.0]))
    return Rotation.from_euler("yxz", [7.0, 18.0, 3.0], degrees=True) * facing


def tangent_noise(rng: np.random.Generator, v: np.ndarray, rms_deg: float) -> np.ndarray:
    """Unit vectors v perturbed by isotropic angular noise of the given RMS angle."""
    s = np.deg2rad(rms_deg) / np.sqrt(2.0)
    n = rng.normal(0.0, s, v.shape)
    n -= np.sum(n * v, axis=1, keepdims=True) * v
    return unit(v + n)


@dataclass
class Scene:
    eye: EyeTrack
    joints: SimpleNamespace
    mocap_time_s: np.ndarray
    clock: SimpleNamespace
    cam: Rotation
    eye_dir_char: np.ndarray     # truth per mocap frame
    eye_dir_head: np.ndarray
    video_eye_cam: np.ndarray    # noise-free cyclopean truth per video sample, camera axes
    head_missing: np.ndarray     # mocap frames given no head rotation


def make_scene(seed: int = 0, *, duration_s: float = 40.0, noise_deg: float = 2.5, offset_s: float = 0.7,
               ratio: float = 1.0004, centre_error_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
               pursuit: bool = False) -> Scene:
    """A synthetic take with its truth (see the module docstring); every random choice comes from ``seed``.

    The target jumps between goals (an eased 0.35 s move, then still), or with ``pursuit`` keeps moving from
    goal to goal at constant speed (as Klein's pole does), so the eyes' delay matters on every frame.

    ``centre_error_mm`` (head axes) displaces the point the joints' target direction is measured from, as when
    the head markers' centroid stands in for the eyes' centre.
    """
    rng = np.random.default_rng(seed)
    cam = true_camera_rotation()
    # target goals in the character frame, mm; the eyes' centre sways a little around (0, 1600, 0)
    n_goals = int(duration_s / 1.2) + 2
    jumps = np.cumsum(rng.uniform(1.2, 2.5, n_goals - 1))
    yaw = rng.uniform(-50, 50, n_goals)
    pitch = rng.uniform(-20, 20, n_goals)
    dist = rng.uniform(1500, 3000, n_goals)
    goal_dir = Rotation.from_euler("YX", np.stack([yaw, -pitch], 1), degrees=True).apply([0.0, 0.0, 1.0])
    phase = rng.uniform(0, 2 * np.pi, 4)

    def centre(t: np.ndarray) -> np.ndarray:
        return np.stack([20 * np.sin(0.3 * t + phase[0]), 1600 + 5 * np.sin(0.5 * t), 10 * np.sin(0.2 * t)], 1)

    def target(t: np.ndarray) -> np.ndarray:
        k = np.searchsorted(jumps, t)                      # goal index: before jumps[k]
        prev = np.clip(k - 1, 0, None)
        since = t - jumps[prev]
        if pursuit:                                        # constant speed from goal k-1 to goal k
            leg = jumps[np.clip(k, 0, len(jumps) - 1)] - jumps[prev]
            u = np.where(k == 0, 1.0, np.clip(since / np.where(leg > 0, leg, 1.0), 0.0, 1.0))
        else:                                              # eased 0.35 s move from goal k-1 to goal k
            u = np.clip(since / 0.35, 0.0, 1.0)
            u = np.where(k == 0, 1.0, u * u * (3 - 2 * u))
        p0 = goal_dir[prev] * dist[prev, None]
        p1 = goal_dir[k] * dist[k, None]
        return (1 - u)[:, None] * p0 + u[:, None] * p1 + np.array([0.0, 1600.0, 0.0])

    def head(t: np.ndarray) -> Rotation:
        y = 25 * np.sin(2 * np.pi * 0.043 * t + phase[1])
        p = 8 * np.sin(2 * np.pi * 0.061 * t + phase[2])
        r = 4 * np.sin(2 * np.pi * 0.05 * t + phase[3])
        return Rotation.from_euler("YXZ", np.stack([y, -p, r], 1), degrees=True)

    # mocap frames
    n = int(duration_s * MOCAP_HZ)
    tm = np.arange(n) / MOCAP_HZ
    rh = head(tm)
    c = centre(tm)
    tdir = unit(target(tm) - c - rh.apply(np.asarray(centre_error_mm, dtype=np.float64)))
    eye_char = unit(target(tm - LAG_S) - c)
    head_q = to_wxyz(rh)
    head_missing = np.zeros(n, dtype=bool)
    head_missing[rng.choice(n, 12, replace=False)] = True
    head_q[head_missing] = np.nan
    quat = np.stack([np.tile([1.0, 0, 0, 0], (n, 1)), head_q], axis=1)
    joints = SimpleNamespace(segments=["pelvis", "head"], quat=quat, target_dir=tdir, rate_hz=MOCAP_HZ)

    # video samples on the video clock, mapped to the mocap clock for the truth
    m = int((duration_s - offset_s - 1.0) / ratio * VIDEO_HZ)
    tv = np.arange(m) / VIDEO_HZ
    t_on_mocap = offset_s + ratio * tv
    rhv = head(t_on_mocap)
    cv = centre(t_on_mocap)
    tgt = target(t_on_mocap - LAG_S)
    eyes = []
    for side in (+1.0, -1.0):        # subject's left eye is +X in head axes
        pos = cv + rhv.apply(np.array([side * IPD_MM / 2, 0.0, 0.0]))
        d_head = rhv.inv().apply(unit(tgt - pos))
        eyes.append(cam.inv().apply(d_head))
    left, right = eyes
    video_truth = cam.inv().apply(rhv.inv().apply(unit(tgt - cv)))
    left = tangent_noise(rng, left, noise_deg)
    right = tangent_noise(rng, right, noise_deg)

    conf = np.clip(0.93 + 0.02 * rng.normal(size=m), 0.81, 0.99)
    success = np.ones(m, dtype=bool)
    blink = np.zeros(m, dtype=bool)
    # confidence dips, short (fillable) and long
    for length in (2, 3, 4, 6, 6, 7, 9, 15, 30, 1):
        s = rng.integers(30, m - 60)
        conf[s:s + length] = rng.uniform(0.2, 0.79)
    # blinks: 4–9 samples; the gaze drops by JUNK_DOWN_DEG
    down = Rotation.from_euler("x", -JUNK_DOWN_DEG, degrees=True)   # camera x: rotating −x tilts the gaze down
    t_blink = 1.0
    while True:
        t_blink += rng.uniform(2.0, 4.0)
        s = int(t_blink * VIDEO_HZ)
        if s >= m - 20:
            break
        length = int(rng.integers(4, 10))
        blink[s:s + length] = True
        left[s:s + length] = down.apply(left[s:s + length])
        right[s:s + length] = down.apply(right[s:s + length])
    # lost tracking: junk directions, confidence 0
    for length in (20, 1, 5):
        s = rng.integers(30, m - 60)
        success[s:s + length] = False
        conf[s:s + length] = 0.0
        left[s:s + length] = unit(rng.normal(size=(length, 3)))
        right[s:s + length] = unit(rng.normal(size=(length, 3)))
    eye = EyeTrack(time_s=tv, frame=np.arange(1, m + 1), success=success, confidence=conf, gaze_left=left,
                   gaze_right=right, blink=blink)
    return Scene(eye=eye, joints=joints, mocap_time_s=tm, clock=SimpleNamespace(offset_s=offset_s, ratio=ratio),
                 cam=cam, eye_dir_char=eye_char, eye_dir_head=rh.inv().apply(eye_char), video_eye_cam=video_truth,
                 head_missing=head_missing)



def sample_scene(take: str, seed: int = 21, noise_deg: float = 2.5) -> tuple[Scene, np.ndarray]:
    """The sample generator's eyes for ``take`` (pursuit with catch-up saccades, a 45° eye limit, a body that
    turns) seen through its true camera rotation, at 60 Hz on a shifted video clock, with per-eye noise and
    blinks with junk gaze; joints from the truth. Returns the scene and the truth's eye_dir_char."""
    from gazepipe.synth import load_truth

    tr = load_truth(SAMPLE, take)
    cam = from_wxyz(np.asarray(tr["session"]["camera_to_head_quat"]))
    tm = tr["time_s"]
    eye_head = tr["eye_dir_head"].astype(np.float64)
    clock = SimpleNamespace(offset_s=0.4, ratio=0.9997)
    tv = np.arange(int((tm[-1] - 0.9) / clock.ratio * VIDEO_HZ)) / VIDEO_HZ
    pos = np.interp(clock.offset_s + clock.ratio * tv, tm, np.arange(tm.size))
    i0 = np.minimum(pos.astype(np.int64), tm.size - 2)
    true_cam = cam.inv().apply(slerp_vectors(eye_head[i0], eye_head[i0 + 1], pos - i0))
    rng = np.random.default_rng(seed)
    m = tv.size
    left, right = tangent_noise(rng, true_cam, noise_deg), tangent_noise(rng, true_cam, noise_deg)
    blink = np.zeros(m, dtype=bool)
    for s in rng.integers(0, m - 10, 12):
        blink[s:s + 8] = True
    left[blink] = right[blink] = unit(np.array([0.7, 0.7, 0.1]))   # junk: away from the face, far off any truth
    eye = EyeTrack(time_s=tv, frame=np.arange(1, m + 1), success=np.ones(m, bool), confidence=np.full(m, 0.9),
                   gaze_left=left, gaze_right=right, blink=blink)
    joints = SimpleNamespace(segments=list(tr["segments"]), quat=tr["seg_quat_char"].astype(np.float64),
                             target_dir=tr["target_dir_char"].astype(np.float64), rate_hz=tr["scalars"]["rate_hz"],
                             char_rot=tr["char_quat_lab"])
    head = from_wxyz(joints.quat[:, -1])
    truth_char = tr["eye_dir_char"].astype(np.float64)
    sc = Scene(eye=eye, joints=joints, mocap_time_s=tm, clock=clock, cam=cam, eye_dir_char=truth_char,
               eye_dir_head=eye_head, video_eye_cam=true_cam, head_missing=np.zeros(tm.size, dtype=bool))
    assert np.allclose(head.apply(eye_head), truth_char, atol=1e-4)   # the truth's own consistency
    return sc, truth_char


def eyes_on_truth(session: Path, take: str):
    """The eyes stage on a generated session's own OpenFace CSV of ``take``, with the truth's joints and clock map
    as its inputs: ``(truth, eye track, EyesResult)``."""
    from gazepipe.io.openface import read_openface
    from gazepipe.stages.eyes.stage import eyes_take
    from gazepipe.synth import load_truth

    tr = load_truth(session, take)
    sc = tr["scalars"]
    eye = read_openface(session / sc["eyes"]["path"])
    clock = SimpleNamespace(offset_s=sc["video"]["offset_s"], ratio=sc["video"]["ratio"])
    joints = SimpleNamespace(segments=list(tr["segments"]), quat=tr["seg_quat_char"].astype(np.float64),
                             target_dir=tr["target_dir_char"].astype(np.float64), rate_hz=sc["rate_hz"],
                             char_rot=tr["char_quat_lab"])
    return tr, eye, eyes_take(eye, joints, tr["time_s"], clock)
