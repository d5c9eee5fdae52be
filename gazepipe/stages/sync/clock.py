"""sync stage, clocks: the map from the video clock to the mocap clock fitted to the clap pairs, and video-clock
signals resampled onto the mocap frames.

The mocap clock is the master clock (SPEC §2): t_mocap = offset + ratio · t_video. Every clap pair is a measurement
with a timing uncertainty (its mocap and its video clap's, :attr:`Clap.timing_s`, :attr:`VideoClap.timing_s`); the
map is their weighted least-squares line with the nominal ratio 1 as a prior whose width is what cameras do
(:func:`fit_clock`). A pair is set aside only when it disagrees with the others and any camera rate within
``max_drift`` of nominal beyond its uncertainty (:func:`choose_clock`), never for a low detector score. The map's
uncertainty anywhere on the video clock follows from the fit (:meth:`ClockMap.sd_s`, :func:`bound_over`).
:func:`resample_to_mocap` never extrapolates.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gazepipe.stages.geometry import slerp_vectors

if TYPE_CHECKING:
    from gazepipe.stages.sync.clap import Clap
    from gazepipe.stages.sync.video import VideoClap

__all__ = ["BOUND_SIGMAS", "DISAGREE_P", "ClockChoice", "ClockMap", "bound_over", "choose_clock", "clock_map",
           "fit_clock", "map_sd_s", "resample_to_mocap", "set_aside"]

#: the clock map's bound is this many standard deviations of its error at the span's worse end (90 % of maps lie
#: within it there: a clap pair at 30 Hz mocap and 60 fps video is timed to about ±2.3 ms, so a 95 % bound near a
#: clap would sit at the 5 ms check's threshold however clean the claps)
BOUND_SIGMAS = 1.645
#: a clap pair is set aside when the claps cannot all be fitted, with a camera rate within tolerance, without a
#: misfit that consistent claps would show less often than this (chi-square; 2.58 standard deviations for one
#: degree of freedom)
DISAGREE_P = 0.01


@dataclass
class ClockMap:
    """t_mocap = offset_s + ratio · t_video, and how well it is known.

    Attributes
    ----------
    offset_s : mocap time of video time 0, seconds.
    ratio : mocap seconds per video second.
    n_claps : clap pairs the map rests on.
    offset_at_first_clap_s : t_mocap − t_video at the first of those pairs.
    residual_ms : largest misfit of a pair the map rests on, ms.
    ref_s : video time the fit is centred on (the claps' weighted mean), s.
    cov : covariance of (the map's mocap time at ``ref_s``, the ratio): (var s², cov s, var), from the claps'
        timing and the ratio's prior; zeros when unknown.
    prior_sd : standard deviation of the ratio's prior (what cameras do), dimensionless; 0 when none.
    """

    offset_s: float
    ratio: float
    n_claps: int
    offset_at_first_clap_s: float = 0.0
    residual_ms: float = 0.0
    ref_s: float = 0.0
    cov: tuple[float, float, float] = (0.0, 0.0, 0.0)
    prior_sd: float = 0.0

    def to_mocap(self, t_video: np.ndarray | float) -> np.ndarray:
        return self.offset_s + self.ratio * np.asarray(t_video, dtype=np.float64)

    def to_video(self, t_mocap: np.ndarray | float) -> np.ndarray:
        return (np.asarray(t_mocap, dtype=np.float64) - self.offset_s) / self.ratio

    @property
    def drift_ppm(self) -> float:
        return (self.ratio - 1.0) * 1e6

    def drift_ms(self, duration_s: float) -> float:
        """How far the video clock drifts from the mocap clock over ``duration_s`` (video seconds), ms."""
        return (self.ratio - 1.0) * duration_s * 1000.0

    def sd_s(self, t_video: np.ndarray | float) -> np.ndarray:
        """Standard deviation of the mapped mocap time at video times ``t_video``, s (quadratic in t: largest at
        the ends of any span)."""
        return map_sd_s(self.cov, self.ref_s, t_video)


def map_sd_s(cov: Sequence[float], ref_s: float, t_video: np.ndarray | float) -> np.ndarray:
    """Standard deviation, s, of a map whose (value at ``ref_s``, ratio) have covariance ``cov`` = (var, cov,
    var), at video times ``t_video``."""
    x = np.asarray(t_video, dtype=np.float64) - ref_s
    v = float(cov[0]) + 2.0 * float(cov[1]) * x + float(cov[2]) * x * x
    return np.sqrt(np.maximum(v, 0.0))


def fit_clock(t_video: np.ndarray, t_mocap: np.ndarray, sd_s: np.ndarray, prior_sd: float | None,
              prior_ratio: float = 1.0) -> ClockMap:
    """The weighted least-squares clock map through clap pairs.

    Parameters
    ----------
    t_video, t_mocap : (n,) the pairs' instants on each clock, s.
    sd_s : (n,) each pair's timing uncertainty (one standard deviation), s.
    prior_sd : the ratio's prior standard deviation around ``prior_ratio`` (what cameras do); None: no prior
        (needs two pairs or more at different times).

    Returns
    -------
    The map minimising Σ ((t_mocap − map(t_video)) / sd)² + ((ratio − prior_ratio) / prior_sd)², with the
    covariance of its value at the weighted mean video time and its ratio (the inverse of the normal matrix).
    """
    tv, tm = np.asarray(t_video, dtype=np.float64), np.asarray(t_mocap, dtype=np.float64)
    w = 1.0 / np.square(np.asarray(sd_s, dtype=np.float64))
    if tv.size == 0:
        raise ValueError("no clap pair to map the clocks")
    ref = float(np.sum(w * tv) / np.sum(w))
    x = tv - ref
    p = 0.0 if prior_sd is None or not prior_sd > 0 else 1.0 / prior_sd ** 2
    normal = np.array([[np.sum(w), np.sum(w * x)], [np.sum(w * x), np.sum(w * x * x) + p]])
    rhs = np.array([np.sum(w * tm), np.sum(w * x * tm) + p * prior_ratio])
    if abs(np.linalg.det(normal)) < 1e-300 or not np.isfinite(normal).all():
        raise ValueError("the clap pairs cannot set a ratio (one clap and no prior)")
    at_ref, ratio = np.linalg.solve(normal, rhs)
    cov = np.linalg.inv(normal)
    res = tm - (at_ref + ratio * x)
    offset = float(at_ref - ratio * ref)
    return ClockMap(offset_s=offset, ratio=float(ratio), n_claps=int(tv.size),
                    offset_at_first_clap_s=float(offset + (ratio - 1.0) * tv[0]),
                    residual_ms=float(np.max(np.abs(res)) * 1000.0) if tv.size > 2 else 0.0,
                    ref_s=ref, cov=(float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])),
                    prior_sd=0.0 if p == 0.0 else float(prior_sd))  # type: ignore[arg-type]


def clock_map(mocap_claps: Sequence[Clap], video_claps: Sequence[VideoClap | None]) -> ClockMap:
    """The map through the clap pairs (the i-th mocap clap with the i-th video clap; pairs with ``None`` are
    skipped), all weighted alike, without a prior: one pair gives ratio 1; two, the line through them; more, the
    least-squares line."""
    pairs = [(m.time_s, v.time_s) for m, v in zip(mocap_claps, video_claps, strict=True) if v is not None]
    if not pairs:
        raise ValueError("no clap pair to map the clocks")
    tm, tv = np.array(pairs).T
    if len(pairs) == 1:
        first = float(tm[0] - tv[0])
        return ClockMap(offset_s=first, ratio=1.0, n_claps=1, offset_at_first_clap_s=first)
    return fit_clock(tv, tm, np.ones(tv.size), None)


def _misfit_within(tv: np.ndarray, tm: np.ndarray, w: np.ndarray, max_drift: float) -> float:
    """The smallest weighted misfit Σ w (tm − a − r·tv)² of a line whose ratio r lies within ``max_drift`` of 1
    (chi-square; 0 with one pair). It is a convex quadratic in r once a is chosen for it, so the best r is the
    free least-squares ratio clamped to the tolerance."""
    if tv.size < 2:
        return 0.0
    mv, mm = np.sum(w * tv) / np.sum(w), np.sum(w * tm) / np.sum(w)
    cv, cm = tv - mv, tm - mm
    sxx = float(np.sum(w * cv * cv))
    r = float(np.sum(w * cv * cm) / sxx) if sxx > 0 else 1.0
    r = min(max(r, 1.0 - max_drift), 1.0 + max_drift)
    return float(np.sum(w * (cm - r * cv) ** 2))


def _misfit_allowed(n: int) -> float:
    """The largest chi-square of ``n`` consistent pairs (n − 1 degrees of freedom at the tolerance's edge, at
    least one) at :data:`DISAGREE_P`."""
    from scipy import stats  # here: planning a run imports this module and must not load scipy

    return float(stats.chi2.isf(DISAGREE_P, max(n - 1, 1)))


def set_aside(tv: np.ndarray, tm: np.ndarray, sd_s: np.ndarray, max_drift: float,
              surety: np.ndarray | None = None) -> list[int]:
    """Indices of the pairs to set aside, worst first: while the pairs kept cannot all be fitted with a ratio
    within ``max_drift`` of 1 without a misfit beyond :data:`DISAGREE_P` (:func:`_misfit_within`), the pair
    whose removal lowers the misfit most goes (between pairs that lower it alike, the less well timed one, then
    the one with the lower ``surety``, the detectors' confidence). At least one pair is kept."""
    keep = list(range(tv.size))
    w = 1.0 / np.square(sd_s)
    out: list[int] = []
    sure = np.zeros(tv.size) if surety is None else np.asarray(surety, dtype=np.float64)
    while len(keep) >= 2:
        idx = np.array(keep)
        chi2 = _misfit_within(tv[idx], tm[idx], w[idx], max_drift)
        if chi2 <= _misfit_allowed(len(keep)):
            break
        gain = np.array([chi2 - _misfit_within(np.delete(tv[idx], k), np.delete(tm[idx], k), np.delete(w[idx], k),
                                               max_drift) for k in range(len(keep))])
        best = gain.max()
        tied = [k for k in range(len(keep)) if gain[k] >= best - 1e-9 * max(best, 1.0)]
        k = max(tied, key=lambda k: (sd_s[keep[k]], -sure[keep[k]]))
        out.append(keep.pop(k))
    return out


def bound_over(cov: Sequence[float], ref_s: float, prior_sd: float, t_video: np.ndarray, sd_s: np.ndarray,
               span: tuple[float, float], sigmas: float = BOUND_SIGMAS) -> tuple[float, float, int | None]:
    """How far a fitted map may be off over the video-clock ``span``, and why.

    Parameters
    ----------
    cov, ref_s, prior_sd : the map's covariance, the video time it is centred on, its ratio's prior standard
        deviation (:class:`ClockMap`).
    t_video, sd_s : the video times and timing (one standard deviation, s) of the clap pairs it rests on.
    span : (start, end) video seconds.

    Returns
    -------
    bound_ms : ``sigmas`` standard deviations of the map's error at the worse end of ``span`` (its variance is
        quadratic in t, so the ends bound it), ms.
    at_s : that end, video seconds.
    limiting : the pair (index into ``t_video``) whose timing adds most to the variance there, or None when the
        ratio's prior does (the map rests on one clap and the nominal rate there). The shares add up to the
        variance: each pair's is (gᵀ C aᵢ)² / σᵢ², the prior's (gᵀ C e)² / σ_r², with C the covariance,
        g = (1, at − ref), aᵢ = (1, tᵢ − ref) and e = (0, 1).
    """
    ends = np.array(span, dtype=np.float64)
    sd = map_sd_s(cov, ref_s, ends)
    k = int(np.argmax(sd))
    at = float(ends[k])
    c = np.array([[cov[0], cov[1]], [cov[1], cov[2]]], dtype=np.float64)
    g = c @ np.array([1.0, at - ref_s])
    share = (g[0] + g[1] * (np.asarray(t_video, dtype=np.float64) - ref_s)) ** 2 / np.square(sd_s)
    prior = (g[1] / prior_sd) ** 2 if prior_sd > 0 else 0.0
    limiting = None if share.size == 0 or prior > share.max() else int(np.argmax(share))
    return float(sigmas * sd[k] * 1000.0), at, limiting


@dataclass
class ClockChoice:
    """The clock map a take's claps support, and what it rests on.

    Attributes
    ----------
    clock : the map.
    used : per clap, whether the map rests on it (False: no video clap, or set aside).
    set_aside : the claps set aside (0-based), worst first.
    pair_sd_s : per clap, its pair's timing (one standard deviation, s; NaN without a video clap).
    bound_ms, bound_at_s, limiting : :func:`bound_over` the whole video (``limiting`` 0-based, among all the
        claps; None for the nominal rate).
    warnings : one line per clap set aside (naming the video and the clap).
    """

    clock: ClockMap
    used: list[bool]
    set_aside: list[int]
    pair_sd_s: list[float]
    bound_ms: float
    bound_at_s: float
    limiting: int | None
    warnings: list[str]


def clap_name(j: int, mocap: Clap, video: VideoClap | None) -> str:
    """How a warning names clap ``j`` (0-based): its number and instants on both clocks."""
    at = f"video {video.time_s:.2f} s" if video is not None else "no video clap"
    return f"clap {j + 1} (mocap {mocap.time_s:.2f} s, {at})"


def choose_clock(mocap_claps: Sequence[Clap], video_claps: Sequence[VideoClap | None], *,
                 video_span: tuple[float, float], max_drift: float = 0.0012,
                 video: str = "the video") -> ClockChoice:
    """The clock map from every clap pair found, weighted by its timing (SPEC §3.4).

    Each pair's uncertainty is its mocap and its video clap's timing together (sqrt(σ_m² + σ_v²)). Pairs that
    disagree with the others and any camera rate within ``max_drift`` of nominal beyond their uncertainty are
    set aside (:func:`set_aside`), with a warning naming ``video`` and the clap; the rest set the map with the
    nominal ratio as a prior of standard deviation ``max_drift`` / 2 (``max_drift`` its 95 % range). A clap is
    never left out for a low detector score.

    Raises ValueError when no pair has both claps.
    """
    pairs = [j for j, v in enumerate(video_claps) if v is not None]
    if not pairs:
        raise ValueError("no clap pair to map the clocks")
    vc = [video_claps[j] for j in pairs]
    tv = np.array([v.time_s for v in vc if v is not None])
    tm = np.array([mocap_claps[j].time_s for j in pairs])
    sd = np.array([float(np.hypot(mocap_claps[j].timing_s, v.timing_s)) for j, v in zip(pairs, vc, strict=True)
                   if v is not None])
    surety = np.array([min(mocap_claps[j].confidence, v.confidence) for j, v in zip(pairs, vc, strict=True)
                       if v is not None])
    out = set_aside(tv, tm, sd, max_drift, surety)
    keep = [k for k in range(len(pairs)) if k not in out]
    clock = fit_clock(tv[keep], tm[keep], sd[keep], 0.5 * max_drift)
    bound, at, lim = bound_over(clock.cov, clock.ref_s, clock.prior_sd, tv[keep], sd[keep], video_span)
    rests = " and ".join(clap_name(pairs[k], mocap_claps[pairs[k]], video_claps[pairs[k]]) for k in keep)
    warnings = []
    alone = " and the nominal rate" if len(keep) == 1 else ""
    for k in out:
        j = pairs[k]
        miss = (tm[k] - float(clock.to_mocap(tv[k]))) * 1000.0
        warnings.append(f"{video}: {clap_name(j, mocap_claps[j], video_claps[j])} set aside: it is {miss:+.1f} ms "
                        f"off the clock the other clap{'s give' if len(keep) > 1 else ' gives'} with a camera rate within "
                        f"{max_drift * 1e6:.0f} ppm of nominal, beyond its timing (±{sd[k] * 1000.0:.1f} ms); the "
                        f"clock rests on {rests}{alone}")
    used = [False] * len(mocap_claps)
    pair_sd = [float("nan")] * len(mocap_claps)
    for k, j in enumerate(pairs):
        used[j], pair_sd[j] = k in keep, float(sd[k])
    return ClockChoice(clock=clock, used=used, set_aside=[pairs[k] for k in out], pair_sd_s=pair_sd, bound_ms=bound,
                       bound_at_s=at, limiting=None if lim is None else pairs[keep[lim]], warnings=warnings)


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
        out = slerp_vectors(lo, hi, u, antipodal="nan")
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

