"""Synthetic Live Link Face takes: a clean (hand-cleaned) and a tracked (raw) CSV per ``face`` take, with their truth.

Format as in ``corpus/livelinkface`` (SPEC §1): ``Timecode, BlendShapeCount`` (61), the 52 blendshapes in Live
Link Face's PascalCase order (JawRight before JawLeft, MouthRight before MouthLeft), head yaw/pitch/roll, then
the left and right eyes' yaw/pitch/roll, radians. Timecode ``HH:MM:SS:FF.fff`` at 60 fps whatever the capture
rate (a 30 Hz capture steps FF by 2); dropped capture frames are missing rows (larger steps).

The clean track is smooth and plausible: a few latent expressions (speech, smile, brows, gaze, blinks) mixed
into the channels, left and right mostly symmetric with a small fixed asymmetry. The tracked track is what a
tracker makes of it: a per-channel gain and offset, cross-talk (jaw into mouthClose, smile into eyeSquint),
blinks that never quite close, timing jitter, white noise and occasional outlier spikes.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import signal

from gazepipe.arkit import ARKIT_NAMES, normalise_name

if TYPE_CHECKING:
    from gazepipe.synth.record import TakeRecord

TIMECODE_FPS = 60
#: Live Link Face's blendshape columns, in its file order (corpus/livelinkface)
LLF_BLENDSHAPES: tuple[str, ...] = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight",
    "EyeSquintRight", "EyeWideRight", "JawForward", "JawRight", "JawLeft", "JawOpen", "MouthClose", "MouthFunnel",
    "MouthPucker", "MouthRight", "MouthLeft", "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft",
    "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft", "MouthStretchRight",
    "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper", "MouthPressLeft", "MouthPressRight",
    "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft", "MouthUpperUpRight", "BrowDownLeft",
    "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight", "CheekPuff", "CheekSquintLeft",
    "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight", "TongueOut",
)
LLF_ANGLES: tuple[str, ...] = ("HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
                               "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
LLF_HEADER: tuple[str, ...] = ("Timecode", "BlendShapeCount", *LLF_BLENDSHAPES, *LLF_ANGLES)
#: file column of every canonical ARKit channel
_FILE_ORDER = np.array([ARKIT_NAMES.index(normalise_name(n)) for n in LLF_BLENDSHAPES])
_IDX = {n: i for i, n in enumerate(ARKIT_NAMES)}


def _smooth(rng: np.random.Generator, n: int, rate: float, cutoff_hz: float) -> np.ndarray:
    """Zero-mean, unit-variance low-passed noise (n,)."""
    b, a = signal.butter(2, min(cutoff_hz, 0.45 * rate), fs=rate)
    x = signal.filtfilt(b, a, rng.standard_normal(n + 200))[100:-100]
    return (x - x.mean()) / (x.std() + 1e-12)


def _act(x: np.ndarray, bias: float, gain: float = 1.0) -> np.ndarray:
    """Soft positive part in [0, 1): 0 well below ``bias``, rising smoothly above it."""
    z = np.maximum(x - bias, 0.0) * gain
    return np.tanh(z)


def _blinks(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    out = np.zeros_like(t)
    s = float(rng.uniform(0.5, 2.0))
    while s < t[-1]:
        d = float(rng.uniform(0.15, 0.25))
        u = np.clip((t - s) / d, 0.0, 1.0)
        out = np.maximum(out, float(rng.uniform(0.85, 1.0)) * np.sin(np.pi * u) ** 2)
        s += d + float(rng.uniform(2.0, 5.0))
    return out


def _saccadic(rng: np.random.Generator, t: np.ndarray, rate: float, amp: float) -> np.ndarray:
    """Fixations held 0.3-1.5 s, joined by ~40 ms saccades (radians)."""
    knots = np.cumsum(rng.uniform(0.3, 1.5, size=int(t[-1] / 0.3) + 2))
    level = rng.uniform(-amp, amp, size=knots.size + 1)
    raw = level[np.searchsorted(knots, t)]
    b, a = signal.butter(2, min(12.0, 0.45 * rate), fs=rate)
    return signal.filtfilt(b, a, raw)


def clean_track(rng: np.random.Generator, t: np.ndarray, rate: float, head: bool) -> tuple[np.ndarray, np.ndarray]:
    """Smooth blendshapes (n, 52) in ARKit order in [0, 1], and angles (n, 9): head yaw/pitch/roll (zeros when
    ``head`` is False: head tracking off), left and right eye yaw/pitch/roll (radians)."""
    n = t.size
    v = np.zeros((n, len(ARKIT_NAMES)))
    speech_env = _act(_smooth(rng, n, rate, 0.25), -0.2, 1.5)
    jaw = 0.05 + 0.45 * speech_env * _act(_smooth(rng, n, rate, 3.0), -0.3, 0.8)
    smile = 0.75 * _act(_smooth(rng, n, rate, 0.2), 0.3, 0.9)
    brow_up = 0.6 * _act(_smooth(rng, n, rate, 0.4), 0.6, 1.2)
    frown = 0.5 * _act(_smooth(rng, n, rate, 0.3), 1.0, 1.2)
    pucker = 0.6 * speech_env * _act(_smooth(rng, n, rate, 1.5), 0.8, 1.0)
    lateral = 0.25 * _smooth(rng, n, rate, 0.5)
    yaw = _saccadic(rng, t, rate, 0.25)
    pitch = 0.05 + _saccadic(rng, t, rate, 0.12)
    blink = _blinks(rng, t)

    def put(name: str, x: np.ndarray) -> None:
        v[:, _IDX[name]] = x

    for side in ("Left", "Right"):
        put(f"eyeBlink{side}", blink)
        put(f"eyeLookUp{side}", np.clip(pitch / 0.3, 0, 1))
        put(f"eyeLookDown{side}", np.clip(-pitch / 0.3, 0, 1) + 0.3 * blink)
        put(f"eyeSquint{side}", 0.35 * smile + 0.15 * frown)
        put(f"eyeWide{side}", 0.6 * brow_up)
        put(f"mouthSmile{side}", smile)
        put(f"mouthFrown{side}", frown)
        put(f"mouthDimple{side}", 0.3 * smile)
        put(f"mouthStretch{side}", 0.2 * speech_env * _act(_smooth(rng, n, rate, 1.0), 0.5))
        put(f"mouthPress{side}", 0.3 * _act(_smooth(rng, n, rate, 0.6), 0.8))
        put(f"mouthLowerDown{side}", 0.5 * jaw)
        put(f"mouthUpperUp{side}", 0.25 * jaw + 0.2 * smile)
        put(f"browDown{side}", 0.7 * frown)
        put(f"browOuterUp{side}", 0.8 * brow_up)
        put(f"cheekSquint{side}", 0.5 * smile)
        put(f"noseSneer{side}", 0.25 * frown + 0.1 * smile)
    # subject's left eye looking to its left (yaw > 0) looks out; the right eye then looks in
    put("eyeLookOutLeft", np.clip(yaw / 0.4, 0, 1))
    put("eyeLookInRight", np.clip(yaw / 0.4, 0, 1))
    put("eyeLookInLeft", np.clip(-yaw / 0.4, 0, 1))
    put("eyeLookOutRight", np.clip(-yaw / 0.4, 0, 1))
    put("jawOpen", jaw)
    put("jawForward", 0.1 * _act(_smooth(rng, n, rate, 0.4), 0.5))
    put("jawLeft", np.clip(lateral, 0, None) * 0.4)
    put("jawRight", np.clip(-lateral, 0, None) * 0.4)
    put("mouthLeft", np.clip(lateral, 0, None) * 0.5)
    put("mouthRight", np.clip(-lateral, 0, None) * 0.5)
    put("mouthClose", 0.15 * speech_env * (1.0 - jaw))
    put("mouthFunnel", 0.5 * pucker)
    put("mouthPucker", pucker)
    put("mouthRollLower", 0.2 * _act(_smooth(rng, n, rate, 0.5), 0.9))
    put("mouthRollUpper", 0.15 * _act(_smooth(rng, n, rate, 0.5), 0.9))
    put("mouthShrugLower", 0.3 * frown + 0.1 * _act(_smooth(rng, n, rate, 0.5), 0.5))
    put("mouthShrugUpper", 0.2 * frown)
    put("browInnerUp", brow_up + 0.2 * frown)
    put("cheekPuff", 0.5 * _act(_smooth(rng, n, rate, 0.3), 1.5, 1.5))
    put("tongueOut", 0.6 * _act(_smooth(rng, n, rate, 0.5), 2.0, 2.0))

    # a fixed left/right asymmetry per pair, and a little independent drift
    for i, name in enumerate(ARKIT_NAMES):
        if name.endswith("Left"):
            j = _IDX[name[:-4] + "Right"]
            a = float(rng.uniform(-0.12, 0.12))
            v[:, i] *= 1.0 + a
            v[:, j] *= 1.0 - a
    v += 0.01 * np.stack([_smooth(rng, n, rate, 0.3) for _ in ARKIT_NAMES], axis=1)
    v = np.clip(v, 0.0, 1.0)

    ang = np.zeros((n, 9))
    if head:
        ang[:, 0] = 0.15 * _smooth(rng, n, rate, 0.3)
        ang[:, 1] = 0.08 * _smooth(rng, n, rate, 0.3)
        ang[:, 2] = 0.05 * _smooth(rng, n, rate, 0.3)
    ang[:, 3], ang[:, 4] = yaw, pitch
    ang[:, 6], ang[:, 7] = yaw - 0.02, pitch
    return v, ang


def tracked_track(rng: np.random.Generator, clean: np.ndarray, angles: np.ndarray,
                  head: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """What a tracker reports for a clean take: (values (n, 52), angles (n, 9), spike mask (n, 52), bias)."""
    c: int   # channels: sizes the per-channel arrays below
    n, c = clean.shape
    k = np.arange(n, dtype=np.float64)
    jitter = np.clip(0.25 * rng.standard_normal(n), -0.6, 0.6)        # capture-time jitter, frames
    at = np.clip(k + jitter, 0, n - 1)
    seen = np.column_stack([np.interp(at, k, clean[:, j]) for j in range(c)])
    gain = rng.uniform(0.85, 1.15, size=c)
    offset = rng.uniform(0.0, 0.04, size=c)
    for side in ("Left", "Right"):
        gain[_IDX[f"eyeBlink{side}"]] = rng.uniform(0.65, 0.8)        # blinks never quite close
    tr = seen * gain + offset
    tr[:, _IDX["mouthClose"]] += 0.15 * seen[:, _IDX["jawOpen"]]
    for side in ("Left", "Right"):
        tr[:, _IDX[f"eyeSquint{side}"]] += 0.25 * seen[:, _IDX[f"mouthSmile{side}"]]
    tr += 0.012 * rng.standard_normal(tr.shape)
    spikes = np.zeros((n, c), dtype=bool)
    for f in np.flatnonzero(rng.random(n) < 0.006):
        ch = rng.choice(c, size=int(rng.integers(1, 7)), replace=False)
        spikes[f, ch] = True
    tr[spikes] += rng.uniform(0.3, 0.7, size=int(spikes.sum()))
    tr = np.clip(tr, 0.0, 1.0)
    ang = np.column_stack([np.interp(at, k, angles[:, j]) for j in range(angles.shape[1])])
    ang += 0.01 * rng.standard_normal(ang.shape)
    if not head:
        ang[:, :3] = 0.0
    return tr, ang, spikes, {"gain": gain, "offset": offset}


def _drops(rng: np.random.Generator, n: int, rate: float, avoid: np.ndarray | None) -> np.ndarray:
    """(n,) bool, True for dropped capture frames: about one in 80 frames, singles and one double, never the
    first or last two frames, never where ``avoid`` is True, never adjacent to another drop."""
    drop = np.zeros(n, dtype=bool)
    for f in np.flatnonzero(rng.random(n) < 1.0 / 80.0):
        if 2 <= f < n - 3 and not drop[f - 1:f + 2].any() and (avoid is None or not avoid[f - 1:f + 2].any()):
            drop[f] = True
    mid = int(rng.integers(n // 3, 2 * n // 3))
    if not drop[mid - 1:mid + 3].any() and (avoid is None or not avoid[mid - 1:mid + 3].any()):
        drop[mid:mid + 2] = True                                      # one double drop
    return drop


def _tracking_loss(rng: np.random.Generator, n: int, rate: float, stretches: int) -> np.ndarray:
    """(n,) bool: ``stretches`` spans of 0.2–1.5 s in which ARKit lost the face (never the first or last second)."""
    lost = np.zeros(n, dtype=bool)
    for _ in range(stretches):
        length = int(round(rng.uniform(0.2, 1.5) * rate))
        lo, hi = int(rate), n - int(rate) - length
        if hi > lo:
            a = int(rng.integers(lo, hi))
            lost[a:a + length] = True
    return lost


def timecodes(start_tc_frames: float, t: np.ndarray) -> np.ndarray:
    """``HH:MM:SS:FF.fff`` strings at 60 fps for capture instants ``t`` seconds after ``start_tc_frames``."""
    milli = np.rint((start_tc_frames + t * TIMECODE_FPS) * 1000.0).astype(np.int64)
    frames, frac = np.divmod(milli, 1000)
    secs, ff = np.divmod(frames, TIMECODE_FPS)
    mins, ss = np.divmod(secs, 60)
    hh, mm = np.divmod(mins, 60)
    return np.array([f"{a:02d}:{b:02d}:{c:02d}:{d:02d}.{e:03d}"
                     for a, b, c, d, e in zip(hh % 24, mm, ss, ff, frac, strict=True)])


def write_llf_csv(path: Path, tc: np.ndarray, values: np.ndarray, angles: np.ndarray,
                  lost: np.ndarray | None = None) -> None:
    """Write rows (timecodes, (n, 52) ARKit-order values, (n, 9) angles) in Live Link Face's layout; rows where
    ``lost`` (n,) is True as the app writes them while ARKit has lost the face: the timecode and a count of 0."""
    body = np.column_stack([values[:, _FILE_ORDER], angles])
    cells = np.char.mod("%.10f", body)
    lines = [",".join(LLF_HEADER)]
    count = str(len(LLF_BLENDSHAPES) + len(LLF_ANGLES))
    lines += [f"{a},{count}," + ",".join(r) for a, r in zip(tc, cells, strict=True)]
    if lost is not None:
        for i in np.flatnonzero(lost):
            lines[i + 1] = f"{tc[i]},0"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def face_writer(session_dir: Path, take: TakeRecord) -> dict[str, Any]:
    """Write ``face/<take>_tracked.csv`` and ``face/<take>_clean.csv`` for a ``face`` take; add their truth.

    The capture rate is ``take.rate_hz``; the length ``take.truth_scalars["duration_s"]``. Head tracking is on
    for 60 Hz captures and off (all zero, as in the real corpus take) otherwise.
    """
    if take.kind != "face":
        return {}
    rng = take.rng
    rate = float(take.rate_hz)
    dur = float(take.truth_scalars.get("duration_s", 20.0))
    n = int(round(dur * rate))
    drift = float(rng.uniform(-3e-5, 3e-5))                            # phone clock against the timecode
    t = np.arange(n) / rate * (1.0 + drift)
    head = rate >= 59.0
    clean, ang_c = clean_track(rng, t, rate, head)
    tracked, ang_t, spikes, bias = tracked_track(rng, clean, ang_c, head)
    drop_clean = _drops(rng, n, rate, None)
    drop_tracked = _drops(rng, n, rate, drop_clean)
    start = float((rng.integers(9, 18) * 3600 + rng.integers(0, 3600)) * TIMECODE_FPS + rng.uniform(0, 59.999))
    tc = timecodes(start, t)
    # drawn last, and only when asked for: the rest of the take stays as it is without them
    n_loss = int(take.truth_scalars.get("tracking_loss_stretches", 0))
    lost = _tracking_loss(rng, n, rate, n_loss) if n_loss else None
    clean_rel = f"face/{take.id}_clean.csv"
    tracked_rel = f"face/{take.id}_tracked.csv"
    write_llf_csv(session_dir / clean_rel, tc[~drop_clean], clean[~drop_clean], ang_c[~drop_clean])
    write_llf_csv(session_dir / tracked_rel, tc[~drop_tracked], tracked[~drop_tracked], ang_t[~drop_tracked],
                  None if lost is None else lost[~drop_tracked])
    if lost is not None:
        take.truth_arrays["face_tracked_lost"] = lost & ~drop_tracked
        take.truth_scalars["lost_tracked"] = int((lost & ~drop_tracked).sum())
    f4 = np.float32
    take.truth_arrays.update({
        "face_names": np.array(ARKIT_NAMES),
        "face_time_s": t,
        "face_timecode": tc,
        "face_clean": clean.astype(f4),
        "face_tracked": tracked.astype(f4),
        "face_clean_angles": ang_c.astype(f4),
        "face_tracked_angles": ang_t.astype(f4),
        "face_clean_dropped": drop_clean,
        "face_tracked_dropped": drop_tracked,
        "face_spikes": spikes,
        "face_gain": bias["gain"],
        "face_offset": bias["offset"],
    })
    take.truth_scalars.update({
        "rate_hz": rate, "timecode_fps": TIMECODE_FPS, "n_frames": n, "clock_drift": drift,
        "head_tracking": head, "clean": clean_rel, "tracked": tracked_rel,
        "dropped_clean": int(drop_clean.sum()), "dropped_tracked": int(drop_tracked.sum()),
        "first_timecode": str(tc[0]),
    })
    rate_out: float | int = int(rate) if rate.is_integer() else rate
    return {"tracked": tracked_rel, "clean": clean_rel, "rate_hz": rate_out, "timecode_fps": TIMECODE_FPS}
