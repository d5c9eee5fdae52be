"""Rest periods and the crop (SPEC §3.2 step 5, Pejsa 5.2.2.1 steps 2–3).

The subject's mean marker speed per frame (mm/s, on Gaussian-smoothed positions), still runs below a threshold
merged and kept when long enough, the end of each long rest moved to where the noise-free speed crosses the
threshold, and the crop a take's kind keeps between its rests. Frames are rows of the uncropped take; ranges
are half-open.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from gazepipe.stages.clean.filters import gaussian_runs, true_runs
from gazepipe.stages.clean.spikes import _sorted_median

#: a marker's speed is not its cluster's (:func:`mean_speed`) above this many times their median plus this (mm/s):
#: a rigid cluster turning fast has its markers' speeds within a factor of two or three
OUTLIER_FACTOR = 3.0
OUTLIER_MM_S = 20.0

#: markers whose speeds are computed at once by :func:`marker_speeds`: the smoothed positions and velocities of
#: that many markers are held, not those of the whole take (about 100 bytes per marker sample otherwise)
_SPEED_MARKERS = 4


def mean_speed(xyz: np.ndarray, valid: np.ndarray, rate_hz: float, filter_hz: float | None,
               min_share: float = 0.0, markers: np.ndarray | Sequence[int] | None = None,
               clusters: Sequence[Sequence[int]] = (), speeds: np.ndarray | None = None) -> np.ndarray:
    """Per-frame mean over markers (``markers``, columns of ``xyz`` and ``valid``; default all) of the speed
    (mm/s) by central differences, (T,); NaN (unknown) where no marker, or fewer than ``min_share`` of them, has
    a speed. Positions are first smoothed by :func:`gaussian_runs` at ``filter_hz`` when it is given.

    ``clusters`` (column lists of markers that move rigidly together): on a frame where at least three of a
    cluster's markers have a speed, one faster than :data:`OUTLIER_FACTOR` × their median +
    :data:`OUTLIER_MM_S` is left out (it is not moving with its cluster: a leap of its name or position).

    ``speeds`` (T, K): the markers' own speeds (:func:`marker_speeds` of the same arguments), when known.
    """
    cols = np.arange(valid.shape[1]) if markers is None else np.asarray(markers, dtype=np.int64)
    speed = marker_speeds(xyz, valid, rate_hz, filter_hz, cols) if speeds is None else speeds.copy()
    where = {int(c): i for i, c in enumerate(cols)}
    for c in clusters:
        idx = [where[int(m)] for m in c if int(m) in where]
        if len(idx) < 3:
            continue
        sub = speed[:, idx]
        judged = np.isfinite(sub).sum(axis=1) >= 3
        if judged.any():
            med = _median_across(sub[judged])
            odd = sub[judged] > OUTLIER_FACTOR * med[:, None] + OUTLIER_MM_S
            part = sub[judged]
            part[odd] = np.nan
            sub[judged] = part
            speed[:, idx] = sub
    n = np.sum(np.isfinite(speed), axis=1)
    total = np.nansum(speed, axis=1)
    enough = (n > 0) & (n >= min_share * cols.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(enough, total / np.maximum(n, 1), np.nan)


def marker_speeds(xyz: np.ndarray, valid: np.ndarray, rate_hz: float, filter_hz: float | None, cols: np.ndarray,
                  reuse: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Each marker of ``cols`` (K,)'s own speed (T, K) mm/s for :func:`mean_speed` (:func:`_speeds`, a few
    markers at a time). ``reuse`` (``valid`` (T, M), speeds (T, K)) of an earlier call: a marker whose samples
    are the same there keeps its speed (a marker's speed depends on its own samples only)."""
    speed = np.full((valid.shape[0], cols.size), np.nan)
    todo = np.arange(cols.size)
    if reuse is not None:
        same = (valid[:, cols] == reuse[0][:, cols]).all(axis=0)
        speed[:, same] = reuse[1][:, same]
        todo = todo[~same]
    for lo in range(0, todo.size, _SPEED_MARKERS):
        at = todo[lo:lo + _SPEED_MARKERS]
        speed[:, at] = _speeds(xyz[:, cols[at]], valid[:, cols[at]], rate_hz, filter_hz)
    return speed


def _median_across(a: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=-1)`` (the same values) of a few markers per frame: every line sorted at once,
    without nanmedian's masked-array path for short lines."""
    return _sorted_median(a, 1)[0]


def _speeds(xyz: np.ndarray, valid: np.ndarray, rate_hz: float, filter_hz: float | None) -> np.ndarray:
    """Each marker's speed (T, M) mm/s for :func:`mean_speed`; NaN where it has none (nor on a missing sample:
    no difference is taken across it, so a sample left out breaks the marker's track)."""
    pos = xyz.copy() if filter_hz is None else gaussian_runs(xyz, valid, filter_hz, rate_hz)
    pos[~valid] = np.nan
    vel = np.full_like(pos, np.nan)
    if len(pos) >= 3:
        vel[1:-1] = (pos[2:] - pos[:-2]) * (rate_hz / 2.0)
    if len(pos) >= 2:  # one-sided at the ends
        vel[0] = (pos[1] - pos[0]) * rate_hz
        vel[-1] = (pos[-1] - pos[-2]) * rate_hz
    vel[~valid] = np.nan
    return np.linalg.norm(vel, axis=2)


#: frames each side of an unknown run whose positions are averaged, and the mean displacement (mm) across it
#: that counts as motion (well above the marker noise left after that average)
_SIDE_FRAMES = 3
_MOVED_MIN_MM = 3.0


def moved_across_unknown(speed: np.ndarray, xyz: np.ndarray, present: np.ndarray, rate_hz: float,
                         threshold: float, markers: np.ndarray | Sequence[int] | None = None) -> np.ndarray:
    """``speed`` (T,) mm/s with each run of unknown frames (NaN) that the subject provably moved across set to
    the speed it must at least have had: the mean over ``markers`` present (``present`` (T, M)) in the frames
    just before and just after the run of their displacement between them (the two largest left out when more
    than four: a label exchange or a ghost inside the run moves two markers, not the subject), over the run's
    duration. Set only
    where that is at least ``threshold`` (the run was not a rest; below it, the subject may have moved away and
    back, and the run stays unknown). A gaze shift hidden by an occlusion that covers most markers left the head
    36° from where it was, and the unknown frames joined the rests on both sides into one."""
    out = speed.copy()
    cols = np.arange(present.shape[1]) if markers is None else np.asarray(markers, dtype=np.int64)
    n, k = len(speed), _SIDE_FRAMES
    for a, b in true_runs(np.isnan(speed)):
        if a == 0 or b >= n:
            continue
        both = cols[present[a - 1, cols] & present[b, cols]]
        if both.size == 0:
            continue
        # each side's position averaged over up to k frames where present: the marker noise, not the motion
        with np.errstate(invalid="ignore"):
            before = np.nanmean(np.where(present[max(0, a - k):a, both, None], xyz[max(0, a - k):a, both], np.nan), axis=0)
            after = np.nanmean(np.where(present[b:b + k, both, None], xyz[b:b + k, both], np.nan), axis=0)
        # two markers that exchanged names (or a ghost) inside the run have not moved the subject: the two
        # largest displacements are left out when there are more than four
        dist = np.sort(np.linalg.norm(after - before, axis=1))
        moved = float((dist[:-2] if dist.size > 4 else dist).mean())
        bound = moved * rate_hz / (b - a + 1)
        if moved >= _MOVED_MIN_MM and bound >= threshold:
            out[a:b] = bound
    return out


#: a frame where fewer than this share of the subject's markers are present (measured or gap-filled) has no rest
#: speed (SPEC §3.2)
PRESENT_SHARE = 0.5
#: a marker's step from one frame to the next is a jump (two markers exchanging names, a ghost) when it departs
#: from the median step of its cluster by more than this (mm) plus :data:`JUMP_SPREAD` times the cluster's median
#: step length (a cluster turning fast: its markers' steps differ by up to twice their length)
JUMP_MM = 10.0
JUMP_SPREAD = 3.0
#: frames each side over which the cluster's step length is the running median
_JUMP_SIDE = 3


def position_jumps(xyz: np.ndarray, present: np.ndarray, clusters: Sequence[Sequence[int]]) -> np.ndarray:
    """(T, M) bool: samples whose step from the frame before departs from their cluster's median step (the
    component-wise median over the cluster's markers present in both frames, at least two) by more than
    :data:`JUMP_MM` + :data:`JUMP_SPREAD` × the cluster's step length (the median over its markers, then the
    running median over :data:`_JUMP_SIDE` frames each side: a leap of most of its markers lasts a frame). A rigid cluster's markers move
    together; a marker that leaps away from its mates has not moved: its name or its position changed (a label
    exchange, a ghost the spike filter left). With two markers present a leap of one marks both (the median
    is their mean): leaving a sample out of the speed costs nothing."""
    from gazepipe.stages.clean.kernels import cluster_jumps  # numba: imported where first needed

    out = np.zeros(present.shape, dtype=bool)
    if len(xyz) < 2:
        return out
    for c in clusters:
        cols = np.asarray(c, dtype=np.int64)
        if cols.size < 2:
            continue
        out[:, cols] |= cluster_jumps(xyz, present, cols, JUMP_MM, JUMP_SPREAD, _JUMP_SIDE)
    return out


def rest_speed(xyz: np.ndarray, present: np.ndarray, rate_hz: float, filter_hz: float | None, threshold: float,
               markers: np.ndarray | Sequence[int] | None = None,
               clusters: Sequence[Sequence[int]] = (),
               seen: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The subject's speed per frame (mm/s, (T,)) for finding its rests (SPEC §3.2): the mean speed of its
    markers ``present`` (T, M; measured or gap-filled) where at least :data:`PRESENT_SHARE` of them are, else
    unknown unless the subject provably moved across (:func:`moved_across_unknown`).

    A sample that leaps away from its rigid cluster (``clusters``: column lists; :func:`position_jumps`) is left
    out, so no speed is taken across the leap, and so is a marker far faster than its cluster on a frame
    (:func:`mean_speed`): two head markers exchanging names in a rest leapt 140 mm, and the smoothed speed's
    bump split the rest (a crop 79 frames short). The speed of the markers measured alone was tried too: a
    fill's speed can hide a gaze shift behind an occlusion, but the measured markers' runs end at every gap and
    their smoothed speed falls to nothing at each end (a motion's end behind an occlusion found 8 frames early
    at 120 Hz), and over takes with every hazard it put more crop bounds more than 3 frames off (16 of 40 and 9
    of 24 against 10 and 6).

    ``seen`` (T, M; default ``present``): the samples that tell where the marker is in their own frame (measured,
    or filled rigidly from its cluster's markers measured there). A frame where fewer than :data:`PRESENT_SHARE` of the
    subject's markers are seen is hidden too, though its speed (from fills through time) is kept: such a fill
    across an occlusion of most of the body moves smoothly whatever the subject did (a gaze shift hidden that
    way read as one rest from the start of the take to the end), but leaving those frames unknown was measured
    and put more crop bounds more than 3 frames off over takes with every hazard (12 of 40 and 8 of 24 against
    10 and 6; also when the subject's displacement across them was taken as motion: the motion's start or end
    may lie anywhere in them). So the crop keeps the best guess, and says where it may be off.

    Returns the speed and the frames (T,) whose speed the markers do not give (hidden: set by the motion across
    them, unknown, or from fills through time)."""
    present = present & ~position_jumps(xyz, present, clusters)
    cols = np.arange(present.shape[1]) if markers is None else np.asarray(markers, dtype=np.int64)
    own = marker_speeds(xyz, present, rate_hz, filter_hz, cols)
    speed = mean_speed(xyz, present, rate_hz, filter_hz, min_share=PRESENT_SHARE, markers=cols,
                       clusters=clusters, speeds=own)
    hidden = np.isnan(speed)
    if seen is not None:
        hidden |= _told_by_time(speed, xyz, present, seen, rate_hz, filter_hz, threshold, cols, clusters,
                                (present, own))
    return moved_across_unknown(speed, xyz, present, rate_hz, threshold, markers), hidden


def _told_by_time(speed: np.ndarray, xyz: np.ndarray, present: np.ndarray, seen: np.ndarray, rate_hz: float,
                  filter_hz: float | None, threshold: float, markers: np.ndarray | Sequence[int] | None,
                  clusters: Sequence[Sequence[int]], known: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> np.ndarray:
    """(T,) bool: frames whose rest or motion the fills through time decide (:func:`rest_speed`'s ``seen``):
    fewer than :data:`PRESENT_SHARE` of the markers present are seen, or the frame moves (``speed`` at or
    above ``threshold``) only with the fills' speed (the seen markers' mean speed stays below it: a PCHIP fill
    across an occlusion of the head ramps from the occlusion's start, and the motion read from it began 8
    frames early). ``known``: ``present`` and its markers' own speeds (:func:`marker_speeds`), reused for the
    markers every sample of which is seen."""
    cols = np.arange(present.shape[1]) if markers is None else np.asarray(markers, dtype=np.int64)
    if cols.size == 0:
        return np.zeros(len(speed), dtype=bool)
    n_present = present[:, cols].sum(axis=1)
    few = (seen[:, cols] & present[:, cols]).sum(axis=1) < PRESENT_SHARE * np.maximum(n_present, 1)
    both = seen & present
    part = mean_speed(xyz, both, rate_hz, filter_hz, markers=cols, clusters=clusters,
                      speeds=marker_speeds(xyz, both, rate_hz, filter_hz, cols, reuse=known))
    moves = np.nan_to_num(speed, nan=-np.inf) >= threshold
    return few | (moves & (np.nan_to_num(part) < threshold))


def hidden_at(hidden: np.ndarray, bound: int) -> int:
    """How many frames of ``hidden`` (T,) bool lie in the run that touches the crop bound ``bound`` (the frame
    before it or the frame at it): the motion's start or end may lie anywhere in them (0: the bound is seen)."""
    return sum(b - a for a, b in true_runs(hidden) if a <= bound <= b)


def rest_periods(speed: np.ndarray, rate_hz: float, threshold: float, merge_s: float,
                 min_s: float) -> list[tuple[int, int]]:
    """Rest periods (start, stop), half-open rows, from a per-frame speed (Pejsa 5.2.2.1 steps 2–3).

    Still = speed below ``threshold``. A frame of unknown speed (NaN: too few markers there) is neither still nor
    moving: a run of them between two still frames does not split the rest (it joins it), elsewhere it is not
    still. Still runs separated by fewer than ``merge_s · rate`` frames merge; merged rests shorter than
    ``min_s · rate`` frames are dropped.
    """
    still = np.nan_to_num(speed, nan=np.inf) < threshold
    unknown = np.isnan(speed)
    for a, b in true_runs(unknown):
        if a > 0 and b < len(speed) and still[a - 1] and still[b]:
            still[a:b] = True
    runs = true_runs(still)
    merged: list[list[int]] = []
    for a, b in runs:
        if merged and (a - merged[-1][1]) < merge_s * rate_hz:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    return [(a, b) for a, b in merged if (b - a) >= min_s * rate_hz - 1e-9]


# Share of the subject's markers taken to be moving at a motion's onset, for how the noise floor f adds to the
# noise-free mean speed g: a moving marker's speed adds to its noise in quadrature, a still one's noise is
# added as it is, so the mean is √(g² + (q·f)²) + (1 − q)·f. A gaze shift starts with the head (a fifth to a
# third of the markers); measured on the sample session and on whole-segment moves, q = 0.3 leaves a median
# bias of 0 frames on both (q = 0: +1 frame on whole-segment moves; q = 1: −1 frame on the sample session).
ONSET_MOVING_SHARE = 0.3


_ONSET_TAUS = np.array([0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0])   # τ grid, in σ


_ONSET_STEP = 0.02                                                         # fine grid, in σ


def _onset_profiles(x_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-smoothed (σ = 1) onset shapes h_τ(d) = d² for 0 ≤ d < τ, then on with the slope 2τ they
    reached (τ² + 2τ(d − τ)); 0 before the onset. Returns the grid x (in σ) and the shapes (len(τ), len(x))."""
    x = np.arange(-6.0, x_max + 6.0, _ONSET_STEP)
    d = np.clip(x, 0.0, None)[None, :]
    tau = _ONSET_TAUS[:, None]
    h = np.where(d < tau, d * d, tau * tau + 2.0 * tau * (d - tau))
    u = np.arange(-4.0, 4.0 + _ONSET_STEP / 2, _ONSET_STEP)
    k = np.exp(-0.5 * u * u)
    k /= k.sum()
    return x, np.stack([np.convolve(row, k, mode="same") for row in h])


def refine_onset(speed: np.ndarray, b: int, sigma: float, threshold: float, lo: int, hi: int) -> int:
    """Unbiased first frame at or above ``threshold`` (the end of a rest) from a Gaussian-smoothed speed.

    The smoothed speed crosses the threshold early: the Gaussian (σ samples) spreads the motion's onset back.
    Model of the noise-free speed after the onset t0: A·((t − t0)/σ)² up to t0 + τσ, then on with the slope it
    reached (a smooth start, then a steady rise); smoothed by the same Gaussian and combined with the rest's
    noise floor f (the median speed of the rest before the window; see ``ONSET_MOVING_SHARE``), it is fitted to
    the smoothed speed from b − 3σ to the end of its rise (4·threshold or its first maximum) by exhaustive
    least squares over t0 (0.1-sample steps within 2σ of b), τ and A (log grids), which has no local minima to
    fall into. Returns the first frame where the fitted noise-free speed reaches the threshold, within
    [b − 1, b + 2σ]; ``b`` itself when the window is too short or not finite. ``lo``/``hi`` bound the frames
    the fit may use (the rest's start, the next rest's start).
    """
    n = len(speed)
    reach = int(np.ceil(3.0 * sigma))
    w0 = max(lo, b - reach)
    seg = speed[b:min(hi, b + 3 * reach)]
    stop = np.flatnonzero((seg >= 4.0 * threshold) | (np.diff(seg, append=np.inf) < 0))   # rise ends
    w1 = b + int(stop[0]) + 1 if len(stop) else b + len(seg)
    step = max(1, int(sigma // 3))          # the smoothed speed varies over σ: a few samples per σ suffice
    frames = np.arange(w0, w1, step)
    y = speed[frames]
    rest = speed[max(lo, w0 - 3 * reach):max(lo, b - reach)]
    if len(frames) < 5 or w1 > n or not np.isfinite(y).all():
        return b
    floor = float(np.median(rest)) if len(rest) >= 3 and np.isfinite(rest).all() else float(speed[w0])
    q = ONSET_MOVING_SHARE
    t0 = np.arange(b - 2.0 * sigma - 1.0, b + 2.0 * sigma, min(0.1, 0.05 * sigma))
    xd = (frames[None, :] - t0[:, None]) / sigma                             # (T0, F), in σ
    xs, prof = _onset_profiles(float(xd.max()))
    amp = threshold * np.geomspace(1e-3, 1e3, 161)                           # A, 4.4 % steps
    from gazepipe.stages.clean.kernels import onset_fit  # numba: imported where first needed

    shapes = np.stack([np.interp(xd, xs, p) for p in prof])                  # (τ, T0, F)
    best_k, best_a, best_t = onset_fit(shapes, amp, (q * floor) ** 2, (1.0 - q) * floor, y.astype(np.float64))
    a, tau = amp[best_a], _ONSET_TAUS[best_k]
    if a * tau * tau >= threshold:
        d_c = np.sqrt(threshold / a)
    else:
        d_c = tau + (threshold - a * tau * tau) / (2.0 * a * tau)
    t_c = t0[best_t] + d_c * sigma
    return int(np.clip(np.ceil(t_c - 1e-9), b - 1, b + int(np.ceil(2.0 * sigma))))


def refine_rests(rests: list[tuple[int, int]], speed: np.ndarray, rate_hz: float, filter_hz: float,
                 threshold: float) -> list[tuple[int, int]]:
    """Rest periods whose end (the onset of the motion after them) is moved to where the noise-free speed
    reaches the threshold (:func:`refine_onset`), for rests long enough to give the noise floor (at least
    9σ of the speed filter: 0.7 s at any rate; short pauses inside motion are left as found).

    Only ends: a motion decelerating into a rest often settles with a slow tail rather than to a still floor,
    and the smoothed speed's crossing there is already close (sample session: starts of the gaze shifts'
    second rests median 0, −1..+1 frames; of the gaze_follow takes' last rests 0..+2). The same fit in reversed
    time was measured and moved the gaze shifts' second-rest starts to a median of −1 (shortening the gaze_map
    duration) and the gaze_follow ones to −2..−1, so it is not applied."""
    sigma = np.sqrt(np.log(2.0)) / (2.0 * np.pi * filter_hz) * rate_hz
    reach = int(np.ceil(3.0 * sigma))
    n = len(speed)
    out = []
    for i, (a, b) in enumerate(rests):
        if b < n and b - a >= 3 * reach:
            nxt = rests[i + 1][0] if i + 1 < len(rests) else n
            b = max(a + 1, min(refine_onset(speed, b, sigma, threshold, a, nxt), nxt))
        out.append((a, b))
    return out


def crop_bounds(rests: list[tuple[int, int]], speed: np.ndarray, kind: str,
                tolerance: int = 0) -> tuple[tuple[int, int], list[str]]:
    """Crop (start, stop) for a take of ``kind`` and its QC warnings; raises ``ValueError`` with a short
    phrase when the rests the kind needs are missing.

    ``gaze_shift``: [end of the first rest, end of the second rest); the whole take, with a warning, when only
    one rest is found (the markers hidden through the other); none is an error. ``neutral``: everything. Other kinds:
    without the leading rest (one that starts at most ``tolerance`` frames after the first frame with a known
    speed) and the trailing rest (likewise before the last).
    """
    n = len(speed)
    warnings: list[str] = []
    if kind == "neutral":
        return (0, n), warnings
    if kind == "gaze_shift":
        if not rests:
            raise ValueError("found no rest period, a gaze_shift take needs two (the wait before the cue and the "
                             "fixation on the target)")
        if len(rests) < 2:
            # the markers may be hidden through one rest: the take stays (cleaned, whole) and gaze_map, which
            # needs both rests, leaves it out with that reason
            warnings.append(f"found {len(rests)} rest period(s), a gaze_shift take needs two (the wait before the "
                            "cue and the fixation on the target): kept whole, without a crop")
            return (0, n), warnings
        if len(rests) > 2:
            warnings.append(f"{len(rests)} rest periods; cropped between the first two")
        return (rests[0][1], rests[1][1]), warnings
    known = np.flatnonzero(np.isfinite(speed))
    if len(known) == 0:
        raise ValueError("no frame with a known marker speed")
    first, last = int(known[0]), int(known[-1])
    start, stop = 0, n
    if rests and rests[0][0] <= first + tolerance:
        start = rests[0][1]
    else:
        warnings.append("no leading rest period; kept from the first frame")
    if rests and rests[-1][1] > last - tolerance:
        stop = rests[-1][0]
    else:
        warnings.append("no trailing rest period; kept to the last frame")
    if stop <= start:
        raise ValueError("the whole take is at rest: no motion to keep")
    return (start, stop), warnings
