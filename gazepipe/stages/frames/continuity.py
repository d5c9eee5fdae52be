"""Continuity of a rotation sequence (SPEC §3.3): a segment's rotation, or the character frame's heading, that
jumps far beyond what its measured angular velocity allows and comes back is a flip, and its frames are a gap.

A marker fit goes wrong for a few frames when one of its markers does (a ghost the spike filter missed, two
markers whose names were exchanged, a fill off where the fit depends on it): the rotation jumps away and back.
Nothing in one frame's fit shows it; the frames around it do. Pure functions on (N, 3, 3) rotation matrices,
NaN where unknown.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JumpRule:
    """When a step of a rotation sequence is a jump, and how long a flip may last.

    Attributes
    ----------
    factor : a step is a jump when it departs from the local angular velocity (the running median of the
        steps' rotation vectors around it) by more than this many times the typical departure there (the
        running median of the departures: the rotations' noise and their changes of speed).
    min_deg : and by at least this many degrees.
    window : half width (steps) of the running medians.
    max_frames : longest flip, frames from the jump away to the jump back.
    short_frames : a flip up to this long needs no more than its two jumps and its coming back; a longer one
        needs far jumps or the same offset at both ends (:func:`flips`).
    """

    factor: float
    min_deg: float
    window: int
    max_frames: int
    short_frames: int = 1


def _median_rows(x: np.ndarray, half: int) -> np.ndarray:
    """Running median along axis 0 of a finite (n,) or (n, m) array over ``2·half + 1`` rows (edges repeat the end
    rows; :func:`gazepipe.stages.frames.kernels.running_median`)."""
    from gazepipe.stages.frames.kernels import running_median

    x = np.asarray(x, dtype=np.float64)
    return running_median(np.ascontiguousarray(x.reshape(len(x), -1)), half).reshape(x.shape)


def step_departures(mats: np.ndarray, rule: JumpRule):
    """The steps between consecutive known rotations of ``mats`` (N, 3, 3), NaN where unknown.

    Returns the known frames ``idx`` (K,), their rotations (a :class:`~gazepipe.stages.frames.kernels.Rot` stack), and per step k (from ``idx[k]`` to
    ``idx[k + 1]``): how far (deg) it departs from the local angular velocity (over a step across unknown
    frames, the velocity times their number), the jump threshold there (deg) and the local speed (deg per
    frame)."""
    from gazepipe.stages.frames.kernels import Rot

    known = np.isfinite(mats).all(axis=(1, 2))
    idx = np.flatnonzero(known)
    rot = Rot.from_matrix(mats[idx]) if len(idx) else None
    if len(idx) < 3:
        empty = np.zeros(max(0, len(idx) - 1))
        return idx, rot, empty, empty, empty
    assert rot is not None
    dt = np.diff(idx).astype(np.float64)
    v = (rot[:-1].inv() * rot[1:]).as_rotvec() / dt[:, None]     # rad per frame, axes of the earlier frame
    vbar = _median_rows(v, rule.window)
    excess = np.degrees(np.linalg.norm(v - vbar, axis=1) * dt)
    thr = np.maximum(rule.min_deg, rule.factor * _median_rows(excess, rule.window))
    return idx, rot, excess, thr, np.degrees(np.linalg.norm(vbar, axis=1))


def _offsets_agree(rot, k: int, m: int, tol_deg: float) -> bool:
    """Whether the run of known rotations k + 1 … m sits off its neighbours k and m + 1 by the same rotation at
    both ends (in the segment's own axes, or in the character frame's): a fit gone wrong the same way over the
    run, not two unrelated jumps: their mismatch within ``tol_deg`` (deg) and within :data:`_SAME` of the smaller
    offset (two of the noise's steps past the threshold are as far from each other as from nothing)."""
    body = (rot[k].inv() * rot[k + 1]).inv() * (rot[m + 1].inv() * rot[m])
    lab = (rot[k + 1] * rot[k].inv()).inv() * (rot[m] * rot[m + 1].inv())
    offset = min(float(np.degrees((rot[k].inv() * rot[k + 1]).magnitude())),
                 float(np.degrees((rot[m].inv() * rot[m + 1]).magnitude())))
    mismatch = min(float(np.degrees(body.magnitude())), float(np.degrees(lab.magnitude())))
    return mismatch <= min(tol_deg, _SAME * offset)


def _one_pass(mats: np.ndarray, rule: JumpRule) -> np.ndarray:
    """The frames of one pass of :func:`flips` over ``mats``."""
    out = np.zeros(len(mats), dtype=bool)
    idx, rot, excess, thr, speed = step_departures(mats, rule)
    if len(excess) < 2:
        return out
    jumps = np.flatnonzero(excess > thr)
    done = -1
    for pos, k in enumerate(jumps.tolist()):
        if k <= done or idx[k + 1] - idx[k] != 1:       # a flip starts between consecutive frames
            continue
        for m in jumps[pos + 1:].tolist():
            span = int(idx[m + 1] - idx[k])
            if span > rule.max_frames + 1:
                break
            tol = max(thr[k], thr[m])
            angle = float(np.degrees((rot[k].inv() * rot[m + 1]).magnitude()))
            if angle > 1.5 * max(speed[k], speed[m]) * span + tol:
                continue
            if (span <= rule.short_frames + 1 or min(excess[k], excess[m]) >= _FAR * tol
                    or _offsets_agree(rot, k, m, tol + 1.5 * (speed[k] + speed[m]) * (idx[m + 1] - idx[m]))):
                out[idx[k + 1:m + 1]] = True
                done = m
                break
    return out


#: a flip longer than ``JumpRule.short_frames`` needs jumps at least this many times the threshold, or the same
#: offset at both ends: two of the noise's rare steps past the threshold, two seconds apart on a still segment,
#: looked like a flip between them
_FAR = 3.0
#: the largest mismatch of the offsets at a flip's two ends, as a share of the smaller (:func:`_offsets_agree`):
#: two jumps of 3.8° and 1.8° five degrees apart, on a still spine at 120 Hz, made 2 s of good rotations a gap
_SAME = 0.5
#: passes of :func:`flips` (a flip inside a flip, or two in a row, shows once the first is out)
_PASSES = 3


def flips(mats: np.ndarray, rule: JumpRule) -> np.ndarray:
    """(N,) bool: the known frames of ``mats`` (N, 3, 3; NaN where unknown) inside a flip.

    A flip starts with a jump between two consecutive frames (:func:`step_departures`: a step far beyond the
    local angular velocity) and ends with a jump back, within ``rule.max_frames``; the jump back may be a step
    across unknown frames. It comes back when the rotation after it is where the rotation before it would be
    at the measured speed (their angle at most 1.5 × the faster of the two local speeds × the frames between
    them, plus the larger jump threshold); a flip longer than ``rule.short_frames`` also needs both jumps
    :data:`_FAR` times the threshold, or the run between sitting off its two neighbours by the same rotation at
    both ends (:func:`_offsets_agree`: a fit gone wrong the same way, not two unrelated jumps). Each jump
    away is paired with the first such jump back; a jump with no jump back (the rotation stays where it jumped
    to) is left alone: nothing says which side is right. Up to :data:`_PASSES` passes, each over what the
    last left.
    """
    work = np.array(mats, dtype=np.float64, copy=True)
    out = np.zeros(len(mats), dtype=bool)
    for _ in range(_PASSES):
        found = _one_pass(work, rule)
        if not found.any():
            break
        out |= found
        work[found] = np.nan
    return out
