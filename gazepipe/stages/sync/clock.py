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

__all__ = ["ClockMap", "clock_map", "resample_to_mocap"]


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

