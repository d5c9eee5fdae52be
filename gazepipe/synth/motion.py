"""Kinematics of the synthetic takes: segment rotations relative to the neutral pose, target, clapper, gaze.

Rotations ``Q_k(t)`` are expressed in the *initial* character axes (X left, Y up, Z forward); the global
rotation of segment k in the lab is ``H · Q_k(t)`` with ``H`` the character-to-lab rotation of the stance.
Times are seconds from the take's first frame; positions are lab millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal
from scipy.spatial.transform import Rotation

from gazepipe.synth.skeleton import (
    EXTRA_MARKERS,
    HEAD_CENTRE_MARKER,
    JOINTS_MM,
    POSE_PROFILES,
    SEGMENTS,
    Placement,
)

FORWARD = np.array([0.0, 0.0, 1.0])
S = len(SEGMENTS)
HEAD = SEGMENTS.index("head")

#: seconds the target takes to reach each goal (Klein 5.1)
LEG_S = 3.33
#: the eyes' rotation limit in the head (cone half-angle, degrees)
EYE_LIMIT_DEG = 45.0
#: clapper geometry (mm): open and shut distance between CLAP1 and CLAP2
CLAP_OPEN_MM = 150.0
CLAP_SHUT_MM = 25.0


@dataclass
class TakeMotion:
    """Noise-free motion of one take before markers are placed.

    Attributes
    ----------
    time_s : (T,) seconds.
    local : S rotation stacks (each length T), parent-relative rotation of each segment, initial character axes.
    floor_lab : (3,) the subject's floor point in the lab, mm; (T, 3) when the whole body steps.
    fixation_lab : (T, 3) the point the eyes aim at, lab mm.
    target_lab : (T, 3) or None, the pole tip (gaze_follow) in lab mm.
    sign_lab : (3,) or None, the gaze-shift target sign in lab mm (gaze_shift).
    clapper_lab : (T, 2, 3) or None, CLAP1 and CLAP2 in lab mm.
    clap_times_s : clap contact instants (closing ends), seconds.
    clapper_busy : (T,) bool, frames where the clapper is in use (no occlusion allowed there).
    gaze_goal_char : (3,) or None, the requested final gaze direction (gaze_shift), initial character axes.
    gaze_dir_char : (T, 3) or None, the intended global gaze direction when it is not defined by
        ``fixation_lab`` alone (gaze_shift), initial character axes.
    design : the generating parameters (for the truth file).
    """

    time_s: np.ndarray
    local: list[Rotation]
    floor_lab: np.ndarray
    fixation_lab: np.ndarray
    target_lab: np.ndarray | None = None
    sign_lab: np.ndarray | None = None
    clapper_lab: np.ndarray | None = None
    clap_times_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    clapper_busy: np.ndarray | None = None
    gaze_goal_char: np.ndarray | None = None
    gaze_dir_char: np.ndarray | None = None
    design: dict = field(default_factory=dict)


def smoothstep(u: np.ndarray) -> np.ndarray:
    """Quintic 0→1 step with zero speed and acceleration at both ends; clipped outside [0, 1]."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (u * (6.0 * u - 15.0) + 10.0)


def delayed(x: np.ndarray, t: np.ndarray, d: float) -> np.ndarray:
    """``x`` delayed by ``d`` seconds (held at its first value before the start); works along axis 0."""
    if x.ndim == 1:
        return np.interp(t - d, t, x)
    out = np.empty_like(x)
    flat_in = x.reshape(len(t), -1)
    flat_out = out.reshape(len(t), -1)
    for j in range(flat_in.shape[1]):
        flat_out[:, j] = np.interp(t - d, t, flat_in[:, j])
    return out


def second_order(x: np.ndarray, rate_hz: float, f_hz: float, zeta: float) -> np.ndarray:
    """Causal second-order system ω²/(s² + 2ζωs + ω²) along axis 0, starting at rest at zero input."""
    w = 2.0 * np.pi * f_hz
    b, a = signal.bilinear([w * w], [1.0, 2.0 * zeta * w, w * w], fs=rate_hz)
    return signal.lfilter(b, a, x, axis=0)


def gaze_rotation(yaw: np.ndarray, pitch: np.ndarray) -> Rotation:
    """Ry(yaw)·Rx(−pitch) (radians), SPEC §2's gaze convention."""
    return Rotation.from_euler("YX", np.column_stack([np.atleast_1d(yaw), -np.atleast_1d(pitch)]))


def neutral_eye_char(drop_mm: float = 0.0) -> np.ndarray:
    """The eyes' centre (HEADC) in the neutral pose, character axes relative to the floor point, mm."""
    p = JOINTS_MM[HEAD] + np.array(EXTRA_MARKERS[HEAD_CENTRE_MARKER][1])
    return p - np.array([0.0, drop_mm, 0.0])


def _profile(pose: str) -> dict:
    return POSE_PROFILES.get(pose, POSE_PROFILES["standing"])


def floor_point(placement: Placement, pose: str) -> np.ndarray:
    """The floor point of the stance in the lab (the seated pose lowers the body), mm."""
    drop = float(_profile(pose)["floor_drop_mm"])
    return np.asarray(placement.floor_mm, dtype=float) - np.array([0.0, 0.0, drop])


def _clapper_distance(t: np.ndarray, contact: np.ndarray, closing_s: np.ndarray,
                      rebound: np.ndarray | None = None, soft: np.ndarray | None = None) -> np.ndarray:
    """Distance between the clapper markers: shut, opened over 0.3 s, held, closed fast (accelerating).
    ``rebound`` (claps, 2): per clap, how far (mm) and how long (s) the stick bounces open right after contact
    (a half sine; 0 mm: none). ``soft`` (claps, 2): per clap, the share of the full opening used and the
    softness s in [0, 1]: the closing follows (1 − s)·u² + s·smoothstep(u), so the arms meet at (1 − s) of
    a hard clap's speed for that depth and duration (1, 0: a hard clap)."""
    d = np.full_like(t, CLAP_SHUT_MM)
    if rebound is not None:
        for tc, (mm, dur) in zip(contact, np.asarray(rebound, dtype=np.float64), strict=True):
            if mm > 0 and dur > 0:
                u = (t - tc) / dur
                d = d + np.where((u > 0) & (u < 1), mm * np.sin(np.pi * np.clip(u, 0.0, 1.0)), 0.0)
    shape = np.tile([1.0, 0.0], (len(contact), 1)) if soft is None else np.asarray(soft, dtype=np.float64)
    for tc, tcl, (depth, s) in zip(contact, closing_s, shape, strict=True):
        t_open = tc - tcl - 0.6
        opening = smoothstep((t - t_open) / 0.3)
        u = np.clip((t - (tc - tcl)) / tcl, 0.0, 1.0)
        closing = (1.0 - s) * u * u + s * u * u * (3.0 - 2.0 * u)   # a hard clap accelerates into contact
        inside = (t >= t_open) & (t < tc)
        d = np.where(inside, CLAP_SHUT_MM + depth * (CLAP_OPEN_MM - CLAP_SHUT_MM) * opening * (1.0 - closing), d)
    return d


def _clapper(t: np.ndarray, eye_lab: np.ndarray, h: Rotation, contact: np.ndarray,
             closing_s: np.ndarray, rebound: np.ndarray | None = None, soft: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Clapper markers (T, 2, 3) held ~0.5 m in front of the face, and the frames where it is in use."""
    centre = eye_lab + h.apply([40.0, -150.0, 500.0])
    d = _clapper_distance(t, contact, closing_s, rebound, soft)
    c1 = np.broadcast_to(centre, (len(t), 3))
    c2 = centre + d[:, None] * h.apply([0.0, 1.0, 0.0])[None, :]
    busy = np.zeros(len(t), dtype=bool)
    for tc, tcl in zip(contact, closing_s, strict=True):
        busy |= (t >= tc - max(1.2, tcl + 0.9)) & (t <= tc + 0.6)
    return np.stack([c1, c2], axis=1), busy


def _goals(rng: np.random.Generator, n: int, floor_lab: np.ndarray, eye_lab: np.ndarray,
           start: np.ndarray) -> np.ndarray:
    """``n`` random goals in a 6 m x 6 m x 3 m box around the subject, each leg keeping 0.8 m off the head
    and 0.45 m off the body's axis."""
    body_a = floor_lab + np.array([0.0, 0.0, 200.0])
    goals: list[np.ndarray] = []
    prev = start
    while len(goals) < n:
        g = floor_lab + np.array([rng.uniform(-3000, 3000), rng.uniform(-3000, 3000), 0.0])
        g[2] = rng.uniform(200.0, 3200.0)
        s = np.linspace(0.0, 1.0, 64)[:, None]
        path = prev + s * (g - prev)
        if np.min(np.linalg.norm(path - eye_lab, axis=1)) < 800.0:
            continue
        horiz = np.linalg.norm((path - body_a)[:, :2], axis=1)
        if np.min(np.where(path[:, 2] < eye_lab[2] + 300.0, horiz, np.inf)) < 450.0:
            continue
        goals.append(g)
        prev = g
    return np.array(goals)


def _saccades(rng: np.random.Generator, t: np.ndarray, seen: np.ndarray, start_s: float,
              rate_hz: float, gain: float = 0.85) -> np.ndarray:
    """Fixation point (T, 3) relative to the start point: pursuit at ``gain`` of the seen target's motion,
    with catch-up saccades every 0.2–0.45 s that land on the seen target, each lasting ~50 ms."""
    iv = rng.uniform(0.2, 0.45, size=int(np.ceil((t[-1] - start_s) / 0.2)) + 2)
    jumps = start_s + np.concatenate([[0.0], np.cumsum(iv)])
    i = np.searchsorted(jumps, t, side="right") - 1
    anchor = np.column_stack([np.interp(jumps, t, seen[:, j]) for j in range(3)])[np.maximum(i, 0)]
    raw = np.where((i >= 0)[:, None], anchor + gain * (seen - anchor), seen)
    return second_order(raw, rate_hz, 12.0, 1.0)


def sway(rng: np.random.Generator, n: int, rate_hz: float, amp_deg: float, band_hz: float = 0.4) -> np.ndarray:
    """Smooth random small rotations (T, S, 3) rotation vectors in radians, RMS ``amp_deg`` per axis, band below
    ~``band_hz``."""
    noise = rng.standard_normal((n, S, 3))
    b, a = signal.butter(2, band_hz, fs=rate_hz)
    sm = signal.filtfilt(b, a, noise, axis=0)
    sm /= np.std(sm, axis=0, keepdims=True) + 1e-12
    return np.deg2rad(amp_deg) * sm


#: band (Hz) of the segments' own motion in gaze_follow takes (``SynthConfig.own_motion_deg``)
OWN_MOTION_HZ = 1.5


def follow_motion(rng: np.random.Generator, rate_hz: float, placement: Placement, pose: str,
                  duration_s: float, clap_rebound: np.ndarray | None = None,
                  weak_clap: tuple[int, float, float, float] | None = None,
                  own_motion: tuple[np.random.Generator, float] | None = None) -> TakeMotion:
    """A gaze_follow take (Klein 5.1): rest, the pole moving between random goals, settle, rest.

    ``clap_rebound``: see :func:`_clapper_distance`. ``weak_clap`` (clap index, closing seconds, share of the
    opening, softness): that clap is slow and soft (see :func:`_clapper_distance`'s ``soft``). ``own_motion``
    (its random stream, RMS degrees): each segment also turns on its own while the subject follows, smooth
    (band below :data:`OWN_MOTION_HZ`) and unlike its neighbours (twists and leans of the trunk, nods of the
    head); the rests stay still.

    The gaze follows the pole with a ~0.2 s reaction delay; the body's part of the gaze change goes through an
    underdamped second-order response (overshoot), with later onsets down the chain (Pejsa 5.1.2).
    """
    prof = _profile(pose)
    h = placement.h_lab
    floor = floor_point(placement, pose)
    eye_lab = floor + h.apply(neutral_eye_char())
    rest1 = float(rng.uniform(2.3, 2.8))
    rest2 = float(rng.uniform(2.3, 2.8))
    settle = 1.6
    n_legs = max(2, int(round((duration_s - rest1 - rest2 - settle) / LEG_S)))
    a0 = rest1
    a1 = rest1 + n_legs * LEG_S
    n = int(np.ceil((a1 + settle + rest2) * rate_hz))
    t = np.arange(n) / rate_hz

    p0 = eye_lab + h.apply([0.0, 0.0, 2000.0])
    goals = _goals(rng, n_legs - 1, floor, eye_lab, p0)
    knots = np.vstack([p0, goals, p0])
    kt = a0 + LEG_S * np.arange(n_legs + 1)
    target = np.column_stack([np.interp(t, kt, knots[:, j]) for j in range(3)])

    reaction = float(rng.uniform(0.18, 0.23))
    seen = delayed(target - p0, t, reaction)
    fix = p0 + _saccades(rng, t, seen, a0 + reaction, rate_hz)
    attention = p0 + second_order(seen, rate_hz, 3.5, 1.0)
    v = h.inv().apply(attention - eye_lab)
    # a target passing behind the subject flips the wanted yaw from about +180° to -180°: the body cannot turn
    # through its back, so it swings round through the front, over about a second (Klein 6: "the long path")
    yaw_u = np.unwrap(np.arctan2(v[:, 0], v[:, 2]))
    turns = np.round(yaw_u / (2.0 * np.pi))
    yaw = yaw_u - 2.0 * np.pi * second_order(turns, rate_hz, 0.6, 1.0)
    pitch = np.arctan2(v[:, 1], np.hypot(v[:, 0], v[:, 2]))

    ymax = np.deg2rad(float(prof["body_yaw_max"]))
    pmax = np.deg2rad(float(prof["body_pitch_max"]))
    body_yaw = ymax * np.tanh(0.85 * yaw / ymax)
    body_pitch = pmax * np.tanh(0.6 * pitch / pmax)
    head_extra = 0.05
    body_yaw = second_order(delayed(body_yaw, t, head_extra), rate_hz, 1.1, 0.5)
    body_pitch = second_order(delayed(body_pitch, t, head_extra), rate_hz, 1.3, 0.5)
    end_env = 1.0 - smoothstep((t - (a1 + 0.4)) / 0.9)
    body_yaw *= end_env
    body_pitch *= end_env

    yaw_share = np.asarray(prof["yaw_share"], dtype=float)
    pitch_share = np.array([0.0, 0.02, 0.02, 0.03, 0.03, 0.05, 0.10, 0.10, 0.13, 0.52])
    onset = np.array([0.20, 0.17, 0.15, 0.13, 0.11, 0.09, 0.06, 0.04, 0.02, 0.0])
    env = smoothstep((t - a0) / 0.6) * end_env
    sw = sway(rng, n, rate_hz, 0.6) * env[:, None, None]
    if own_motion is not None and own_motion[1] > 0:
        sw = sw + sway(own_motion[0], n, rate_hz, own_motion[1], OWN_MOTION_HZ) * env[:, None, None]
    local = []
    for k in range(S):
        yk = yaw_share[k] * delayed(body_yaw, t, onset[k])
        pk = pitch_share[k] * delayed(body_pitch, t, onset[k])
        local.append(gaze_rotation(yk, pk) * Rotation.from_rotvec(sw[:, k]))

    contact = np.array([rng.uniform(1.1, 1.4), a1 + settle + rng.uniform(0.6, 0.9)])
    closing = rng.uniform(0.06, 0.10, size=2)
    soft = None
    if weak_clap is not None:
        j, closing_s, depth, softness = weak_clap
        closing[j] = closing_s
        soft = np.tile([1.0, 0.0], (2, 1))
        soft[j] = (depth, softness)
    clap, busy = _clapper(t, eye_lab, h, contact, closing, clap_rebound, soft)
    design = {"rest1_s": rest1, "rest2_s": rest2, "active_s": [a0, a1], "n_legs": n_legs, "leg_s": LEG_S,
              "reaction_s": reaction, "clap_closing_s": closing.tolist(), "goals_lab": knots.tolist()}
    if clap_rebound is not None:
        design["clap_rebound"] = np.asarray(clap_rebound, dtype=np.float64).tolist()
    if soft is not None:
        design["clap_soft"] = soft.tolist()
    return TakeMotion(time_s=t, local=local, floor_lab=floor, fixation_lab=fix, target_lab=target,
                      clapper_lab=clap, clap_times_s=contact, clapper_busy=busy, design=design)


def shift_motion(rng: np.random.Generator, rate_hz: float, placement: Placement, pose: str,
                 yaw_deg: float, pitch_deg: float, step: tuple[float, float, np.ndarray] | None = None,
                 more_rest_s: float = 0.0) -> TakeMotion:
    """A gaze_shift take (Pejsa 5.2.1): rest ≥ 1 s, one gaze change with a cascade and an overshoot, rest ≥ 1 s.

    The eyes start first (saccade), then head, neck3 … neck1, chest, spine4 … spine1, pelvis, each after a
    known delay; every segment follows the same overshooting profile of duration ``D``. ``step`` = (start
    relative to the end of the gaze change, s; duration, s; displacement (3,) lab mm): the whole body also
    steps (its floor point moves, smoothly) as the change ends; the take grows by the step's length.
    ``more_rest_s``: the final rest lasts that much longer (the same random draws either way).
    """
    h = placement.h_lab
    floor = floor_point(placement, pose)
    eye_lab = floor + h.apply(neutral_eye_char())
    yaw = np.deg2rad(yaw_deg)
    pitch = np.deg2rad(pitch_deg)
    amp = float(np.hypot(yaw_deg, pitch_deg))

    body_yaw = np.sign(yaw) * (abs(yaw) - min(0.35 * abs(yaw), np.deg2rad(20.0)))
    body_pitch = 0.7 * pitch
    if abs(yaw_deg) <= 40.0:
        yaw_share = np.array([0.02, 0.03, 0.03, 0.03, 0.03, 0.06, 0.10, 0.10, 0.10, 0.50])
    else:       # a large turn brings the hips and the chest round (Pejsa 5.1.1: the spine matters above 40°)
        yaw_share = np.array([0.12, 0.03, 0.03, 0.03, 0.03, 0.10, 0.08, 0.08, 0.08, 0.42])
    pitch_share = np.array([0.0, 0.02, 0.02, 0.02, 0.02, 0.05, 0.10, 0.10, 0.10, 0.57])
    fin_yaw = yaw_share * body_yaw
    fin_pitch = pitch_share * body_pitch

    head_onset = float(rng.uniform(0.05, 0.1))
    cascade = np.array([0.42, 0.38, 0.34, 0.30, 0.26, 0.22, 0.15, 0.10, 0.05, 0.0])
    onset = head_onset + cascade
    dur = 0.5 + 0.006 * amp + float(rng.uniform(0.0, 0.1))
    beta = 0.08 + 0.0012 * amp + float(rng.uniform(0.0, 0.05))
    u_beta = float(rng.uniform(0.5, 0.6))
    moving = (np.abs(fin_yaw) + np.abs(fin_pitch)) > 0

    rest1 = float(rng.uniform(1.2, 1.6))
    t_end = rest1 + (onset[moving].max() if moving.any() else 0.0) + dur
    tail = rng.uniform(1.3, 1.6) + more_rest_s
    extra = 0.0 if step is None else max(0.0, step[0] + step[1])
    n = int(np.ceil((t_end + extra + tail) * rate_hz))
    t = np.arange(n) / rate_hz
    if step is not None:
        floor = floor + smoothstep((t - t_end - step[0]) / step[1])[:, None] * np.asarray(step[2])[None, :]

    local = []
    for k in range(S):
        u = (t - rest1 - onset[k]) / dur
        prof_k = np.where(u < u_beta, (1.0 + beta) * smoothstep(u / u_beta),
                          1.0 + beta - beta * smoothstep((u - u_beta) / (1.0 - u_beta)))
        local.append(gaze_rotation(fin_yaw[k] * prof_k, fin_pitch[k] * prof_k))

    goal = gaze_rotation(yaw, pitch).apply(FORWARD)[0]
    sacc = 0.025 + 0.0022 * amp
    s = smoothstep((t - rest1) / sacc)
    gaze = Rotation.from_rotvec(s[:, None] * Rotation.align_vectors(goal[None], FORWARD[None])[0].as_rotvec())
    gaze_dir = gaze.apply(FORWARD)
    sign = eye_lab + h.apply(3000.0 * goal)
    fix = eye_lab + h.apply(3000.0 * gaze_dir)
    step_design = {} if step is None else {"step": {"start_s": t_end + step[0], "duration_s": step[1],
                                                    "lab_mm": np.asarray(step[2]).tolist()}}
    return TakeMotion(time_s=t, local=local, floor_lab=floor, fixation_lab=fix, sign_lab=sign,
                      gaze_goal_char=goal, gaze_dir_char=gaze_dir,
                      design={**step_design, "rest1_s": rest1, "eye_onset_s": rest1, "onset_s": (rest1 + onset).tolist(),
                              "moving": moving.tolist(), "duration_s": dur, "beta": beta, "u_beta": u_beta,
                              "t_beta_s": rest1 + head_onset + u_beta * dur, "saccade_s": sacc,
                              "final_yaw_deg": np.rad2deg(fin_yaw).tolist(),
                              "final_pitch_deg": np.rad2deg(fin_pitch).tolist()})


def neutral_motion(rng: np.random.Generator, rate_hz: float, placement: Placement, duration_s: float) -> TakeMotion:
    """The neutral take: the subject stands still in the neutral pose, looking straight ahead."""
    h = placement.h_lab
    floor = floor_point(placement, "standing")
    n = int(np.ceil(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    eye_lab = floor + h.apply(neutral_eye_char())
    fix = np.broadcast_to(eye_lab + h.apply([0.0, 0.0, 3000.0]), (n, 3)).copy()
    ident = Rotation.identity(n)
    return TakeMotion(time_s=t, local=[ident] * S, floor_lab=floor, fixation_lab=fix, design={})
