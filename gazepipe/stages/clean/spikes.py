"""Spike removal (SPEC §3.2 step 1): samples no body could have produced become gaps.

Two detectors. :func:`find_glitches` finds short glitches (ghost reflections of one or two frames, 15 mm and up)
by a robust test on each trajectory, confirmed or extended by the marker's distances to its rigid cluster;
:func:`remove_spikes` cuts trajectories at implausible accelerations (jumps, swapped labels) and drops the
short pieces. Positions are (T, M, 3) float64 mm in the lab frame; ``valid`` is (T, M) bool; frames are rows.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from gazepipe.stages.geometry import norm3

#: standard gravity, mm/s²
G_MM_S2 = 9806.65
#: half-width (frames) of the running median a sample is compared with: five frames outvote a glitch of two
_MEDIAN_HALF = 2
#: half-width (frames) of the window whose median frame-to-frame step scales the trajectory test
_STEP_HALF = 5
#: a marker's distance to its cluster deviates significantly beyond this many times its typical deviation
_CLUSTER_K = 6.0
#: frames per block of the per-frame tests: their temporaries (some 200 bytes per marker sample: sorted windows,
#: running medians) are bounded by a block, not the take; each block also reads ``_BLOCK_MARGIN`` frames on each
#: side, as far as the widest window reaches (the step median's half-width, one frame of differences, the
#: residual median's half-width), so the result is the same bits whatever the block size
_BLOCK_FRAMES = 8192
_BLOCK_MARGIN = _STEP_HALF + 1 + _MEDIAN_HALF + 1
#: lines at most this long (windows; a few markers of a frame) take the compiled median, longer ones numpy's sort
_SHORT_WINDOW = 16
#: trajectories (a marker's or a pair's, the whole take) sorted at a time for their medians
_MEDIAN_LINES = 8


def running_median(a: np.ndarray, half: int, min_count: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Median over the ``2·half + 1`` rows centred on each row of ``a`` (T, ...), NaNs left out, and the count
    of finite values it used; NaN where fewer than ``min_count`` are finite. Compiled
    (:func:`gazepipe.stages.clean.kernels.running_medians`): each window sorted, NaN last; five-row windows
    with every value finite (nearly all of them) take a min/max network instead."""
    from gazepipe.stages.clean.kernels import running_medians  # numba: imported where first needed

    pad = np.full((half, *a.shape[1:]), np.nan)
    padded = np.concatenate([pad, np.asarray(a, dtype=np.float64), pad])
    med, count = running_medians(padded.reshape(padded.shape[0], -1), half, min_count)
    return med.reshape(a.shape), count.reshape(a.shape)


def _sorted_median(win: np.ndarray, min_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Median and finite count over the last axis of ``win``, NaNs left out (see :func:`running_median`):
    the two middle values of the sorted line (NaN last) averaged; NaN with fewer than ``max(min_count, 1)``
    finite values."""
    if win.shape[-1] > _SHORT_WINDOW:         # a long line (a marker's whole take): numpy's sort is the faster
        win = np.sort(win, axis=-1)
        count = np.isfinite(win).sum(axis=-1)
        lo = np.take_along_axis(win, np.maximum(count - 1, 0)[..., None] // 2, axis=-1)[..., 0]
        hi = np.take_along_axis(win, count[..., None] // 2, axis=-1)[..., 0]
        hi = np.where(count % 2 == 1, lo, hi)
        return np.where(count >= max(min_count, 1), 0.5 * (lo + hi), np.nan), count
    from gazepipe.stages.clean.kernels import nan_medians  # numba: imported where first needed

    lines = np.ascontiguousarray(win, dtype=np.float64).reshape(-1, win.shape[-1])
    med, count = nan_medians(lines, min_count)
    return med.reshape(win.shape[:-1]), count.reshape(win.shape[:-1])


def cluster_deviation(xyz: np.ndarray, valid: np.ndarray, clusters: Sequence[Sequence[int]]) -> np.ndarray:
    """Per sample, how far (mm) the marker's distances to its cluster mates are from their values over the take:
    the smallest deviation over the mates measured in that frame (a mate's own glitch moves one distance, the
    marker's glitch moves all of them). (T, M); NaN for markers in no cluster of three or more and where fewer
    than two mates are measured (one mate's glitch would look like the marker's own)."""
    from gazepipe.stages.clean.kernels import least_pair_deviation, pair_distances  # numba: first needed here

    dev = np.full(valid.shape, np.nan)
    for cluster in clusters:
        idx = np.asarray(cluster, dtype=np.int64)
        if idx.size < 3:
            continue
        iu, ju = np.triu_indices(idx.size, 1)
        pairs = pair_distances(xyz, valid, idx[iu], idx[ju])                    # (T, pairs) mm, NaN: unmeasured
        dev[:, idx] = least_pair_deviation(pairs, _nanmedian(pairs, axis=0), iu, ju, idx.size)
    return dev


def find_glitches(xyz: np.ndarray, valid: np.ndarray, clusters: Sequence[Sequence[int]] = (), *,
                  residual_mm: float = 8.0, step_factor: float = 2.0, cluster_mm: float = 5.0) -> np.ndarray:
    """Short glitches: measured samples a ghost reflection put off the marker's path for one or two frames.

    Trajectory test: a sample's distance r to the running median of the five frames around it (which a glitch of
    one or two frames cannot move) is implausible above ``max(residual_mm, step_factor · s)``, s being the median
    frame-to-frame step of the marker over the eleven frames around it. Smooth motion at any speed stays near its
    running median; a sharp turn or a rebound of a fast marker (a target carried from goal to goal) leaves the
    median by about one step, which the step term allows for, at any capture rate. On a marker moving faster than
    a ghost is far, the ghost can stay between its neighbours and the running median follows it. Cluster test,
    for those: where the marker's distances to each of at least two mates measured in that frame
    (:func:`cluster_deviation`) are off their values over the take by more than
    ``max(cluster_mm, 6 ×`` its median deviation``)``, it is a glitch at any speed; a whole segment moving keeps
    its distances. A ghost straight off the plane of a segment of three barely changes the distances: the
    trajectory test is the one that sees it. Samples whose running median has fewer than three measured frames,
    or none on one side, are not judged by the trajectory test.

    Returns the (T, M) bool mask of glitches (measured samples only).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool) & np.isfinite(xyz).all(axis=2)
    n_t = valid.shape[0]
    if n_t < 3:
        return np.zeros(valid.shape, dtype=bool)
    glitch = path_glitches(xyz, valid, residual_mm, step_factor)
    dev = cluster_deviation(xyz, valid, clusters)
    floor = np.maximum(cluster_mm, _CLUSTER_K * np.nan_to_num(_nanmedian(dev, axis=0), nan=np.inf))
    with np.errstate(invalid="ignore"):
        glitch |= dev > floor[None, :]
    return glitch & valid


def path_excess_mm(xyz: np.ndarray, valid: np.ndarray, residual_mm: float, step_factor: float) -> np.ndarray:
    """The trajectory test of :func:`find_glitches`, (T, M) mm: how much farther each sample is from its running
    median than ``max(residual_mm, step_factor`` × the marker's typical step there``)`` (a glitch above 0; NaN
    where not judged). Computed in blocks of ``_BLOCK_FRAMES`` frames, each with ``_BLOCK_MARGIN`` more on either
    side, so its memory is bounded by a block and its values do not depend on the block size."""
    return _by_blocks(lambda x, v: _path_excess_block(x, v, residual_mm, step_factor), xyz, valid, np.float64)


def path_glitches(xyz: np.ndarray, valid: np.ndarray, residual_mm: float, step_factor: float) -> np.ndarray:
    """(T, M) bool: where :func:`path_excess_mm` is above 0, without holding its take-sized float array."""
    def block(x: np.ndarray, v: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return _path_excess_block(x, v, residual_mm, step_factor) > 0.0
    return _by_blocks(block, xyz, valid, np.bool_)


def _by_blocks(block: Callable[[np.ndarray, np.ndarray], np.ndarray], xyz: np.ndarray, valid: np.ndarray,
               dtype: type) -> np.ndarray:
    """A per-frame test ``block(xyz_rows, valid_rows) -> (n, M)`` over the take in blocks of ``_BLOCK_FRAMES``
    frames, each given ``_BLOCK_MARGIN`` frames more on either side."""
    n_t = valid.shape[0]
    out: np.ndarray = np.empty(valid.shape, dtype=dtype)
    for lo in range(0, n_t, _BLOCK_FRAMES):
        hi = min(n_t, lo + _BLOCK_FRAMES)
        a, b = max(0, lo - _BLOCK_MARGIN), min(n_t, hi + _BLOCK_MARGIN)
        out[lo:hi] = block(xyz[a:b], valid[a:b])[lo - a:hi - a]
    return out


def _path_excess_block(xyz: np.ndarray, valid: np.ndarray, residual_mm: float, step_factor: float) -> np.ndarray:
    """:func:`path_excess_mm` of one block of frames (n, M)."""
    x = np.where(valid[..., None], xyz, np.nan)
    med, _ = running_median(x, _MEDIAN_HALF, min_count=3)
    r = norm3(x - med)                                                        # NaN where not judged
    # a median from one side only (the edge of a gap or of the take) lags a moving marker by a step: not judged
    h = _MEDIAN_HALF
    around = sliding_window_view(np.pad(valid, ((h, h), (0, 0))), 2 * h + 1, axis=0)
    r[~(around[..., :h].any(axis=-1) & around[..., h + 1:].any(axis=-1))] = np.nan
    steps = norm3(np.diff(x, axis=0))
    typical_step, _ = running_median(np.vstack([steps, np.full((1, steps.shape[1]), np.nan)]), _STEP_HALF)
    return r - np.maximum(residual_mm, step_factor * np.nan_to_num(typical_step, nan=0.0))


def find_spikes(xyz: np.ndarray, valid: np.ndarray, rate_hz: float, clusters: Sequence[Sequence[int]] = (), *,
                residual_mm: float = 8.0, step_factor: float = 2.0, cluster_mm: float = 5.0,
                max_accel_mm_s2: float = 50.0 * G_MM_S2, min_step_mm: float = 100.0,
                max_piece_s: float = 0.5) -> np.ndarray:
    """Every measured sample either detector rejects: the short pieces :func:`remove_spikes` cuts off at
    implausible accelerations (first: its pieces are runs of the capture as measured), then the glitches of
    :func:`find_glitches` among the rest. (T, M) bool."""
    valid = np.asarray(valid, dtype=bool) & np.isfinite(np.asarray(xyz, dtype=np.float64)).all(axis=2)
    kept, _ = remove_spikes(xyz, valid, rate_hz, max_accel_mm_s2=max_accel_mm_s2, min_step_mm=min_step_mm,
                            max_piece_s=max_piece_s)
    glitch = find_glitches(xyz, kept, clusters, residual_mm=residual_mm, step_factor=step_factor,
                           cluster_mm=cluster_mm)
    return valid & ~(kept & ~glitch)


def _nanmedian(a: np.ndarray, axis: int) -> np.ndarray:
    """The median along ``axis`` of a 2-D array with NaNs left out (NaN for an all-NaN slice: a marker or pair
    never measured): ``np.nanmedian``'s value by one sort (NaN sorts last), without its masked-array path, ten
    times slower on the small arrays of a take. A few slices at a time: the sorted copy is of those only."""
    lines = np.moveaxis(a, axis, -1)
    out = np.empty(lines.shape[0])
    for lo in range(0, lines.shape[0], _MEDIAN_LINES):
        out[lo:lo + _MEDIAN_LINES] = _sorted_median(lines[lo:lo + _MEDIAN_LINES], 1)[0]
    return out


def remove_spikes(xyz: np.ndarray, valid: np.ndarray, rate_hz: float, *,
                  max_accel_mm_s2: float = 50.0 * G_MM_S2, min_step_mm: float = 100.0,
                  max_piece_s: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Turn samples with implausible acceleration into gaps.

    Rule: within each run of consecutive measured samples of a marker, the second difference
    ``|x[t+1] - 2 x[t] + x[t-1]|`` (mm) is implausible when it exceeds
    ``max(max_accel_mm_s2 / rate_hz², min_step_mm)``: 50 g is beyond body-marker accelerations, and the
    displacement floor keeps centimetre jitter of fast cameras (seen in real 240 Hz data, where 50 g is only
    8.5 mm per frame²) from counting. Two consecutive implausible second differences mark a break between
    those samples (a single-sample spike makes two breaks, a jump or sign flip one). The run is cut at the
    breaks; pieces shorter than ``max_piece_s`` become gaps, unless every piece is that short, in which case
    the longest piece is kept.

    Returns
    -------
    valid_new : (T, M) bool.
    n_removed : (M,) int64, samples removed per marker.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool) & np.isfinite(xyz).all(axis=2)
    n_t, n_m = valid.shape
    thr = max(max_accel_mm_s2 / rate_hz ** 2, min_step_mm)
    min_piece = max_piece_s * rate_hz
    out = valid.copy()
    if n_t < 3:
        return out, np.zeros(n_m, dtype=np.int64)
    big = np.zeros((n_t, n_m), dtype=bool)
    for lo in range(1, n_t - 1, _BLOCK_FRAMES):      # in blocks: the differences' temporaries stay small
        hi = min(n_t - 1, lo + _BLOCK_FRAMES)
        d2 = np.linalg.norm(xyz[lo + 1:hi + 1] - 2.0 * xyz[lo:hi] + xyz[lo - 1:hi - 1], axis=2)
        ok3 = valid[lo + 1:hi + 1] & valid[lo:hi] & valid[lo - 1:hi - 1]
        big[lo:hi] = ok3 & (np.nan_to_num(d2, nan=0.0) > thr)
    # break between t-1 and t when the second differences at both are implausible
    brk = np.zeros((n_t, n_m), dtype=bool)
    brk[1:] = big[1:] & big[:-1]
    for m in np.flatnonzero(brk.any(axis=0)):
        v = valid[:, m]
        # piece ids: a new piece starts at every gap→measured transition and at every break
        starts = v & (np.concatenate([[True], ~v[:-1]]) | brk[:, m])
        pid = np.cumsum(starts)
        pid[~v] = 0
        run_id = np.cumsum(v & np.concatenate([[True], ~v[:-1]]))
        run_id[~v] = 0
        sizes = np.bincount(pid)
        for r in np.unique(run_id[brk[:, m] & v]):
            pieces = np.unique(pid[run_id == r])
            lens = sizes[pieces]
            drop = pieces[lens < min_piece]
            if drop.size == pieces.size:
                drop = pieces[pieces != pieces[np.argmax(lens)]]
            out[np.isin(pid, drop) & (run_id == r), m] = False
    return out, (valid & ~out).sum(axis=0).astype(np.int64)
