"""The eyes stage's axes (SPEC §3.5, Klein 9): camera → head → character frame, and the camera rotation fitted
from the frames where the gaze rests on the target.

Axes. OpenFace's camera: x right, y down, z forward (out of the lens). The head segment: X the subject's left,
Y up, Z forward (out of the face). A head-mounted camera in front of the face looks back at it, so:

- camera z (away from the lens, into the face) is head −Z: a subject looking into the lens gives (0, 0, −1) in
  camera axes and must give head forward (0, 0, 1);
- camera x (image right) is the subject's left, head +X (the image's left shows the subject's right eye, which
  is why OpenFace's ``gaze_0`` is the right eye);
- camera y (image down) is head −Y.

So R = diag(1, −1, −1): the 180° rotation about the head's Y axis (diag(−1, 1, −1), turning the camera round to
face the subject) composed with the 180° rotation about the optical axis that flips x and y (diag(−1, −1, 1),
image axes "right, down" to "left, up"): Ry(180°) · Rz(180°) = diag(1, −1, −1) = Rx(180°), quaternion
(w, x, y, z) = (0, 1, 0, 0), :data:`CAMERA_FACING_FACE`. A real mount adds its tilt and turn: R = R_mount · that.

The fixation rules and the robust fit work on a stack of target series at once (one per candidate eye lag, see
:mod:`gazepipe.stages.eyes.lag`): the gaze's own speed is computed once, and every fit is a batched Kabsch
solution (one SVD per candidate) rather than a Rotation object per fit.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.stages.eyes.params import EyesParams
from gazepipe.stages.geometry import angle_between, angle_from_components, from_wxyz, to_wxyz, unit_or_nan

__all__ = ["CAMERA_FACING_FACE", "CameraEstimate", "camera_to_character", "camera_to_head",
           "combine_camera_estimates", "estimate_camera_rotation", "fixation_frames", "head_to_character"]

#: camera → head rotation (w, x, y, z) of a camera straight in front of the face looking back at it
CAMERA_FACING_FACE = np.array([0.0, 1.0, 0.0, 0.0])


class CameraEstimate(NamedTuple):
    """Result of :func:`estimate_camera_rotation`.

    quat : (4,) w, x, y, z rotation from camera axes to head axes (v_head = R · v_cam).
    residual_deg : median angle between the rotated gaze and the target direction over the fixation frames.
    n_used : frames in the final (trimmed) fit.
    """

    quat: np.ndarray
    residual_deg: float
    n_used: int



# ---------------------------------------------------------------------------------------------------------------
# axes


def camera_to_head(gaze_cam: np.ndarray, r_cam_to_head: np.ndarray) -> np.ndarray:
    """Directions (N, 3) from camera axes to head axes: v_head = R · v_cam (R as w, x, y, z); NaN stays NaN."""
    v = np.asarray(gaze_cam, dtype=np.float64)
    return from_wxyz(r_cam_to_head).as_matrix().dot(v.T).T if v.size else v.reshape(-1, 3).copy()


def head_to_character(v_head: np.ndarray, head_rot_char: np.ndarray) -> np.ndarray:
    """Directions (N, 3) from head axes to the character frame: v_char = R_head · v_head per frame.

    ``head_rot_char`` (N, 4) w, x, y, z is the head segment's rotation in the character frame; rows where it or
    the vector is not finite give NaN.
    """
    v = np.asarray(v_head, dtype=np.float64)
    q = np.asarray(head_rot_char, dtype=np.float64)
    out = np.full(v.shape, np.nan)
    ok = np.isfinite(v).all(axis=1) & np.isfinite(q).all(axis=1)
    if ok.any():
        out[ok] = from_wxyz(q[ok]).apply(v[ok])
    return out


def camera_to_character(gaze_cam: np.ndarray, r_cam_to_head: np.ndarray, head_rot_char: np.ndarray) -> np.ndarray:
    """Directions (N, 3) from camera axes into the character frame: v_char = R_head · R · v_cam.

    Parameters
    ----------
    gaze_cam : (N, 3) unit vectors in OpenFace camera axes (x right, y down, z forward).
    r_cam_to_head : (4,) w, x, y, z camera → head rotation (see the module docstring for the worked example of
        a camera in front of the face: :data:`CAMERA_FACING_FACE`).
    head_rot_char : (N, 4) w, x, y, z head rotation in the character frame.
    """
    return head_to_character(camera_to_head(gaze_cam, r_cam_to_head), head_rot_char)



# ---------------------------------------------------------------------------------------------------------------
# fixation frames


def _smooth_dirs(v: np.ndarray, k: int) -> np.ndarray:
    """Centred moving average of unit vectors (..., N, 3) over k frames along N, renormalised; NaN if any in the
    window is NaN."""
    if k <= 1:
        return v
    from scipy.ndimage import uniform_filter1d  # here: planning a run imports this module, not scipy.ndimage

    ok = np.isfinite(v).all(axis=-1)
    vz = np.where(ok[..., None], v, 0.0)
    s = uniform_filter1d(vz, k, axis=-2, mode="constant", cval=0.0)
    cnt = uniform_filter1d(ok.astype(np.float64), k, axis=-1, mode="constant", cval=0.0)
    return np.where((cnt > 1.0 - 1e-9)[..., None], unit_or_nan(s), np.nan)


def _angular_speed(v: np.ndarray, rate_hz: float) -> np.ndarray:
    """Angular speed in degrees per second of direction series (..., N, 3), central differences; NaN at the
    ends."""
    out = np.full(v.shape[:-1], np.nan)
    if v.shape[-2] >= 3:
        out[..., 1:-1] = np.rad2deg(angle_between(v[..., 2:, :], v[..., :-2, :])) * rate_hz / 2.0
    return out


def _odd(x: float) -> int:
    k = max(1, int(round(x)))
    return k if k % 2 else k + 1


def fixation_frames(gaze_cam: np.ndarray, target_dir_head: np.ndarray, rate_hz: float,
                    params: EyesParams | None = None, *, target_dir_world: np.ndarray | None = None) -> np.ndarray:
    """Frames (N,) bool where the gaze plausibly rests on the target (for the camera-rotation fit).

    Speeds come from directions smoothed over ``smooth_s``. A frame qualifies when the gaze (camera axes) moves
    slower than ``max_gaze_speed_deg_s`` (no saccade), the target (``target_dir_world``, else head axes) slower
    than ``max_target_speed_deg_s`` and not faster at any time in the last ``settle_s``, and the target lies
    within ``max_eccentricity_deg`` of the head's forward axis (+Z).

    The targets may be stacked, (L, N, 3) (one series per candidate lag): the result is then (L, N).
    """
    p = params or EyesParams()
    g = np.asarray(gaze_cam, dtype=np.float64)
    th = np.asarray(target_dir_head, dtype=np.float64)
    tw = th if target_dir_world is None else np.asarray(target_dir_world, dtype=np.float64)
    n = g.shape[0]
    if n == 0:
        return np.zeros(th.shape[:-1], dtype=bool)
    k = _odd(p.smooth_s * rate_hz)
    sg = _angular_speed(_smooth_dirs(g, k), rate_hz)
    st = _angular_speed(_smooth_dirs(tw, k), rate_hz)
    idx = np.arange(n)
    moving = ~(st <= p.max_target_speed_deg_s)            # NaN counts as moving
    last_move = np.maximum.accumulate(np.where(moving, idx, -n - 1), axis=-1)
    settled = (idx - last_move) > p.settle_s * rate_hz
    with np.errstate(invalid="ignore"):
        central = th[..., 2] >= np.cos(np.deg2rad(p.max_eccentricity_deg))
    return (sg <= p.max_gaze_speed_deg_s) & settled & central


# ---------------------------------------------------------------------------------------------------------------
# camera rotation


def _kabsch(target: np.ndarray, gaze: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Rotation matrices (L, 3, 3) minimising Σ w ‖target − R · gaze‖² per stack (weighted Wahba / Kabsch).

    target (3, L, N) by component and weights (L, N) (zero where a frame is left out; its target must then be
    finite), gaze (N, 3) shared by every stack.
    """
    b = np.moveaxis((weights[None] * target) @ gaze, 0, 1)  # (L, 3, 3): Σ_n w t gᵀ
    u, _, vh = np.linalg.svd(b)
    flip = np.linalg.det(u @ vh) < 0                    # a reflection: flip the weakest axis
    u[flip, :, -1] *= -1.0
    return u @ vh


def _rotated_error(rot: np.ndarray, gaze: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Angle (L, N) radians between R_l · gaze_n and target (3, L, N) by component."""
    r = rot @ gaze.T                                     # (L, 3, N)
    return angle_from_components(r[:, 0], r[:, 1], r[:, 2], target[0], target[1], target[2])


def _sorted_rows(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of x (L, N) sorted with their NaNs last, the count of numbers per row, and the row indices."""
    return np.sort(x, axis=-1), np.count_nonzero(~np.isnan(x), axis=-1), np.arange(x.shape[0])


def _row_percentile(x: np.ndarray, q: float) -> np.ndarray:
    """Per row of x (L, N), the ``q`` percentile of its numbers (NaN = absent); exactly np.percentile's linear
    method on each row's numbers, without a Python call per row. Rows need at least one number."""
    s, n, rows = _sorted_rows(x)
    v = (n - 1) * (q / 100.0)
    lo = np.floor(v)
    t = v - lo
    top = v >= n - 1
    a = s[rows, np.where(top, n - 1, lo).astype(np.intp)]
    b = s[rows, np.where(top, n - 1, lo + 1).astype(np.intp)]
    d = b - a
    return np.where(t >= 0.5, b - d * (1 - t), a + d * t)


def _row_median(x: np.ndarray) -> np.ndarray:
    """Per row of x (L, N), the median of its numbers (NaN = absent), as np.median; NaN for a row without any."""
    s, n, rows = _sorted_rows(x)
    half = np.maximum(n, 1) // 2
    lo = s[rows, np.where(n % 2 == 1, half, half - 1)]
    hi = s[rows, half]
    return np.where(n > 0, np.where(n % 2 == 1, hi, (lo + hi) / 2), np.nan)


class _Fits(NamedTuple):
    """Robust fits of a stack of L target series: rotation matrices (L, 3, 3), median residual in degrees (L,)
    (NaN where the fit was not possible), frames in the final fit (L,), candidate frames (L,)."""

    rot: np.ndarray
    residual_deg: np.ndarray
    n_used: np.ndarray
    n_cand: np.ndarray


def _robust_fits(gaze: np.ndarray, target: np.ndarray, weights: np.ndarray, cand: np.ndarray,
                 p: EyesParams) -> _Fits:
    """:func:`estimate_camera_rotation`'s trimmed fit for L target series at once, to score candidate lags (its
    Kabsch solution may differ from ``Rotation.align_vectors`` in the last bits; the winner is refitted by
    :func:`estimate_camera_rotation`).

    gaze (N, 3) finite where ``cand``; target (L, N, 3) finite where ``cand`` (L, N); weights (N,). Each stack
    follows the single fit step for step: fit on its kept frames, then up to ``refit_iterations`` times keep the
    candidates whose error is at most the ``keep_percentile`` percentile, stopping when fewer than three remain or
    the set does not change.
    """
    n_cand = np.count_nonzero(cand, axis=-1)
    ok = n_cand >= max(p.min_fixation_frames, 3)
    g = np.where(np.any(cand, axis=0)[:, None], gaze, 0.0)
    t = np.ascontiguousarray(np.moveaxis(np.where(cand[..., None], target, 0.0), -1, 0))  # (3, L, N)
    w = np.where(cand, weights[None, :], 0.0)
    rot = np.broadcast_to(np.eye(3), (cand.shape[0], 3, 3)).copy()
    keep = cand.copy()
    rows = np.flatnonzero(ok)                            # the stacks still being refitted
    for it in range(p.refit_iterations + 1):
        if rows.size == 0:
            break
        t_rows = t[:, rows] if rows.size < cand.shape[0] else t
        rot[rows] = _kabsch(t_rows, g, np.where(keep[rows], w[rows], 0.0))
        if it == p.refit_iterations:
            break
        err = np.where(cand[rows], _rotated_error(rot[rows], g, t_rows), np.nan)
        cut = _row_percentile(err, p.keep_percentile)
        new = err <= cut[:, None]
        stop = (np.count_nonzero(new, axis=-1) < 3) | np.all(new == keep[rows], axis=-1)
        keep[rows[~stop]] = new[~stop]
        rows = rows[~stop]
    err = np.where(cand & ok[:, None], _rotated_error(rot, g, t), np.nan)
    residual = np.rad2deg(_row_median(err))
    return _Fits(rot, residual, np.count_nonzero(keep, axis=-1), n_cand)


def _candidates(gaze: np.ndarray, target_head: np.ndarray, weights: np.ndarray, rate_hz: float | None,
                p: EyesParams, target_world: np.ndarray | None) -> np.ndarray:
    """Frames (..., N) with finite gaze and target and a positive weight, restricted to the fixation frames when
    ``rate_hz`` is given."""
    cand = (np.isfinite(gaze).all(axis=-1) & np.isfinite(target_head).all(axis=-1) & np.isfinite(weights)
            & (weights > 0))
    if rate_hz is not None:
        cand &= fixation_frames(gaze, target_head, rate_hz, p, target_dir_world=target_world)
    return cand


def estimate_camera_rotation(gaze_cam: np.ndarray, target_dir_head: np.ndarray,
                             weights: np.ndarray | None = None, *, rate_hz: float | None = None,
                             params: EyesParams | None = None,
                             target_dir_world: np.ndarray | None = None) -> CameraEstimate:
    """Least-squares camera → head rotation from gaze and target directions while the gaze rests on the target.

    Parameters
    ----------
    gaze_cam : (N, 3) unit gaze vectors in camera axes, per mocap frame (NaN where invalid).
    target_dir_head : (N, 3) unit vectors from the eyes' centre (head centre, never the head markers' centroid:
        SPEC §3.5) to the target, in head axes.
    weights : (N,) non-negative weights or a bool mask; zero / False leaves a frame out. Default: all ones.
    rate_hz : the frames' rate; when given, frames are further restricted to :func:`fixation_frames`.
    params : :class:`EyesParams` (fixation rules, trimming, minimum frames).
    target_dir_world : (N, 3) the target direction in lab or character axes, for the target-speed rule of
        :func:`fixation_frames` (default: head axes).

    Returns
    -------
    :class:`CameraEstimate` (quaternion w, x, y, z with target ≈ R · gaze; the median residual angle in degrees
    over all candidate frames under the final rotation; the frames in the final fit).

    Method: ``Rotation.align_vectors`` (weighted Wahba / Kabsch) on the candidates, then ``refit_iterations``
    times: keep the candidates whose error is at most the ``keep_percentile`` percentile and re-fit. This drops
    frames where the eyes had not yet arrived, blinks that slipped through, and OpenFace outliers.

    Raises
    ------
    ValueError : fewer than ``min_fixation_frames`` candidate frames.
    """
    p = params or EyesParams()
    g = np.asarray(gaze_cam, dtype=np.float64)
    tdir = np.asarray(target_dir_head, dtype=np.float64)
    w = np.ones(g.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    cand = _candidates(g, tdir, w, rate_hz, p, target_dir_world)
    n_cand = int(np.count_nonzero(cand))
    need = max(p.min_fixation_frames, 3)
    if n_cand < need:
        raise ValueError(f"only {n_cand} fixation frame(s) with valid gaze and target; need {need}")
    gi, ti, wi = g[cand], tdir[cand], w[cand]
    keep = np.ones(n_cand, dtype=bool)
    rot = Rotation.identity()
    for it in range(p.refit_iterations + 1):
        rot, _ = Rotation.align_vectors(ti[keep], gi[keep], weights=wi[keep])
        if it == p.refit_iterations:
            break
        err = angle_between(rot.apply(gi), ti)
        new = err <= np.percentile(err, p.keep_percentile)
        if np.count_nonzero(new) < 3 or np.array_equal(new, keep):
            break
        keep = new
    err = angle_between(rot.apply(gi), ti)
    return CameraEstimate(quat=to_wxyz(rot), residual_deg=float(np.rad2deg(np.median(err))),
                          n_used=int(np.count_nonzero(keep)))


def combine_camera_estimates(quats: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """One camera rotation for a session from per-take estimates (the camera does not move between takes).

    Parameters
    ----------
    quats : (K, 4) w, x, y, z estimates, e.g. from the session's ``gaze_follow`` takes.
    weights : (K,) e.g. each estimate's ``n_used``; default equal.

    Returns
    -------
    (quaternion w, x, y, z of the weighted mean rotation (``Rotation.mean``), the largest angle in degrees
    between an estimate and that mean: a check that the takes agree).
    """
    r = from_wxyz(np.atleast_2d(np.asarray(quats, dtype=np.float64)))
    mean = r.mean(weights=None if weights is None else np.asarray(weights, dtype=np.float64))
    return to_wxyz(mean), float(np.rad2deg(np.max((r * mean.inv()).magnitude())))


def _target_spread_deg(v: np.ndarray) -> float:
    """RMS angle of directions (N, 3) from their normalised mean, degrees."""
    m = unit_or_nan(v.mean(axis=0))
    return float(np.rad2deg(np.sqrt(np.mean(angle_between(v, m[None, :]) ** 2))))

