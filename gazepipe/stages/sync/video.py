"""sync stage, video side: the clapper's claps in the head-camera video, from a few seconds of frames around each
expected clap only (the video is never decoded whole).

The video comes in as its probe's frame timestamps and a ``read_window(start, stop)`` callable returning
``(timestamps_s, frames)`` for the frames [start, stop) (``gazepipe.io.video.FrameReader`` for the take,
typically with a small ``scale``). The clap is the end of the closing burst of per-frame motion energy
(:func:`video_claps`), refined from the moving arm's displacement.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from gazepipe.stages.sync.clap import _MAD, _robust_sigma, _score

__all__ = ["ReadWindow", "VideoClap", "match_clap", "motion_energy", "video_claps"]

#: ``read_window(start, stop) -> (timestamps_s (M,), frames (M, H, W) uint8)`` for the frames [start, stop)
ReadWindow = Callable[[int, int], tuple[np.ndarray, np.ndarray]]


@dataclass
class VideoClap:
    """A clap found in the video.

    Attributes
    ----------
    time_s : end of the closing burst, seconds on the video clock (the frames' own timestamps).
    frame : the same instant as a fractional frame index (interpolated between frame timestamps).
    confidence : 0..1 (see :func:`video_claps`).
    peak, still : motion energy (mean absolute grey-level difference) at the burst's peak and when still.
    window : the frames [start, stop) that were decoded to find it.
    match : how well the motion energy around it follows the mocap clapper's speed (normalised correlation,
        −1..1; :func:`match_clap`), or None when it was found without the mocap's help.
    match_time_s : the contact as the match alone places it (video clock), or None.
    timed_by : what set ``time_s``: ``"displacement"`` (the arm's displacement from its shut position followed
        into contact, :func:`_refine_by_displacement`), ``"match"`` (the motion energy matched to the mocap
        clapper's speed, :func:`match_clap`) or ``"burst"`` (the closing burst's end alone).
    timing_s : how well ``time_s`` is known, s (one standard deviation, :func:`video_timing_s`).
    burst_time_s : the closing burst's end (video clock), s, whatever timed ``time_s``.
    """

    time_s: float
    frame: float
    confidence: float
    peak: float
    still: float
    window: tuple[int, int]
    match: float | None = None
    match_time_s: float | None = None
    timed_by: str = "displacement"
    timing_s: float = 0.0
    burst_time_s: float | None = None


#: how well a video clap is timed, in video frames (one standard deviation), by what timed it: the arm's
#: displacement followed into contact (a quadratic through its last moving frames: the exposure's blur and the
#: displacement's own shape leave about a tenth of a frame); the motion energy matched to the mocap clapper's
#: speed (the peak of a correlation sampled every quarter frame, of an energy that saturates when the arm moves
#: more than its width between frames: about a quarter frame); the closing burst's end alone (anywhere within a
#: frame either side of it: 1/√3). ``bench/bench_claps_truth.py`` checks that they cover the errors.
TIMING_FRAMES = {"displacement": 0.1, "match": 0.25, "burst": 1.0 / np.sqrt(3.0)}
#: a frame exposed across the contact shows the arm still moving, so the fit through it comes out late, by up to
#: an eighth of a frame for an exposure of a whole frame: when the contact lies within half a frame after the last
#: frame that moves (where any exposure up to a frame may take it in), the contact is moved this much earlier (half
#: that range; the displacement's timing, :data:`TIMING_FRAMES`, covers the rest)
STRADDLE_FRAMES = 0.0625


#: the arm's displacement times a clap when it lies within a frame of the closing burst's end (which comes out late,
#: by up to half a frame and more under noise) or agrees with the motion match within this many standard
#: deviations of their timings together
AGREE_SIGMAS = 2.0


def video_timing_s(timed_by: str, frame_s: float) -> float:
    """How well a video clap timed by ``timed_by`` is known (one standard deviation, s), with frames ``frame_s``
    apart (:data:`TIMING_FRAMES`)."""
    return TIMING_FRAMES[timed_by] * frame_s


def motion_energy(read_window: ReadWindow, start: int, stop: int, *, roi: tuple[int, int, int, int] | None = None,
                  chunk: int = 64) -> tuple[np.ndarray, int]:
    """Motion energy between consecutive frames of [start, stop), decoded in chunks of ``chunk`` frames.

    Returns
    -------
    energy : (n − 1,) mean absolute grey-level difference between frames i − 1 and i (sample i − 1 belongs
        between those two frames' timestamps), optionally inside ``roi = (y0, y1, x0, x1)`` pixels.
    n : the number of frames actually returned (fewer than stop − start at the end of the video).
    """
    out: list[np.ndarray] = []
    prev: np.ndarray | None = None
    n = 0
    for c0 in range(start, stop, chunk):
        _, frames = read_window(c0, min(c0 + chunk, stop))
        frames = np.asarray(frames)
        if roi is not None:
            y0, y1, x0, x1 = roi
            frames = frames[:, y0:y1, x0:x1]
        n += frames.shape[0]
        if prev is not None:
            frames = np.concatenate([prev[None], frames])
        if frames.shape[0] > 1:
            out.append(_mean_abs_steps(frames))
        if frames.shape[0]:
            prev = frames[-1]
        if n < min(c0 + chunk, stop) - start:
            break  # end of the video
    return (np.concatenate(out) if out else np.zeros(0)), n


def _mean_abs_steps(frames: np.ndarray) -> np.ndarray:
    """(n − 1,) mean absolute difference of every pixel value (colour: every channel) between consecutive
    ``frames`` (n, ...): the larger minus the smaller in the frames' own unsigned type (no wider copy of the
    stack), summed exactly in integers, then divided by the count (the value numpy's float64 mean gives)."""
    a, b = frames[:-1], frames[1:]
    if np.issubdtype(frames.dtype, np.unsignedinteger):
        step = np.maximum(a, b) - np.minimum(a, b)
    else:
        step = np.abs(b.astype(np.int64) - a)
    step = step.reshape(step.shape[0], -1)
    return step.sum(axis=1, dtype=np.int64) / step.shape[1]


def _falling_edge(fts: np.ndarray, tm: np.ndarray, e: np.ndarray, p: int, post_n: int, exclude_s: float,
                  z_lo: float, z_hi: float, min_distinct: float) -> tuple[float, float, float, float] | None:
    """(time, confidence, peak, still) of the end of the burst peaking at sample p, or None.

    ``fts`` are the frames' timestamps, ``e[j]`` the energy between frames j and j + 1, at ``tm[j]`` (the
    midpoint). See :func:`video_claps` for the definition of the end.
    """
    peak = float(e[p])
    post = e[p + 1: p + 1 + post_n]
    if post.size < max(3, post_n // 2):
        return None  # the burst is too close to the end of what was decoded
    still = float(np.median(post))
    if not peak > still:
        return None
    half = still + 0.5 * (peak - still)
    below = np.flatnonzero(e[p + 1:] < half)
    if below.size == 0:
        return None
    k = p + 1 + int(below[0])
    t = tm[k - 1] + (tm[k] - tm[k - 1]) * (e[k - 1] - half) / (e[k - 1] - e[k])
    j0 = k - 2  # the last sample wholly before the stop (k − 1 may be partial when it is above half)
    if j0 >= 1 and j0 + 4 <= e.size:
        slope = (e[j0] - e[j0 - 1]) / (tm[j0] - tm[j0 - 1])  # energy per sample, per second
        level = e[j0] - still + slope * (fts[j0 + 1] - tm[j0])  # extrapolated to the end of sample j0
        dt = fts[j0 + 2] - fts[j0 + 1]
        mass = float(np.sum(e[j0 + 1: j0 + 4] - still))  # in samples' worth of energy
        if level > 0 and mass > 0:
            # level·τ + slope·τ²/2 = mass·dt, τ the motion after the end of sample j0
            a2, a1, c = 0.5 * slope, level, mass * dt
            disc = a1 * a1 + 4.0 * a2 * c
            tau = c / a1 if abs(a2) * c < 1e-9 * a1 * a1 else (-a1 + np.sqrt(max(disc, 0.0))) / (2.0 * a2)
            if 0.0 <= tau <= 2.0 * dt and disc >= 0:
                t = fts[j0 + 1] + tau
    noise = _MAD * float(np.median(np.abs(post - still)))
    z = (peak - still) / max(noise, 1e-9 * max(peak, 1.0))
    far = np.abs(tm - tm[p]) > exclude_s
    rival = float(e[far].max()) if np.any(far) else still
    distinct = (peak - max(rival, still)) / (peak - still)
    conf = _score(z, z_lo, z_hi) * float(np.clip(distinct / min_distinct, 0.0, 1.0))
    return float(t), conf, peak, still


def _displacement(frames: np.ndarray, shut: np.ndarray, thr: float) -> np.ndarray:
    """(M,) how far, in pixels up to a common scale, the moving arm in each frame is from its shut position.

    Where a frame differs from the shut image by more than ``thr``, the brighter and the darker parts are
    where the arm is and where it will be (or the reverse). The distance between their centroids is the
    displacement while they are apart and the arm's width once they overlap, when instead their mass shrinks
    in proportion to the displacement: the product of the two, normalised by the largest mass, follows the
    displacement in both cases (frame differences alone saturate once the arm moves more than its width).
    """
    d = frames.astype(np.float32) - shut[None]
    pos = np.where(d > thr, d, np.float32(0))
    neg = np.where(d < -thr, -d, np.float32(0))
    yy, xx = np.mgrid[0:shut.shape[0], 0:shut.shape[1]].astype(np.float32)

    def centroid(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = w.sum(axis=(1, 2), dtype=np.float64)
        safe = np.where(m > 0, m, 1.0)
        c = np.stack([(w * yy).sum(axis=(1, 2), dtype=np.float64) / safe,
                      (w * xx).sum(axis=(1, 2), dtype=np.float64) / safe], axis=1)
        return m, c

    mp, cp = centroid(pos)
    mn, cn = centroid(neg)
    mass = np.minimum(mp, mn)
    if not mass.max() > 0:
        return np.zeros(len(frames))
    return np.linalg.norm(cp - cn, axis=1) * (mass / mass.max())


#: a displacement under this share of the approach's largest is "nearly shut" (about the last tenth of the stroke)
_NEARLY_SHUT = 0.1


def _refine_by_displacement(ts: np.ndarray, read_window: ReadWindow, t_edge: float,
                            roi: tuple[int, int, int, int] | None, n_before: int = 6,
                            n_shut: int = 10) -> tuple[float, float] | None:
    """The instant the arm's displacement from its shut position reaches zero, near ``t_edge``, and how well it
    is known (one standard deviation, frames: :data:`TIMING_FRAMES`; when the last frame that moves may have been
    exposed across the contact, moved :data:`STRADDLE_FRAMES` earlier), or None.

    Decodes the ``n_before`` frames before the edge and ``n_shut`` still frames after it (their median is the
    shut image), follows the displacement down from its largest value to the last frame where it still falls
    (a rebound after contact rises again), fits that frame and the two before it (a quadratic) and solves it
    for zero between that frame and the next; the fractional frame becomes a time by interpolating the
    two frames' timestamps. Pixels that move in the still frames (something moving beside the clapper) are left
    out.
    """
    k_e = int(np.searchsorted(ts, t_edge, side="right")) - 1  # the frame at or before the edge
    a, b = k_e - n_before, k_e + 3 + n_shut
    if a < 0 or b > ts.size:
        return None
    _, fr = read_window(a, b)
    fr = np.asarray(fr)
    if len(fr) != b - a:
        return None
    if roi is not None:
        y0, y1, x0, x1 = roi
        fr = fr[:, y0:y1, x0:x1]
    if fr.ndim == 4:
        fr = fr.mean(axis=3)
    still = fr[-n_shut:].astype(np.float32)
    shut = np.median(still, axis=0)
    sigma = _robust_sigma((still - shut[None]).ravel())
    # only pixels that stay still once the clapper is shut can show how far its arm is from shut (a hand moving
    # beside the clapper does not stay still)
    moves = np.abs(still - shut[None]).max(axis=0) > 6.0 * max(sigma, 0.5)
    approach = fr[: n_before + 3].astype(np.float32)
    approach[:, moves] = shut[moves]
    s = _displacement(approach, shut, max(3.0, 4.0 * sigma))
    moving = np.flatnonzero(s > 0.02 * s.max())
    if moving.size == 0:
        return None
    # the approach: from the largest displacement down to where it stops falling (a stick that bounces open
    # after contact moves again, and those frames are not the approach). It starts at the last frame still on
    # the open plateau (within a tenth of the largest displacement): a partly hidden arm's plateau wobbles by a
    # few hundredths, and a walk from its first frame would stop on the wobble, losing the refinement
    head = s[: n_before + 1]
    k = int(np.flatnonzero(head >= 0.9 * head.max())[-1])
    while k + 1 < s.size and s[k + 1] < s[k] and s[k + 1] > 0.02 * s.max():
        k += 1
    if k < 2 or not (s[k - 2] > s[k - 1] > s[k]):
        return None  # not a clean approach to the shut position
    # the arms close accelerating: a fit that decelerates into a last frame already (nearly) shut says that frame
    # is past the contact (a stick bouncing open after it), so the three frames before it are fitted instead and
    # the contact sought up to two frames on, when they do accelerate
    span, last_moving = 1.0, k
    if (s[k] < _NEARLY_SHUT * s.max() and k >= 3 and s[k - 3] > s[k - 2]
            and s[k] - 2.0 * s[k - 1] + s[k - 2] > 0 >= s[k - 1] - 2.0 * s[k - 2] + s[k - 3]):
        k, span = k - 1, 2.0
    y = s[k - 2: k + 1]
    r = np.roots(np.polyfit([-2.0, -1.0, 0.0], y, 2))
    r = r[np.abs(r.imag) < 1e-9].real
    r = r[(r >= 0.0) & (r <= span + 0.5)]
    root = float(r.min()) if r.size else float(y[2] / (y[1] - y[2]))
    root = min(max(root, 0.0), span)
    j = a + k
    # within half a frame after the last frame that moves, the contact may fall inside that frame's exposure
    straddle = STRADDLE_FRAMES if k + root - last_moving < 0.5 else 0.0
    return float(np.interp(j + root - straddle, np.arange(ts.size, dtype=float), ts)), TIMING_FRAMES["displacement"]


class _Kept:
    """A ``read_window`` that keeps the frames it decodes, one contiguous run of at most ``budget`` bytes, so that
    frames asked for again (the refinement looks back at frames of the window just searched) come from memory
    instead of a second decode behind a backward seek. Past the budget it keeps nothing more."""

    def __init__(self, read_window: ReadWindow, budget: int = 64 << 20) -> None:
        self.read_window, self.budget = read_window, budget
        self.chunks: list[tuple[int, np.ndarray, np.ndarray]] = []  # (first frame, timestamps, frames)
        self.nbytes = 0

    def __call__(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        kept = self._slice(start, stop)
        if kept is not None:
            return kept
        t, fr = self.read_window(start, stop)
        fr = np.asarray(fr)
        end = self.chunks[-1][0] + len(self.chunks[-1][2]) if self.chunks else None
        if end != start:
            self.chunks, self.nbytes = [], 0
        if self.nbytes + fr.nbytes <= self.budget:
            self.chunks.append((start, np.asarray(t), fr))
            self.nbytes += fr.nbytes
        else:
            self.budget = -1  # over budget: keep nothing from now on
            self.chunks, self.nbytes = [], 0
        return t, fr

    def _slice(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray] | None:
        if not self.chunks or start < self.chunks[0][0] or stop > self.chunks[-1][0] + len(self.chunks[-1][2]):
            return None
        parts = [(t[max(start - c0, 0): stop - c0], fr[max(start - c0, 0): stop - c0])
                 for c0, t, fr in self.chunks if c0 < stop and c0 + len(fr) > start]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _clap_in(ts: np.ndarray, read_window: ReadWindow, t0: float, t1: float, *, post_s: float, exclude_s: float,
             roi: tuple[int, int, int, int] | None, chunk: int, z_lo: float, z_hi: float,
             min_distinct: float, refine: bool, anchor: float | None = None) -> VideoClap | None:
    """The strongest closing burst among the frames with timestamps in [t0, t1 + post_s]; refined by the arm's
    displacement when that lies within a frame of the burst's end or, given an ``anchor`` (the contact as the
    motion match places it), within :data:`AGREE_SIGMAS` of their timings of it."""
    i0 = int(np.searchsorted(ts, t0, side="left"))
    i1 = int(np.searchsorted(ts, t1 + post_s, side="right"))
    i0, i1 = max(i0 - 1, 0), min(i1, ts.size)
    if i1 - i0 < 4:
        return None
    read_window = _Kept(read_window)
    e, n = motion_energy(read_window, i0, i1, roi=roi, chunk=chunk)
    fts = ts[i0: i0 + n]
    tm = 0.5 * (fts[:-1] + fts[1:])  # an energy sample sits between its two frames
    dt = float(np.median(np.diff(fts))) if fts.size > 1 else 1.0
    # the peak must lie inside [t0, t1]; the post_s after t1 is only there to see the burst end
    inside = np.flatnonzero((tm >= t0) & (tm <= t1))
    if inside.size == 0:
        return None
    p = int(inside[np.argmax(e[inside])])
    r = _falling_edge(fts, tm, e, p, max(3, round(post_s / dt)), exclude_s, z_lo, z_hi, min_distinct)
    if r is None:
        return None
    t, conf, peak, still = r
    refined = _refine_by_displacement(ts, read_window, t, roi) if refine else None
    t_burst, timed_by, timing = t, "burst", video_timing_s("burst", dt)
    if refined is not None:
        t_ref, sd_ref = refined[0], refined[1] * dt
        if abs(t_ref - t) <= dt or (anchor is not None and abs(t_ref - anchor) <= AGREE_SIGMAS * float(np.hypot(
                sd_ref, video_timing_s("match", dt)))):
            t, timed_by, timing = t_ref, "displacement", sd_ref
    frame = float(np.interp(t, ts, np.arange(ts.size, dtype=float)))
    return VideoClap(time_s=t, frame=frame, confidence=conf, peak=peak, still=still, window=(i0, i0 + n),
                     timed_by=timed_by, timing_s=timing, burst_time_s=t_burst)


def video_claps(probe_timestamps: np.ndarray, read_window: ReadWindow, approx_times: Sequence[float] | None,
                *, window_s: float = 1.5, search_s: float = 20.0, post_s: float = 0.3, exclude_s: float = 0.4,
                roi: tuple[int, int, int, int] | None = None, chunk: int = 64, z_lo: float = 5.0,
                z_hi: float = 30.0, min_distinct: float = 0.5, refine: bool = True) -> list[VideoClap | None]:
    """Claps in the video near the expected times, decoding only the frames around them.

    Parameters
    ----------
    probe_timestamps : (N,) every frame's own timestamp, seconds (video clock).
    read_window : returns ``(timestamps, frames)`` for the frames [start, stop) (see :data:`ReadWindow`).
    approx_times : expected clap times on the video clock; ``None`` searches the first ``search_s`` seconds
        (at most half the video) for one clap (and, only when none is found there, the last ``search_s``).
    window_s : half-width of the search window around each expected time.
    post_s : the still level is the median motion energy over the ``post_s`` after the burst's peak; that many
        extra frames are decoded after each window.
    exclude_s : energy further than this from the peak counts as a rival burst.
    roi : optional (y0, y1, x0, x1) region of the frames (in the frames ``read_window`` returns).
    chunk : frames decoded per ``read_window`` call (bounds memory; pass a ``read_window`` that scales the
        frames down, e.g. ``read_frames(..., scale=0.25)``: the clapper fills much of the head camera's view).
    refine : refine the end of the burst from the arm's displacement (step 3 below).
    z_lo, z_hi, min_distinct : confidence = snr · distinct, where snr maps (peak − still) over the robust
        spread of the still energy linearly from ``z_lo`` → 0 to ``z_hi`` → 1, and distinct = min(1,
        (peak − rival) / (peak − still) / min_distinct), rival the highest energy further than ``exclude_s``
        from the peak (the opening of the clapper, a head movement).

    Returns
    -------
    One entry per expected time (a single one when searching): the clap, or ``None`` when no burst with a
    falling edge is found. An energy sample compares frames j and j + 1 and sits midway between their
    timestamps. The clap is the instant the closing motion stops:

    1. the falling edge is located where the energy, after the burst's peak, first drops below halfway
       between the peak and the still level (sample k); the crossing, interpolated linearly in time between
       samples k − 1 and k, is the fallback estimate;
    2. sample j0 = k − 2 is the last one wholly before the stop. The energy per sample is proportional to the
       distance moved between the two frames, so the energy above the still level in the next three samples,
       divided by the rate of energy just before the stop (samples j0 − 1 and j0, extrapolated linearly to
       the end of sample j0: constant acceleration), is how long the motion went on after frame j0 + 1. That
       interval is added to frame j0 + 1's timestamp (solving level·τ + slope·τ²/2 = energy·Δt).

    3. with ``refine`` (default), the frames just before the edge and a few still ones after it are decoded
       once more, and the arm's displacement from its shut position is measured in each frame (see
       :func:`_displacement`); the instant it reaches zero (a quadratic through the last three moving
       frames, solved between the last moving frame and the next, as for the mocap) replaces the estimate
       when it lies within a frame of it.

    Motion blur and the partial sample spread the edge but keep its energy, which is why step 2 is used
    rather than the halfway crossing (biased late by up to a quarter frame for an accelerating arm). Step 3
    matters when the arm moves more than its own width between frames: frame differences then saturate and
    steps 1–2 come out late by up to half a frame.
    """
    ts = np.asarray(probe_timestamps, dtype=np.float64)
    clap_in = functools.partial(_clap_in, post_s=post_s, exclude_s=exclude_s, roi=roi, chunk=chunk, z_lo=z_lo,
                                z_hi=z_hi, min_distinct=min_distinct, refine=refine)
    if approx_times is None:
        span = min(search_s, 0.5 * float(ts[-1] - ts[0]))
        head = clap_in(ts, read_window, float(ts[0]), float(ts[0]) + span)
        if head is not None and head.confidence > 0:
            return [head]
        return [clap_in(ts, read_window, float(ts[-1]) - span, float(ts[-1]))]
    return [clap_in(ts, read_window, t - window_s, t + window_s) for t in approx_times]



def _best_match(cand: np.ndarray, tm: np.ndarray, e: np.ndarray, tau: np.ndarray, speed: np.ndarray
                ) -> tuple[int, np.ndarray]:
    """Index of the candidate contact time whose energy window best correlates with ``speed``, and every
    candidate's normalised correlation."""
    # (C, P) energy around each candidate; outside the frames decoded (before the video starts) the still level,
    # which says nothing either way
    win = np.interp(cand[:, None] + tau[None, :], tm, e, left=np.nan, right=np.nan)
    win[np.isnan(win)] = float(np.median(e))
    win -= win.mean(axis=1, keepdims=True)
    ref = speed - speed.mean()
    den = np.sqrt((win * win).sum(axis=1) * float(ref @ ref))
    ncc = np.where(den > 0, win @ ref / np.where(den > 0, den, 1.0), -1.0)
    return int(np.argmax(ncc)), ncc


def match_clap(ts: np.ndarray, read_window: ReadWindow, t0: float, t1: float, profile_s: np.ndarray,
               profile_speed: np.ndarray, *, roi: tuple[int, int, int, int] | None = None, chunk: int = 64,
               post_s: float = 0.3, min_match: float = 0.3, good_match: float = 0.8, exclude_s: float = 0.4,
               z_lo: float = 5.0, z_hi: float = 30.0, min_distinct: float = 0.5, refine: bool = True
               ) -> VideoClap | None:
    """The clap in [t0, t1] (video clock) found by the shape of the clapper's motion seen by the mocap.

    The mocap knows how the clapper moved around the clap: ``profile_speed`` (P,), the speed of the distance
    between its markers (mm/s, any scale) at ``profile_s`` (P,) seconds from its contact, on a grid of the
    video's frame interval. The motion energy of the frames follows that speed (opening, hold, closing,
    stillness); the contact is where the energy, read at each candidate contact plus ``profile_s``, correlates
    best with it (normalised correlation, candidates every quarter frame). A burst of another shape (a hand
    coming into view, the clapper opening, a head movement) correlates poorly however strong it is. The
    instant is then refined by the arm's displacement followed into contact (:func:`_clap_in` over the frames
    from a frame before the matched contact's closing to a frame after it) when that agrees with the match
    (:data:`AGREE_SIGMAS`) or lies within a frame of the closing burst's end; otherwise the match's instant stands
    (``timed_by``, ``timing_s``: the closing burst's end alone is known less well than the match).

    Confidence: the match mapped linearly from ``min_match`` (0) to ``good_match`` (1), times how far the
    closing's energy stands out of the window's noise (as in :func:`video_claps`, ``z_lo`` → 0, ``z_hi`` → 1),
    times the burst end's own confidence, or halved when the burst's end lies more than a frame from the match. ``exclude_s``, ``z_lo``, ``z_hi``, ``min_distinct``, ``refine``: the burst's end and
    confidence, as in :func:`video_claps`. Returns None when nothing matches at least ``min_match``.
    """
    tau = np.asarray(profile_s, dtype=np.float64)
    i0 = max(int(np.searchsorted(ts, t0 + tau[0], side="left")) - 1, 0)
    i1 = min(int(np.searchsorted(ts, t1 + tau[-1] + post_s, side="right")), ts.size)
    if i1 - i0 < 8:
        return None
    kept = _Kept(read_window)
    e, n = motion_energy(kept, i0, i1, roi=roi, chunk=chunk)
    fts = ts[i0: i0 + n]
    if e.size < 4:
        return None
    tm = 0.5 * (fts[:-1] + fts[1:])
    dt = float(np.median(np.diff(fts)))
    cand = np.arange(t0, t1 + 0.25 * dt, 0.25 * dt)
    j, ncc = _best_match(cand, tm, e, tau, np.asarray(profile_speed, dtype=np.float64))
    score = float(ncc[j])
    if not score >= min_match:
        return None
    t = float(cand[j])
    if 0 < j < cand.size - 1:                  # the correlation's peak between candidates
        y0, y1, y2 = ncc[j - 1], ncc[j], ncc[j + 1]
        den = y0 - 2.0 * y1 + y2
        if den < 0:
            t += 0.25 * dt * float(np.clip(0.5 * (y0 - y2) / den, -1.0, 1.0))
    closing = tau[np.argmax(np.asarray(profile_speed)[tau <= 0.0])] if np.any(tau <= 0.0) else -dt
    edge = _clap_in(ts, kept, t + min(closing, -dt) - dt, t + dt, post_s=post_s, exclude_s=exclude_s, roi=roi,
                    chunk=chunk, z_lo=z_lo, z_hi=z_hi, min_distinct=min_distinct, refine=refine, anchor=t)
    conf = float(np.clip((score - min_match) / (good_match - min_match), 0.0, 1.0))
    # the closing must stand out of the frames' noise, whatever the match
    still = float(np.median(e))
    noise = _MAD * float(np.median(np.abs(e - still)))
    near = (tm >= t + min(closing, -dt) - dt) & (tm <= t + dt)
    burst = float(e[near].max()) if near.any() else still
    conf *= _score((burst - still) / max(noise, 1e-9 * max(burst, 1.0)), z_lo, z_hi)
    t_match, timed_by, t_burst = t, "match", None
    timing = video_timing_s("match", dt)
    if edge is not None:
        t_burst = edge.burst_time_s
        if edge.timed_by == "displacement":    # it agrees with the match or the burst's end
            t, timing, timed_by = edge.time_s, edge.timing_s, edge.timed_by
    if edge is not None and t_burst is not None and abs(t_burst - t_match) <= dt:
        conf *= edge.confidence
    else:
        conf *= 0.5                            # the burst's end disagrees with the match
    frame = float(np.interp(t, ts, np.arange(ts.size, dtype=float)))
    return VideoClap(time_s=t, frame=frame, confidence=conf, peak=burst, still=still, window=(i0, i0 + n),
                     match=score, match_time_s=t_match, timed_by=timed_by, timing_s=timing, burst_time_s=t_burst)
