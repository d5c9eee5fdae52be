"""sync stage, clocks: the map from the video clock to the mocap clock fitted to the clap pairs, and video-clock
signals resampled onto the mocap frames.

The mocap clock is the master clock (SPEC §2): t_mocap = offset + ratio · t_video. One clap pair gives the offset
(ratio 1); two or more also give the ratio, which holds a camera's rate error (labelled 60 fps running at 59.94:
ratio 1.001) or crystal drift. :func:`resample_to_mocap` never extrapolates.
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

__all__ = ["CLAP_TIMING_MS", "ClockChoice", "ClockMap", "choose_clock", "clap_timing_ms", "clock_map",
           "resample_to_mocap"]

#: how far a trusted clap pair's offset typically is from the truth, ms: ``bench/bench_sync.py`` (29.97–120 Hz
#: mocap, 60 fps video, 0.4–2 mm marker noise) gives a median of 0.7 ms (the worst of 24 takes: 6 ms, at 29.97 Hz)
CLAP_TIMING_MS = 1.5


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


@dataclass
class ClockChoice:
    """The clock map a take's claps support, and what it rests on.

    Attributes
    ----------
    clock : the map.
    used : per clap pair, whether it set the map.
    bound_ms : how far the map may be from the truth anywhere over the video, ms: each clap's timing
        (:func:`clap_timing_ms`: :data:`CLAP_TIMING_MS`, or half a video frame for a clap timed by its closing
        burst alone) carried along the fitted line, plus, on a single clap, what an unmeasured ratio of up to
        ``max_drift`` does over the video's distance from that clap.
    warnings : one line per clap left out and why (naming the video and the clap).
    """

    clock: ClockMap
    used: list[bool]
    bound_ms: float
    warnings: list[str]


def _floor2(x: float) -> str:
    """A confidence to two decimals, rounded down (so a value just under a threshold never prints as it)."""
    return f"{np.floor(x * 100.0) / 100.0:.2f}"


def clap_timing_ms(clap: VideoClap) -> float:
    """How far a video clap's instant may be off, ms: the claps' typical timing (:data:`CLAP_TIMING_MS`), or
    more where the clap could not be refined by the arm's displacement (``VideoClap.timing_ms``)."""
    return CLAP_TIMING_MS if clap.timing_ms is None else max(CLAP_TIMING_MS, float(clap.timing_ms))


def _bound_ms(tv_used: np.ndarray, eps_ms: np.ndarray, video_span: tuple[float, float], max_drift: float) -> float:
    """How far the map fitted to claps at video times ``tv_used``, each within ``eps_ms``, may be off over
    ``video_span``: one clap, its timing plus what an unmeasured ratio of up to ``max_drift`` does at the
    span's far end; more, the least-squares line's error Σ |h_i(t)| ε_i (h_i(t) = 1/n + (t − t̄)(t_i − t̄) /
    Σ(t_j − t̄)², each clap's weight in the line at t) at the span's ends and at the claps (it is convex in t):
    with two claps of equal timing ε, ε between them and ε·distance/half-span beyond."""
    far = max(abs(video_span[0] - tv_used.mean()), abs(video_span[1] - tv_used.mean()))
    if tv_used.size == 1:
        return float(eps_ms[0]) + max_drift * far * 1000.0
    c = tv_used - tv_used.mean()
    at = np.concatenate([np.asarray(video_span, dtype=np.float64), tv_used])
    h = 1.0 / tv_used.size + np.outer(at - tv_used.mean(), c) / float(c @ c)      # (points, claps)
    return float((np.abs(h) @ eps_ms).max())


def choose_clock(mocap_claps: Sequence[Clap], video_claps: Sequence[VideoClap | None], *,
                 video_span: tuple[float, float], trust: float = 0.5, mocap_trust: float = 0.15,
                 max_drift: float = 0.0012, video: str = "the video") -> ClockChoice:
    """The clock map from the clap pairs that can be trusted, falling back rather than failing (SPEC §3.4).

    A pair is trusted when its video clap has at least ``trust`` confidence and its mocap clap at least
    ``mocap_trust`` (the mocap's confidence saturates late: sharp claps under 2 mm of marker noise at 120 Hz
    score 0.2–0.5 and land within a third of a frame, while slow, soft claps and contacts hidden by a gap score
    under 0.1; ``bench/bench_sync.py``, ``bench/bench_claps_truth.py``). Two or more trusted pairs set the
    offset and the ratio when the ratio is within ``max_drift`` of 1 (the rates' nominal ratio; a 59.94 Hz
    camera labelled 60 is 0.001 off); otherwise the map falls back to the surest single pair and the nominal
    ratio. A weak clap never sets the ratio. With no trusted pair the surest pair found stands alone. Every
    clap left out gets a warning line naming ``video`` and the clap.

    Raises ValueError when no pair has both claps.
    """
    pairs = [j for j, v in enumerate(video_claps) if v is not None]
    if not pairs:
        raise ValueError("no clap pair to map the clocks")
    sure = {j: min(mocap_claps[j].confidence, video_claps[j].confidence) for j in pairs}  # type: ignore[union-attr]
    trusted = [j for j in pairs if video_claps[j].confidence >= trust  # type: ignore[union-attr]
               and mocap_claps[j].confidence >= mocap_trust]

    def name(j: int) -> str:
        v = video_claps[j]
        at = f"video {v.time_s:.2f} s" if v is not None else "no video clap"
        return f"clap {j + 1} (mocap {mocap_claps[j].time_s:.2f} s, {at})"

    warnings: list[str] = []
    use = trusted
    if len(trusted) >= 2:
        fit = clock_map([mocap_claps[j] for j in trusted], [video_claps[j] for j in trusted])
        if abs(fit.ratio - 1.0) > max_drift:
            best = max(trusted, key=lambda j: sure[j])
            warnings.append(f"{video}: claps {', '.join(str(j + 1) for j in trusted)} give a clock ratio of "
                            f"{fit.ratio:.6f} ({fit.drift_ppm:+.0f} ppm), more than cameras drift "
                            f"({max_drift * 1e6:.0f} ppm): the clock rests on {name(best)} and the nominal rate")
            use = [best]
    elif len(trusted) == 1:
        use = trusted
    else:
        use = [max(pairs, key=lambda j: sure[j])]
    rests_on = " and ".join(name(k) for k in use) + (" and the nominal rate" if len(use) == 1 else "")
    for j in (k for k in pairs if k not in trusted):
        found = f"mocap {_floor2(mocap_claps[j].confidence)}, video {_floor2(video_claps[j].confidence)}"  # type: ignore[union-attr]
        what = "it stands alone, with the nominal rate" if j in use else f"not used; the clock rests on {rests_on}"
        warnings.append(f"{video}: {name(j)} found with low confidence ({found}; a clap pair sets the ratio from "
                        f"mocap {mocap_trust:g} and video {trust:g}): {what}")
    clock = clock_map(mocap_claps, [v if j in use else None for j, v in enumerate(video_claps)])
    tv = np.array([video_claps[j].time_s for j in use])  # type: ignore[union-attr]
    eps = np.array([clap_timing_ms(video_claps[j]) for j in use])  # type: ignore[arg-type]
    for j, e in zip(use, eps, strict=True):
        if e > CLAP_TIMING_MS:
            warnings.append(f"{video}: {name(j)} is timed by the closing burst alone (the arm's approach to shut "
                            f"could not be followed frame by frame, e.g. a clapper partly hidden): its instant "
                            f"may be {e:.1f} ms off, and the clock map with it")
    return ClockChoice(clock=clock, used=[j in use for j in range(len(mocap_claps))],
                       bound_ms=_bound_ms(tv, eps, video_span, max_drift if len(use) == 1 else 0.0),
                       warnings=warnings)


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

