"""The eyes' delay behind the target, searched together with the camera rotation (SPEC §3.5, step 5).

The eyes follow a moving target about 0.2 s late (Klein's subjects follow a pole that keeps moving), so the gaze
at time t is paired with the target direction at t − lag, carried in world axes (lab, through the character
frame's rotation, where the eyes hold still while the head turns; else character axes) and rotated into the head
axes at t. Pairing with the current target biases the camera rotation by degrees whenever the target keeps
moving.

Every candidate lag of a search step is scored in one batch: the delayed targets are a (L, N, 3) stack, the
fixation rules and the trimmed fits of :mod:`gazepipe.stages.eyes.camera` run on the whole stack, and the lag with
the smallest median residual wins. Whole frames from 0 to ``max_lag_s`` first, then quarter frames around the
best whole frame: two batches per take.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from gazepipe.stages.eyes.camera import (
    CameraEstimate,
    _candidates,
    _robust_fits,
    _row_median,
    camera_to_head,
    estimate_camera_rotation,
    fixation_frames,
)
from gazepipe.stages.eyes.params import EyesParams
from gazepipe.stages.geometry import angle_between, from_wxyz, unit_or_nan

__all__ = ["check_camera_rotation", "estimate_camera_rotation_lagged", "world_targets"]

_QUARTERS = (-0.75, -0.5, -0.25, 0.25, 0.5, 0.75)


def world_targets(head_q: np.ndarray, target_dir_char: np.ndarray, char_rot: np.ndarray | None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: world-from-head rotations as (N, 3, 3) matrices (NaN where undefined) and the target direction
    in world axes (lab when ``char_rot`` is given and finite, else character axes)."""
    n = head_q.shape[0]
    w_head = np.full((n, 3, 3), np.nan)
    tw = np.full((n, 3), np.nan)
    lab = char_rot if char_rot is not None and np.isfinite(char_rot).all(axis=1).any() else None
    c_ok = np.isfinite(lab).all(axis=1) if lab is not None else np.ones(n, dtype=bool)
    ok = np.isfinite(head_q).all(axis=1) & c_ok
    if ok.any():
        r = from_wxyz(head_q[ok])
        if lab is not None:
            r = from_wxyz(lab[ok]) * r
        w_head[ok] = r.as_matrix()
    okt = c_ok & np.isfinite(target_dir_char).all(axis=1)
    if okt.any():
        tw[okt] = from_wxyz(lab[okt]).apply(target_dir_char[okt]) if lab is not None else target_dir_char[okt]
    return w_head, tw


def _delayed(v: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """Directions (N, 3) as they were ``shifts`` (L,) frames earlier (non-negative), (L, N, 3): a whole shift
    moves the rows, a fractional one interpolates between the two frames and renormalises; NaN before the first
    frame."""
    n = v.shape[0]
    out = np.full((len(shifts), n, 3), np.nan)
    i = np.arange(n)
    for j, s in enumerate(np.asarray(shifts, dtype=np.float64)):  # a few lags, each shifted as a whole
        if s == np.floor(s):
            k = int(s)
            out[j, k:] = v[: max(n - k, 0)]
            continue
        pos = i - s
        i0 = np.floor(pos).astype(np.int64)
        f = (pos - i0)[:, None]
        ok = i0 >= 0
        lo, hi = v[i0[ok]], v[np.minimum(i0[ok] + 1, n - 1)]
        out[j, ok] = unit_or_nan((1.0 - f[ok]) * lo + f[ok] * hi)
    return out


def _lagged(w_head: np.ndarray, tw: np.ndarray, shifts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Delayed targets in world axes and in head axes at each frame, both (L, N, 3)."""
    twl = _delayed(tw, shifts)
    # head-from-world is the transpose: th_i = Σ_j w_head[j, i] · twl_j
    th = twl[..., 0:1] * w_head[:, 0, :] + twl[..., 1:2] * w_head[:, 1, :] + twl[..., 2:3] * w_head[:, 2, :]
    return twl, th


def _lag_search(score: Callable[[np.ndarray], np.ndarray], rate_hz: float, max_lag_s: float
                ) -> tuple[float, int, int] | None:
    """The best lag: (lag in seconds, batch, row in the batch), or None when no whole-frame lag scores.

    ``score(shifts)`` scores a batch of shifts (frames) and returns their median residuals (NaN where a shift
    cannot be fitted). Batch 0 is the whole frames 0..max_lag; batch 1 the quarter frames around the best whole
    frame, each replacing the best only when strictly better (in the order −¾ … +¾).
    """
    kmax = max(0, int(np.floor(max_lag_s * rate_hz + 1e-9)))
    res = score(np.arange(kmax + 1, dtype=np.float64))
    if np.isnan(res).all():
        return None
    k = int(np.nanargmin(res))  # the first of equal minima
    lag, best, batch, row = k / rate_hz, float(res[k]), 0, k
    k0 = lag * rate_hz
    near = [k0 + d for d in _QUARTERS if 0.0 <= k0 + d <= kmax]
    if near:
        res2 = score(np.array(near))
        for j, r in enumerate(res2):
            if np.isfinite(r) and r < best:
                lag, best, batch, row = near[j] / rate_hz, float(r), 1, j
    return lag, batch, row


def estimate_camera_rotation_lagged(gaze_cam: np.ndarray, head_rot_char: np.ndarray, target_dir_char: np.ndarray,
                                    rate_hz: float, weights: np.ndarray | None = None, *,
                                    char_rot: np.ndarray | None = None, params: EyesParams | None = None
                                    ) -> tuple[CameraEstimate, float]:
    """Camera → head rotation and the eyes' delay behind the target, fitted together.

    For each lag from 0 to ``max_lag_s`` (whole frames, then quarter frames around the best) the robust fit of
    :func:`~gazepipe.stages.eyes.camera.estimate_camera_rotation` runs on that lag's fixation frames (all lags of
    a step in one batch); the lag with the smallest median residual wins.

    Parameters
    ----------
    gaze_cam : (N, 3) unit gaze in camera axes per mocap frame, NaN where invalid.
    head_rot_char : (N, 4) w, x, y, z head rotation in the character frame.
    target_dir_char : (N, 3) unit direction from the eyes' centre to the target, character frame.
    rate_hz : mocap rate.
    weights : (N,) weights or mask (e.g. the eye validity).
    char_rot : (N, 4) w, x, y, z lab-from-character rotation, optional.

    Returns
    -------
    (:class:`CameraEstimate`, lag in seconds).

    Raises
    ------
    ValueError : no lag gives ``min_fixation_frames`` frames.
    """
    p = params or EyesParams()
    g = np.asarray(gaze_cam, dtype=np.float64)
    w = np.ones(g.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    w_head, tw = world_targets(np.asarray(head_rot_char, dtype=np.float64),
                               np.asarray(target_dir_char, dtype=np.float64),
                               None if char_rot is None else np.asarray(char_rot, dtype=np.float64))
    batches = []

    def score(shifts: np.ndarray) -> np.ndarray:
        twl, th = _lagged(w_head, tw, shifts)
        fits = _robust_fits(g, th, w, _candidates(g, th, w, rate_hz, p, twl), p)
        batches.append((shifts, fits))
        return fits.residual_deg

    found = _lag_search(score, rate_hz, p.max_lag_s)
    if found is None:
        need = max(p.min_fixation_frames, 3)
        raise ValueError(f"only {int(batches[0][1].n_cand[0])} fixation frame(s) with valid gaze and target; "
                         f"need {need}")
    lag, batch, i = found
    shift = batches[batch][0][i]
    # the winner refitted on its own, exactly as a single fit: the batched scores only choose the lag
    twl = _delayed(tw, np.array([shift]))[0]
    th = np.einsum("nji,nj->ni", w_head, twl)
    return estimate_camera_rotation(g, th, weights, rate_hz=rate_hz, params=p, target_dir_world=twl), lag


def check_camera_rotation(gaze_cam: np.ndarray, r_cam: np.ndarray, head_q: np.ndarray, tdir_char: np.ndarray,
                          char_rot: np.ndarray | None, weights: np.ndarray, rate_hz: float, p: EyesParams
                          ) -> tuple[float | None, float | None, int]:
    """Median residual (degrees), eye lag (s) and frames of a configured rotation ``r_cam`` (w, x, y, z) over the
    fixation frames, the lag searched as in :func:`estimate_camera_rotation_lagged`; ``(None, None, 0)`` when
    no lag has enough frames."""
    w_head, tw = world_targets(head_q, tdir_char, char_rot)
    v_head = camera_to_head(gaze_cam, r_cam)
    usable = np.asarray(weights, dtype=bool) & np.isfinite(v_head).all(axis=1)
    need = max(p.min_fixation_frames, 3)
    batches = []

    def score(shifts: np.ndarray) -> np.ndarray:
        twl, th = _lagged(w_head, tw, shifts)
        ok = usable & np.isfinite(th).all(axis=-1) & fixation_frames(gaze_cam, th, rate_hz, p, target_dir_world=twl)
        n_ok = np.count_nonzero(ok, axis=-1)
        ok &= (n_ok >= need)[:, None]
        res = np.rad2deg(_row_median(np.where(ok, angle_between(v_head[None], th), np.nan)))
        batches.append((res, n_ok))
        return res

    found = _lag_search(score, rate_hz, p.max_lag_s)
    if found is None:
        return None, None, 0
    lag, batch, i = found
    res, n_ok = batches[batch]
    return float(res[i]), lag, int(n_ok[i])
