"""Geometry shared by every stage (SPEC §2): 3-vectors and rotations, batched over a leading axis of frames.

Conventions: quaternions are ``w, x, y, z`` (scipy's own order is ``x, y, z, w``; the conversion lives only
here); the 6-number form of a rotation R is its forward vector R·ẑ followed by its up vector R·ŷ (Klein 6.1).
No Python loops over frames. numpy only at import: scipy is imported where a rotation is computed, so planning
a run (which imports the stages' parameters) goes without it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # scipy is imported where it is used: planning a run (no rotation computed) goes without it
    from scipy.spatial.transform import Rotation

_EPS = 1e-12


# ------------------------------------------------------------------------------------------------ vectors

def norm3(v: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis (of length 3): the same result as ``np.linalg.norm(v, axis=-1)``,
    several times faster on many short vectors."""
    sq = v * v
    return np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products over the last axis (length 3) of broadcastable arrays: the same arithmetic as
    ``np.cross`` (so the same bits), without its axis handling, which dominates on short batches."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    np.multiply(a1, b2, out=out[..., 0])
    out[..., 0] -= a2 * b1
    np.multiply(a2, b0, out=out[..., 1])
    out[..., 1] -= a0 * b2
    np.multiply(a0, b1, out=out[..., 2])
    out[..., 2] -= a1 * b0
    return out


def up_vector(up_axis: str) -> np.ndarray:
    """Unit lab vertical for ``up_axis`` ``"y"`` or ``"z"`` (a leading ``-`` flips it)."""
    ax = up_axis.strip().lower()
    sign = -1.0 if ax.startswith("-") else 1.0
    ax = ax.lstrip("+-")
    v = np.zeros(3)
    v["xyz".index(ax)] = sign
    return v


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in radians between vectors (..., 3), robust near 0 and π; NaN where either is NaN."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return angle_from_components(a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2])


def angle_from_components(a0: np.ndarray, a1: np.ndarray, a2: np.ndarray, b0: np.ndarray, b1: np.ndarray,
                          b2: np.ndarray) -> np.ndarray:
    """:func:`angle_between` on the vectors' components. |a × b| and a · b are written out: the same sums as
    np.cross and np.linalg.norm, several times faster."""
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    return np.arctan2(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), a0 * b0 + a1 * b1 + a2 * b2)


def norm_keepdims(v: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis of (..., 3), kept as (..., 1)."""
    x, y, z = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    return np.sqrt(x * x + y * y + z * z)


def unit_or_nan(v: np.ndarray) -> np.ndarray:
    """Unit vectors over the last axis of (..., 3); NaN where the norm is below 1e-12 (or NaN)."""
    n = norm_keepdims(v)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > _EPS, v / n, np.nan)


# ---------------------------------------------------------------------------------------------- rotations


def to_wxyz(rot: Rotation) -> np.ndarray:
    """Quaternions ``w, x, y, z`` of ``rot``, canonical (w ≥ 0), shape (N, 4) or (4,)."""
    return rot.as_quat(canonical=True, scalar_first=True)


def from_wxyz(q: np.ndarray) -> Rotation:
    """Rotation from quaternions ``w, x, y, z`` (normalised on the way), shape (..., 4)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(np.asarray(q, dtype=np.float64), scalar_first=True)


def mean_wxyz(q: np.ndarray, min_count: int = 1) -> np.ndarray | None:
    """``Rotation.mean`` of the known (finite) quaternions among ``q`` (n, 4) wxyz, as (4,) wxyz; None when
    fewer than ``min_count`` are known."""
    ok = np.isfinite(q).all(axis=1)
    if ok.sum() < max(min_count, 1):
        return None
    return np.asarray(to_wxyz(from_wxyz(q[ok]).mean())).reshape(4)


def six_from_matrix(m: np.ndarray) -> np.ndarray:
    """6-number form of rotation matrices (..., 3, 3): forward R·ẑ then up R·ŷ, shape (..., 6)."""
    m = np.asarray(m, dtype=np.float64)
    return np.concatenate([m[..., :, 2], m[..., :, 1]], axis=-1)


def six_from_rotation(rot: Rotation) -> np.ndarray:
    """6-number form (forward R·ẑ, then up R·ŷ) of ``rot``, shape (N, 6) or (6,)."""
    return six_from_matrix(rot.as_matrix())


def matrix_from_six(six: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from the 6-number form (forward, up), not necessarily orthonormal.

    Gram–Schmidt: forward is kept (normalised), up is made orthogonal to it, left = up × forward.
    """
    six = np.asarray(six, dtype=np.float64)
    fwd = six[..., 0:3]
    up = six[..., 3:6]
    z = fwd / np.linalg.norm(fwd, axis=-1, keepdims=True)
    y = up - np.sum(up * z, axis=-1, keepdims=True) * z
    y = y / np.linalg.norm(y, axis=-1, keepdims=True)
    x = cross3(y, z)
    return np.stack([x, y, z], axis=-1)


def rotation_from_six(six: np.ndarray) -> Rotation:
    """Rotation from the 6-number form (see :func:`matrix_from_six`)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(matrix_from_six(six))


def slerp_vectors(p: np.ndarray, q: np.ndarray, f: np.ndarray, *, antipodal: str = "first") -> np.ndarray:
    """Spherical interpolation of unit vectors: the point a fraction ``f`` along the great arc from p to q.

    Parameters
    ----------
    p, q : (N, 3) unit vectors.
    f : (N,) fractions (0 gives p, 1 gives q).
    antipodal : what a pair with no unique arc (p = −q) gives: ``"first"``, p; ``"nan"``, NaN.

    The arc is the rotation about p × q by f times the angle between them; identical vectors give p. Rows with
    a non-finite input give NaN.
    """
    from scipy.spatial.transform import Rotation

    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    f = np.asarray(f, dtype=np.float64)
    if antipodal not in ("first", "nan"):
        raise ValueError(f"antipodal must be 'first' or 'nan', not {antipodal!r}")
    out = np.full(p.shape, np.nan)
    axis = cross3(p, q)
    s = np.linalg.norm(axis, axis=1)
    c = np.sum(p * q, axis=1)
    ang = np.arctan2(s, c)
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = np.where((s > _EPS)[:, None], axis / s[:, None], 0.0)
    rotvec = axis * (f * ang)[:, None]
    ok = np.isfinite(rotvec).all(axis=1) & np.isfinite(p).all(axis=1)
    if antipodal == "nan":
        ok &= ~((s <= _EPS) & (c < 0))
    if ok.any():
        out[ok] = Rotation.from_rotvec(rotvec[ok]).apply(p[ok])
    return out


def frame_from_points(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Orthonormal frames (N, 3, 3) from three points per frame, (N, 3) each, by Gram–Schmidt.

    Columns: e1 along the edge p1 − p0, e3 along the plane normal (p1 − p0) × (p2 − p0), e2 = e3 × e1.
    Degenerate (collinear or coincident) points give NaN.
    """
    a = np.asarray(p1, dtype=np.float64) - p0
    b = np.asarray(p2, dtype=np.float64) - p0
    n = cross3(a, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        e1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
        nn = np.linalg.norm(n, axis=-1, keepdims=True)
        e3 = np.where(nn > _EPS, n / nn, np.nan)
    e2 = cross3(e3, e1)
    return np.stack([e1, e2, e3], axis=-1)


def det3(m: np.ndarray) -> np.ndarray:
    """Determinants of (..., 3, 3) matrices by the triple product of their rows (no LU per matrix)."""
    return np.einsum("...i,...i->...", m[..., 0, :], cross3(m[..., 1, :], m[..., 2, :]))


def kabsch(ref: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Least-squares rotations (N, 3, 3) with pts[n] − centroid ≈ R[n] · (ref[n] − centroid(ref[n])).

    Parameters
    ----------
    ref : (K, 3) reference cluster shared by every frame, or (N, K, 3) one per frame (any origin).
    pts : (N, K, 3) observed clusters, same marker order; every marker must be finite.

    Batched SVD over frames (Kabsch; the sign correction keeps det R = +1).
    """
    ref = np.asarray(ref, dtype=np.float64)
    pts = np.asarray(pts, dtype=np.float64)
    b = pts - pts.mean(axis=1, keepdims=True)
    if ref.ndim == 2:
        h = (ref - ref.mean(axis=0)).T @ b        # cross-covariance, (N, 3, 3)
    else:
        h = np.swapaxes(ref - ref.mean(axis=1, keepdims=True), 1, 2) @ b
    u, _, vt = np.linalg.svd(h)
    v = vt.transpose(0, 2, 1)
    d = np.sign(det3(v) * det3(u))
    d[d == 0] = 1.0
    v[:, :, 2] *= d[:, None]
    return v @ u.transpose(0, 2, 1)


def heading_frames(left_raw: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Lab-from-character rotation matrices (N, 3, 3) from a raw left vector per frame (N, 3).

    Columns: +X left = horizontal part of ``left_raw`` (normalised), +Y = ``up``, +Z forward = left × up.
    Frames where the left vector has no horizontal part (or is NaN) give NaN.
    """
    left = left_raw - (left_raw @ up)[:, None] * up
    with np.errstate(invalid="ignore", divide="ignore"):
        nl = np.linalg.norm(left, axis=1, keepdims=True)
        left = np.where(nl > _EPS, left / nl, np.nan)
    upb = np.broadcast_to(up, left.shape)
    fwd = cross3(left, upb)
    return np.stack([left, upb, fwd], axis=-1)
