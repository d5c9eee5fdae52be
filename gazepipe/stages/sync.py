"""sync stage: clapper sync of the mocap clock and the head-camera clock, and resampling onto mocap frames.

Klein 5.1: a clapper carrying one marker on each arm is snapped shut in view of the head camera, typically
once near the start and once near the end of a take. The mocap clock is the master clock (SPEC §2):

    t_mocap = offset + ratio · t_video

- Mocap clap (:func:`mocap_claps`): the contact instant, when the closing of the clapper arms ends.
- Video clap (:func:`video_claps`): the end of the closing burst of per-frame motion energy, from a few seconds
  of frames around each expected clap only (the video is never decoded whole).
- Clock map (:func:`clock_map`): one clap pair gives the offset (ratio 1); two or more also give the ratio,
  which holds a camera's rate error (labelled 60 fps running at 59.94: ratio 1.001) or crystal drift.
- :func:`resample_to_mocap` puts video-clock signals on the mocap frames, never extrapolating.

Everything here is pure: the video comes in as its probe's frame timestamps and a ``read_window(start, stop)``
callable returning ``(timestamps_s, frames)`` for the frames [start, stop) (``gazepipe.io.video.read_frames``
bound to a path, typically with a small ``scale``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.errors import StageError

__all__ = ["Clap", "ClockMap", "ReadWindow", "SyncResult", "VideoClap", "clock_map", "mocap_claps",
           "motion_energy", "resample_to_mocap", "sync_take", "video_claps"]

#: ``read_window(start, stop) -> (timestamps_s (M,), frames (M, H, W) uint8)`` for the frames [start, stop)
ReadWindow = Callable[[int, int], tuple[np.ndarray, np.ndarray]]

_MAD = 1.4826  # MAD → standard deviation for Gaussian noise


def _robust_sigma(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan")
    return float(_MAD * np.median(np.abs(x - np.median(x))))


def _score(z: float, lo: float, hi: float) -> float:
    """Linear map of a signal-to-noise ratio onto 0..1: ``lo`` (just detectable) → 0, ``hi`` → 1."""
    if not np.isfinite(z):
        return 1.0 if z > 0 else 0.0
    return float(np.clip((z - lo) / (hi - lo), 0.0, 1.0))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open [start, stop) runs of True."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


# --------------------------------------------------------------------------------------------- mocap
@dataclass
class Clap:
    """A clap found in the mocap.

    Attributes
    ----------
    time_s : contact instant, seconds on the mocap clock (0 at the take's first frame).
    frame : the same instant as a fractional frame index (time_s · rate).
    confidence : 0..1, how clearly the closing stands out of the noise (see :func:`mocap_claps`).
    closing_speed_mm_s : fastest closing speed of the distance between the markers.
    open_mm, shut_mm : distance held before the closing, and the plateau after it.
    margin_mm : tolerance around ``shut_mm`` used to decide that the clapper is shut.
    """

    time_s: float
    frame: float
    confidence: float
    closing_speed_mm_s: float
    open_mm: float
    shut_mm: float
    margin_mm: float


def clapper_distance(clap_a_xyz: np.ndarray, clap_b_xyz: np.ndarray, valid_a: np.ndarray,
                     valid_b: np.ndarray) -> np.ndarray:
    """(T,) distance in mm between the two clapper markers, NaN where either is invalid."""
    d = np.linalg.norm(np.asarray(clap_a_xyz, float) - np.asarray(clap_b_xyz, float), axis=1)
    ok = np.asarray(valid_a, bool) & np.asarray(valid_b, bool) & np.isfinite(d)
    return np.where(ok, d, np.nan)


def _trajectory_root(d: np.ndarray, last: int, shut: float, n_fit: int) -> float | None:
    """Where the closing trajectory fitted on its ``n_fit`` frames up to ``last`` reaches ``shut``, in frames
    after ``last`` (a quadratic: constant acceleration; a line with two frames); None when it cannot say."""
    idx = np.arange(max(last - n_fit + 1, 0), last + 1)
    idx = idx[np.isfinite(d[idx])]
    if idx.size < 2 or idx[-1] != last:
        return None
    x = (idx - last).astype(float)
    y = d[idx] - shut
    root = float(-y[-1] / (y[-1] - y[-2])) if y[-1] != y[-2] else None
    if idx.size >= 3:
        r = np.roots(np.polyfit(x, y, 2))
        r = r[np.abs(r.imag) < 1e-9].real
        r = r[r >= -0.25]
        if r.size:
            root = float(r.min())
    return root


def _contact_crossing(d: np.ndarray, k0: int, shut: float, sigma_d: float, n_fit: int) -> float:
    """Fractional frame where the closing trajectory reaches ``shut``, near the first frame k0 within the margin.

    The arms stop abruptly at contact, so the distance has a kink there: interpolating linearly between the
    two frames around the crossing would put the contact up to a frame late. Instead the closing trajectory
    is fitted on its last ``n_fit`` frames before k0 and solved for ``shut``, within [k0 − 1, k0]. When that
    solution lies beyond k0 and frame k0 is still more than 2 σ_d above the shut value (closing, only within
    the margin), the trajectory is refitted up to k0 and solved within [k0, k0 + 1].
    """
    root = _trajectory_root(d, k0 - 1, shut, n_fit)
    if root is None:
        return float(k0)
    if root > 1.0 and d[k0] - shut > 2.0 * sigma_d and k0 + 1 < d.size:
        later = _trajectory_root(d, k0, shut, n_fit)
        if later is not None:
            return float(k0 + np.clip(later, 0.0, 1.0))
    return float(k0 - 1 + np.clip(root, 0.0, 1.0))


def mocap_claps(clap_a_xyz: np.ndarray, clap_b_xyz: np.ndarray, valid_a: np.ndarray, valid_b: np.ndarray,
                rate_hz: float, *, speed_k: float = 8.0, min_speed_mm_s: float = 100.0,
                min_depth_mm: float = 20.0, margin_mm: float = 1.0, margin_k: float = 5.0,
                plateau_s: float = 0.3, open_s: float = 0.3, fit_s: float = 0.08,
                min_separation_s: float = 1.0, lag_s: float = 0.02, z_lo: float = 8.0,
                z_hi: float = 40.0) -> list[Clap]:
    """Every clap in the clapper markers' trajectories.

    Parameters
    ----------
    clap_a_xyz, clap_b_xyz : (T, 3) marker positions, mm (NaN allowed where invalid).
    valid_a, valid_b : (T,) validity masks.
    rate_hz : mocap frame rate; frame i is at i / rate_hz seconds.
    speed_k, min_speed_mm_s : a closing event is a run of frames whose distance velocity is below
        −max(speed_k · σ_v, min_speed_mm_s), σ_v the robust (MAD) spread of the distance velocity over the
        whole take.
    lag_s : the distance velocity is a central difference over ± max(1, round(lag_s · rate)) frames, so that
        its noise, and the confidence, do not grow with the frame rate.
    min_depth_mm : the distance must drop at least this much (open − shut).
    margin_mm, margin_k : the clapper counts as shut within max(margin_mm, margin_k · σ_d) of the shut value,
        σ_d the robust spread of the distance on the plateau after the closing.
    plateau_s : the plateau after the fastest closing from which the shut value is taken (its median); the
        clapper must stay shut over most of it, or the event is not a clap.
    open_s : the open distance is the largest one in the ``open_s`` before the closing.
    fit_s : length of the closing trajectory fitted to refine the contact (at least three frames).
    min_separation_s : two claps closer than this are one (the faster closing is kept).
    z_lo, z_hi : confidence = the smaller of the closing speed over σ_v and the depth over σ_d, mapped
        linearly so that ``z_lo`` (the detection floor) gives 0 and ``z_hi`` or more gives 1.

    Returns
    -------
    The claps in time order. Each is the first time, after the fastest closing of its event, that the
    distance comes within the margin of its shut value, refined below one frame by solving the fitted
    closing trajectory for the shut value (see :func:`_contact_crossing`).
    """
    d = clapper_distance(clap_a_xyz, clap_b_xyz, valid_a, valid_b)
    T = d.size
    rate = float(rate_hz)
    lag = max(1, round(lag_s * rate))
    if T < 2 * lag + 5:
        return []
    v = np.full(T, np.nan)
    v[lag:-lag] = (d[2 * lag:] - d[:-2 * lag]) * (rate / (2 * lag))
    sigma_v = _robust_sigma(v)
    if not np.isfinite(sigma_v):
        return []
    thr = max(speed_k * sigma_v, min_speed_mm_s)
    closing = np.nan_to_num(v, nan=0.0) < -thr
    n_plat = max(5, round(plateau_s * rate))
    n_open = max(3, round(open_s * rate))
    n_fit = max(3, round(fit_s * rate))
    found: list[Clap] = []
    for s, e in _runs(closing):
        f = s + int(np.nanargmin(v[s:e]))
        plat = d[f + 1: f + 1 + n_plat]
        if np.count_nonzero(np.isfinite(plat)) < 0.8 * n_plat:
            continue  # not enough of the plateau seen (end of the take or occluded)
        shut = float(np.nanmedian(plat))
        sigma_d = max(_robust_sigma(plat), sigma_v * np.sqrt(2.0) * lag / rate)
        margin = max(margin_mm, margin_k * sigma_d)
        tail = plat[len(plat) // 2:]
        if np.count_nonzero(np.abs(tail - shut) <= margin) < 0.8 * tail.size:
            continue  # the clapper does not stay shut: not a clap
        before = d[max(s - n_open, 0): f + 1]
        if not np.any(np.isfinite(before)):
            continue
        opened = float(np.nanmax(before))
        if opened - shut < min_depth_mm:
            continue
        within = np.flatnonzero(d[s:] <= shut + margin)
        if within.size == 0:
            continue
        k0 = s + int(within[0])
        frame = _contact_crossing(d, k0, shut, sigma_d, n_fit)
        speed = float(-v[f])
        z = min(speed / max(sigma_v, 1e-12), (opened - shut) / max(sigma_d, 1e-12))
        clap = Clap(time_s=frame / rate, frame=frame, confidence=_score(z, z_lo, z_hi),
                    closing_speed_mm_s=speed, open_mm=opened, shut_mm=shut, margin_mm=margin)
        if found and clap.time_s - found[-1].time_s < min_separation_s:
            if clap.closing_speed_mm_s > found[-1].closing_speed_mm_s:
                found[-1] = clap
            continue
        found.append(clap)
    return found


# --------------------------------------------------------------------------------------------- video
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
    """

    time_s: float
    frame: float
    confidence: float
    peak: float
    still: float
    window: tuple[int, int]


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
        frames = frames.astype(np.int16)  # grey levels (colour: every channel counts) and their differences
        n += frames.shape[0]
        if prev is not None:
            frames = np.concatenate([prev[None], frames])
        if frames.shape[0] > 1:
            diff = np.abs(np.diff(frames, axis=0))
            out.append(diff.reshape(diff.shape[0], -1).mean(axis=1, dtype=np.float64))
        if frames.shape[0]:
            prev = frames[-1]
        if n < min(c0 + chunk, stop) - start:
            break  # end of the video
    return (np.concatenate(out) if out else np.zeros(0)), n


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


def _refine_by_displacement(ts: np.ndarray, read_window: ReadWindow, t_edge: float,
                            roi: tuple[int, int, int, int] | None, n_before: int = 6,
                            n_shut: int = 10) -> float | None:
    """The instant the arm's displacement from its shut position reaches zero, near ``t_edge``, or None.

    Decodes the ``n_before`` frames before the edge and ``n_shut`` still frames after it (their median is the
    shut image), fits the displacement of the last three moving frames (a quadratic) and solves it for zero
    between that last moving frame and the next; the fractional frame becomes a time by interpolating the
    two frames' timestamps.
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
    s = _displacement(fr[: n_before + 3], shut, max(3.0, 4.0 * sigma))
    moving = np.flatnonzero(s > 0.02 * s.max())
    if moving.size == 0:
        return None
    k = int(moving[-1])
    if k < 2 or not (s[k - 2] > s[k - 1] > s[k]):
        return None  # not a clean approach to the shut position
    y = s[k - 2: k + 1]
    r = np.roots(np.polyfit([-2.0, -1.0, 0.0], y, 2))
    r = r[np.abs(r.imag) < 1e-9].real
    r = r[(r >= 0.0) & (r <= 1.5)]
    root = float(r.min()) if r.size else float(y[2] / (y[1] - y[2]))
    root = min(max(root, 0.0), 1.0)
    j = a + k
    return float(ts[j] + root * (ts[j + 1] - ts[j]))


def _clap_in(ts: np.ndarray, read_window: ReadWindow, t0: float, t1: float, *, post_s: float, exclude_s: float,
             roi: tuple[int, int, int, int] | None, chunk: int, z_lo: float, z_hi: float,
             min_distinct: float, refine: bool) -> VideoClap | None:
    """The strongest closing burst among the frames with timestamps in [t0, t1 + post_s]."""
    i0 = int(np.searchsorted(ts, t0, side="left"))
    i1 = int(np.searchsorted(ts, t1 + post_s, side="right"))
    i0, i1 = max(i0 - 1, 0), min(i1, ts.size)
    if i1 - i0 < 4:
        return None
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
    if refined is not None and abs(refined - t) <= dt:
        t = refined
    frame = float(np.interp(t, ts, np.arange(ts.size, dtype=float)))
    return VideoClap(time_s=t, frame=frame, confidence=conf, peak=peak, still=still, window=(i0, i0 + n))


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
    kw = dict(post_s=post_s, exclude_s=exclude_s, roi=roi, chunk=chunk, z_lo=z_lo, z_hi=z_hi,
              min_distinct=min_distinct, refine=refine)
    if approx_times is None:
        span = min(search_s, 0.5 * float(ts[-1] - ts[0]))
        head = _clap_in(ts, read_window, float(ts[0]), float(ts[0]) + span, **kw)
        if head is not None and head.confidence > 0:
            return [head]
        return [_clap_in(ts, read_window, float(ts[-1]) - span, float(ts[-1]), **kw)]
    return [_clap_in(ts, read_window, t - window_s, t + window_s, **kw) for t in approx_times]


# --------------------------------------------------------------------------------------------- clocks
@dataclass
class ClockMap:
    """t_mocap = offset_s + ratio · t_video.

    Attributes
    ----------
    offset_s : mocap time of video time 0, seconds.
    ratio : mocap seconds per video second (1 with a single clap).
    n_claps : clap pairs used.
    offset_at_first_clap_s : t_mocap − t_video at the first clap pair.
    residual_ms : largest misfit of a clap pair (0 with one or two pairs).
    """

    offset_s: float
    ratio: float
    n_claps: int
    offset_at_first_clap_s: float = 0.0
    residual_ms: float = 0.0

    def to_mocap(self, t_video: np.ndarray | float) -> np.ndarray:
        return self.offset_s + self.ratio * np.asarray(t_video, dtype=np.float64)

    @property
    def drift_ppm(self) -> float:
        return (self.ratio - 1.0) * 1e6

    def drift_ms(self, duration_s: float) -> float:
        """How far the video clock drifts from the mocap clock over ``duration_s`` (video seconds), ms."""
        return (self.ratio - 1.0) * duration_s * 1000.0


def clock_map(mocap_claps: Sequence[Clap], video_claps: Sequence[VideoClap | None]) -> ClockMap:
    """Fit t_mocap = offset + ratio · t_video to the clap pairs (the i-th mocap clap with the i-th video clap;
    pairs with ``None`` are skipped). One pair: ratio 1; two: exact; more: least squares."""
    pairs = [(m.time_s, v.time_s) for m, v in zip(mocap_claps, video_claps, strict=True) if v is not None]
    if not pairs:
        raise ValueError("no clap pair to map the clocks")
    tm = np.array([p[0] for p in pairs])
    tv = np.array([p[1] for p in pairs])
    first = float(tm[0] - tv[0])
    if len(pairs) == 1:
        return ClockMap(offset_s=first, ratio=1.0, n_claps=1, offset_at_first_clap_s=first)
    cv = tv - tv.mean()
    ratio = float(np.dot(cv, tm - tm.mean()) / np.dot(cv, cv))
    offset = float(tm.mean() - ratio * tv.mean())
    res = tm - (offset + ratio * tv)
    return ClockMap(offset_s=offset, ratio=ratio, n_claps=len(pairs),
                    offset_at_first_clap_s=float(offset + (ratio - 1.0) * tv[0]),
                    residual_ms=float(np.max(np.abs(res)) * 1000.0))


def _slerp_vectors(a: np.ndarray, b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Great-circle interpolation between unit vectors a and b (N, 3) at fractions u (N,): a rotated about
    a × b by u times the angle between them. Antipodal pairs (no unique great circle) give NaN."""
    cross = np.cross(a, b)
    s = np.linalg.norm(cross, axis=1)
    c = np.einsum("ij,ij->i", a, b)
    angle = np.arctan2(s, c)
    # rotvec = axis · angle, with angle / sin(angle) → 1 for nearly equal vectors
    scale = np.divide(angle, s, out=np.ones_like(angle), where=s > 1e-12)
    rotvec = cross * (u * scale)[:, None]
    out = np.full_like(a, np.nan)
    ok = np.all(np.isfinite(rotvec), axis=1) & np.all(np.isfinite(a), axis=1) & ~((s <= 1e-12) & (c < 0))
    if np.any(ok):
        out[ok] = Rotation.from_rotvec(rotvec[ok]).apply(a[ok])
    return out


def resample_to_mocap(t_video: np.ndarray, values: np.ndarray, kind: str, mocap_times: np.ndarray,
                      clock: ClockMap) -> tuple[np.ndarray, np.ndarray]:
    """Put a video-clock signal on the mocap frames.

    Parameters
    ----------
    t_video : (N,) increasing sample times, video clock, seconds.
    values : (N, 3) unit directions (``kind="direction"``), (N,) or (N, D) floats (``"scalar"``: linear;
        ``"confidence"``: the smaller of the two neighbours), or (N,) bool (``"bool"``: both neighbours).
    mocap_times : (F,) mocap frame times, seconds.
    clock : the clock map.

    Returns
    -------
    resampled : (F, ...) values on the mocap frames; NaN (False for bool) where the video does not cover the
        frame (before its first or after its last sample: never extrapolated) or a neighbour is NaN.
    covered : (F,) bool, frames inside the video's span.

    A mocap time that falls exactly on a video sample takes that sample alone.
    """
    tv = clock.to_mocap(t_video)
    tm = np.asarray(mocap_times, dtype=np.float64)
    vals = np.asarray(values)
    n = tv.size
    if n < 2:
        raise ValueError("need at least two video samples to resample")
    covered = (tm >= tv[0]) & (tm <= tv[-1])
    i = np.clip(np.searchsorted(tv, tm, side="right") - 1, 0, n - 2)
    u = np.clip((tm - tv[i]) / (tv[i + 1] - tv[i]), 0.0, 1.0)
    lo, hi = vals[i], vals[i + 1]
    if kind == "bool":
        out = np.where(u == 0, lo, np.where(u == 1, hi, lo & hi)) & covered
        return out.astype(bool), covered
    lo = lo.astype(np.float64)
    hi = hi.astype(np.float64)
    if kind == "direction":
        out = _slerp_vectors(lo, hi, u)
    elif kind == "scalar":
        uu = u.reshape((-1,) + (1,) * (vals.ndim - 1))
        out = lo + uu * (hi - lo)
        # keep exact samples exact, and a NaN neighbour with zero weight harmless
        out = np.where(uu == 0, lo, np.where(uu == 1, hi, out))
    elif kind == "confidence":
        uu = u.reshape((-1,) + (1,) * (vals.ndim - 1))
        out = np.where(uu == 0, lo, np.where(uu == 1, hi, np.minimum(lo, hi)))
    else:
        raise ValueError(f"unknown kind {kind!r} (direction, scalar, confidence or bool)")
    out = np.array(out, dtype=np.float64)
    out[~covered] = np.nan
    return out, covered


# --------------------------------------------------------------------------------------------- take
@dataclass
class SyncResult:
    """The clock map of a take and how it was found.

    Attributes
    ----------
    clock : the clock map.
    mocap_claps : every clap found in the mocap.
    video_claps : the video clap paired with each mocap clap (``None`` where none was found).
    frames_without_video : mocap frames outside the video's span once mapped.
    frames_decoded : video frames decoded to find the claps.
    qc : the QC record (plain JSON-able values).
    """

    clock: ClockMap
    mocap_claps: list[Clap]
    video_claps: list[VideoClap | None]
    frames_without_video: int
    frames_decoded: int
    qc: dict = field(default_factory=dict)


def sync_take(clap_a_xyz: np.ndarray, clap_b_xyz: np.ndarray, valid_a: np.ndarray, valid_b: np.ndarray,
              rate_hz: float, probe_timestamps: np.ndarray, read_window: ReadWindow, *,
              offset_guess_s: float | None = None, ratio_guess: float = 1.0, window_s: float = 1.5,
              search_s: float = 20.0, max_drift: float = 0.005, min_confidence: float = 0.05,
              roi: tuple[int, int, int, int] | None = None, mocap_path: str | None = None,
              video_path: str | None = None, take: str | None = None,
              mocap_kw: dict | None = None, video_kw: dict | None = None) -> SyncResult:
    """Find the claps on both clocks and map the video clock onto the mocap clock.

    Parameters
    ----------
    clap_a_xyz, clap_b_xyz, valid_a, valid_b, rate_hz : the clapper markers (see :func:`mocap_claps`); the
        take has ``len(valid_a)`` frames at ``rate_hz``.
    probe_timestamps, read_window : the video (see :func:`video_claps`).
    offset_guess_s, ratio_guess : prior t_mocap ≈ offset + ratio · t_video. Without one, the first mocap
        clap is looked for in the first ``search_s`` of the video (or, failing that, the last mocap clap in
        the last ``search_s``), and the other claps are predicted from that pair.
    window_s : half-width of each video search window; windows predicted from a clap pair widen by
        ``max_drift`` times the distance to that pair.
    max_drift : largest |ratio − 1| accepted; more means the claps were mismatched (StageError).
    min_confidence : video claps below this confidence count as not found.
    mocap_path, video_path, take : named in error messages.
    mocap_kw, video_kw : further parameters of :func:`mocap_claps` and :func:`video_claps`.

    Raises
    ------
    StageError : no clap in the mocap, no clap found in the video, or an implausible clock ratio.
    """
    mocap_kw = dict(mocap_kw or {})
    video_kw = dict(video_kw or {}, roi=roi)
    ts = np.asarray(probe_timestamps, dtype=np.float64)
    T = int(np.asarray(valid_a).shape[0])
    counted = [0]

    def reader(start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        t, fr = read_window(start, stop)
        counted[0] += len(fr)
        return t, fr

    mc = mocap_claps(clap_a_xyz, clap_b_xyz, valid_a, valid_b, rate_hz, **mocap_kw)
    if not mc:
        raise StageError(mocap_path, "no clap found in the clapper markers (no fast closing that stays shut)",
                         take=take)
    tm = np.array([c.time_s for c in mc])
    vc: list[VideoClap | None]
    if offset_guess_s is not None:
        approx = (tm - offset_guess_s) / ratio_guess
        vc = video_claps(ts, reader, approx.tolist(), window_s=window_s, **video_kw)
    else:
        vc = [None] * len(mc)
        # never more than half the video, so that a clap near the end cannot be taken for the first one
        half = 0.5 * min(search_s, 0.5 * float(ts[-1] - ts[0]))
        anchor = 0
        first = video_claps(ts, reader, [float(ts[0] + half)], window_s=half, **video_kw)[0]
        if first is None or first.confidence < min_confidence:
            anchor = len(mc) - 1
            first = video_claps(ts, reader, [float(ts[-1] - half)], window_s=half, **video_kw)[0]
        if first is not None and first.confidence >= min_confidence:
            vc[anchor] = first
            off = tm[anchor] - first.time_s
            for j in range(len(mc)):
                if j != anchor:
                    w = window_s + max_drift * abs(tm[j] - tm[anchor])
                    vc[j] = video_claps(ts, reader, [tm[j] - off], window_s=w, **video_kw)[0]
    vc = [v if v is not None and v.confidence >= min_confidence else None for v in vc]
    if all(v is None for v in vc):
        where = "around the expected times" if offset_guess_s is not None else \
            f"in the first or last {search_s:g} s"
        raise StageError(video_path, f"no clap found in the video {where} ({counted[0]} frames decoded)",
                         take=take)
    clock = clock_map(mc, vc)
    if abs(clock.ratio - 1.0) > max_drift:
        raise StageError(video_path, f"clock ratio {clock.ratio:.6f} from the claps is implausible "
                         f"(more than {max_drift:.2%} drift): the claps are probably mismatched", take=take)
    frame_t = np.arange(T, dtype=np.float64) / float(rate_hz)
    span = clock.to_mocap(ts[[0, -1]])
    uncovered = int(np.count_nonzero((frame_t < span[0]) | (frame_t > span[1])))
    duration_v = float(ts[-1] - ts[0])
    qc = {
        "offset_s": clock.offset_at_first_clap_s,
        "offset_at_video_zero_s": clock.offset_s,
        "ratio": clock.ratio,
        "drift_ppm": clock.drift_ppm,
        "drift_ms_over_take": clock.drift_ms(duration_v),
        "n_claps": clock.n_claps,
        "residual_ms": clock.residual_ms,
        "claps": [{"mocap_s": m.time_s, "mocap_confidence": m.confidence,
                   "video_s": None if v is None else v.time_s,
                   "video_confidence": None if v is None else v.confidence}
                  for m, v in zip(mc, vc, strict=True)],
        "frames_without_video": uncovered,
        "frames_decoded": counted[0],
        "video_frames": int(ts.size),
        "warnings": [f"mocap clap at {m.time_s:.3f} s has no video counterpart"
                     for m, v in zip(mc, vc, strict=True) if v is None],
    }
    return SyncResult(clock=clock, mocap_claps=mc, video_claps=vc, frames_without_video=uncovered,
                      frames_decoded=counted[0], qc=qc)
