"""The filler's model candidates compiled: the PCA models' moving-frame coordinates and least-squares
predictions, and the rigid-cluster fill, frame by frame, where numpy's per-call cost on a gap's few frames
outweighed the arithmetic.

Unlike :mod:`gazepipe.stages.clean.kernels`, these do not reproduce numpy's bits: a frame's coordinates in the
moving frame are plain three-term sums (BLAS's small products before); each occlusion pattern's PCA fit is a
Householder QR of the pattern's own rows with the target mapped through R by substitution (LAPACK's QR of the
masked matrix and an explicit inverse of R before); a rigid fit's rotation is Horn's closed form per frame and
reference (:mod:`gazepipe.stages.rotation_kernels`; a batched Kabsch SVD before). The results are the same solutions to the rounding of the arithmetic
(~1e-11 mm on positions of ~1e3 mm).

Compiled as :mod:`gazepipe.stages.jit` says; imported where a model is first fitted. Positions are float64 mm,
frames are rows, intervals half-open.
"""

from __future__ import annotations

import numpy as np

from gazepipe.stages.jit import kernel
from gazepipe.stages.rotation_kernels import horn_rotation

_EPS = 1e-12                 # a triangle's normal shorter than this leaves its frame undefined (NaN), as geometry's
_GOOD_DIAG = 1e-8            # a column of R counts while |R_jj| exceeds this fraction of the largest


@kernel
def _triad(p: np.ndarray, i0: int, i1: int, i2: int, rot: np.ndarray, c: np.ndarray) -> None:
    """The Gram–Schmidt frame of points ``p[i0], p[i1], p[i2]`` (rows of ``p`` (K, 3)) into ``rot`` (3, 3)
    (columns: e1 along the first edge, e2, e3 along the normal; NaN when the points are collinear) and their
    centroid into ``c`` (3,): :func:`gazepipe.stages.geometry.frame_from_points`."""
    a0, a1, a2 = p[i1, 0] - p[i0, 0], p[i1, 1] - p[i0, 1], p[i1, 2] - p[i0, 2]
    b0, b1, b2 = p[i2, 0] - p[i0, 0], p[i2, 1] - p[i0, 1], p[i2, 2] - p[i0, 2]
    n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    la = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    e10, e11, e12 = a0 / la, a1 / la, a2 / la
    if nn > _EPS:
        e30, e31, e32 = n0 / nn, n1 / nn, n2 / nn
    else:
        e30 = e31 = e32 = np.nan
    rot[0, 0], rot[1, 0], rot[2, 0] = e10, e11, e12
    rot[0, 1], rot[1, 1], rot[2, 1] = e31 * e12 - e32 * e11, e32 * e10 - e30 * e12, e30 * e11 - e31 * e10
    rot[0, 2], rot[1, 2], rot[2, 2] = e30, e31, e32
    for j in range(3):
        c[j] = (p[i0, j] + p[i1, j] + p[i2, j]) / 3.0


@kernel
def _local_row(p: np.ndarray, rot: np.ndarray, c: np.ndarray, out: np.ndarray) -> None:
    """Points ``p`` (K, 3) in the frame ``rot`` at ``c``: ``out[k] = rotᵀ (p[k] − c)``."""
    for k in range(p.shape[0]):
        d0, d1, d2 = p[k, 0] - c[0], p[k, 1] - c[1], p[k, 2] - c[2]
        for j in range(3):
            out[k, j] = d0 * rot[0, j] + d1 * rot[1, j] + d2 * rot[2, j]


@kernel
def local_coords(x: np.ndarray, pick: np.ndarray) -> np.ndarray:
    """Points ``x`` (n, K, 3) in each frame's moving frame of its points ``pick`` (3 indices into K), (n, K, 3)."""
    out = np.empty_like(x)
    rot = np.empty((3, 3))
    c = np.empty(3)
    for f in range(x.shape[0]):
        _triad(x[f], pick[0], pick[1], pick[2], rot, c)
        _local_row(x[f], rot, c, out[f])
    return out


@kernel
def training_coords(xt: np.ndarray, picks: np.ndarray, body_frame: bool) -> np.ndarray:
    """Each model's coordinates of the training positions ``xt`` (n, K, 3), (len(picks), n, 3 K): in the moving
    frame of the model's three points (a row of ``picks``), or, for a row of -1s, relative to the mean of the
    predictors (all but the last point) with ``body_frame``, else as they are (the lab frame)."""
    n, n_k = xt.shape[0], xt.shape[1]
    out = np.empty((picks.shape[0], n, 3 * n_k))
    for i in range(picks.shape[0]):
        if picks[i, 0] >= 0:
            out[i] = local_coords(xt, picks[i]).reshape(n, 3 * n_k)
            continue
        for f in range(n):
            for j in range(3):
                centre = 0.0
                if body_frame:
                    for k in range(n_k - 1):
                        centre += xt[f, k, j]
                    centre /= n_k - 1
                for k in range(n_k):
                    out[i, f, 3 * k + j] = xt[f, k, j] - centre
    return out


@kernel
def centred_weighted(coords: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each model's coordinate means over the training frames (F, C) and its centred, weighted coordinates
    ``(coords − mean) · weights`` (F, n, C), from ``coords`` (F, n, C) and ``weights`` (F, C)."""
    n_m, n, n_c = coords.shape
    mean = np.zeros((n_m, n_c))
    for i in range(n_m):
        for f in range(n):
            for c in range(n_c):
                mean[i, c] += coords[i, f, c]
        for c in range(n_c):
            mean[i, c] /= n
    z = np.empty_like(coords)
    for i in range(n_m):
        for f in range(n):
            for c in range(n_c):
                z[i, f, c] = (coords[i, f, c] - mean[i, c]) * weights[i, c]
    return mean, z


@kernel
def _pattern_keys(seen: np.ndarray) -> np.ndarray:
    """Each row of ``seen`` (n, P ≤ 62) as an integer (bit p set where predictor p is measured)."""
    keys = np.zeros(seen.shape[0], dtype=np.int64)
    for f in range(seen.shape[0]):
        key = np.int64(0)
        for p in range(seen.shape[1]):
            if seen[f, p]:
                key |= np.int64(1) << p
        keys[f] = key
    return keys


@kernel
def _householder(a: np.ndarray, tau: np.ndarray) -> None:
    """Householder QR of ``a`` (m, k) in place: R in its upper triangle, the reflector of column j below its
    diagonal with an implicit leading 1 (LAPACK's layout, ``H_j = I − tau_j v vᵀ``), ``tau`` (min(m, k),)."""
    m, k = a.shape
    for j in range(min(m, k)):
        scale = 0.0
        for i in range(j, m):
            scale = max(scale, abs(a[i, j]))
        if scale == 0.0:
            tau[j] = 0.0
            continue
        ss = 0.0
        for i in range(j, m):
            ss += (a[i, j] / scale) ** 2
        norm = scale * np.sqrt(ss)
        alpha = -norm if a[j, j] >= 0.0 else norm
        v0 = a[j, j] - alpha
        for i in range(j + 1, m):
            a[i, j] /= v0
        tau[j] = -v0 / alpha
        a[j, j] = alpha
        for col in range(j + 1, k):
            _reflect(a, j, tau[j], a, col)


@kernel
def _form_q(a: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """The first ``tau.size`` columns of Q (m, tau.size), the product of :func:`_householder`'s reflectors in
    ``a``, applied to the identity's columns from the last reflector to the first."""
    m, kk = a.shape[0], tau.size
    q = np.zeros((m, kk))
    for i in range(kk):
        q[i, i] = 1.0
    for j in range(kk - 1, -1, -1):
        if tau[j] == 0.0:
            continue
        for col in range(j, kk):
            _reflect(a, j, tau[j], q, col)
    return q


@kernel
def _reflect(a: np.ndarray, j: int, tau_j: float, c: np.ndarray, col: int) -> None:
    """Column ``col`` of ``c`` ← H_j times it, H_j = I − tau_j v vᵀ the reflector stored below the diagonal of
    column j of ``a`` (implicit leading 1). ``c`` may be ``a`` itself for a column other than j."""
    s = c[j, col]
    for i in range(j + 1, a.shape[0]):
        s += a[i, j] * c[i, col]
    s *= tau_j
    c[j, col] -= s
    for i in range(j + 1, a.shape[0]):
        c[i, col] -= s * a[i, j]


@kernel
def _good_columns(a: np.ndarray, k_top: int) -> int:
    """How many leading columns of R (in ``a``'s upper triangle) are resolved: the first j with |R_jj| at most
    ``_GOOD_DIAG`` of the largest |R_jj| (columns past R's rows are unresolved)."""
    kk = min(a.shape[0], k_top)
    top = 1e-300
    for j in range(kk):
        top = max(top, abs(a[j, j]))
    for j in range(kk):
        if not abs(a[j, j]) > _GOOD_DIAG * top:
            return j
    return kk


@kernel
def _target_maps(a: np.ndarray, target: np.ndarray, n_good: int) -> np.ndarray:
    """``M`` (3, n_good) with M R[:n_good, :n_good] = ``target[:, :n_good]`` (forward substitution; R in ``a``'s
    upper triangle). Column i depends only on columns up to i, so ``M[:, :k]`` is the map for the first k
    components: target = M[:, :k] (Qᵀ z)[:k]."""
    maps = np.empty((target.shape[0], n_good))
    for j in range(target.shape[0]):
        for i in range(n_good):
            s = target[j, i]
            for col in range(i):
                s -= maps[j, col] * a[col, i]
            maps[j, i] = s / a[i, i]
    return maps


@kernel
def _body_centres(x: np.ndarray, seen: np.ndarray, mean: np.ndarray, n_seen: np.ndarray) -> np.ndarray:
    """Each frame's mean trajectory of the measured predictors, shifted by the training offset between their
    centroid and all predictors' centroid: (Σ measured x − Σ measured training means) / count, (n, 3)."""
    n, n_p = seen.shape
    ctr = np.zeros((n, 3))
    for f in range(n):
        for j in range(3):
            s, t = 0.0, 0.0
            for p in range(n_p):
                if seen[f, p]:
                    s += x[f, p, j]
                    t += mean[3 * p + j]
            ctr[f, j] = (s - t) / n_seen[f]
    return ctr


@kernel
def predict(pts: np.ndarray, seen_in: np.ndarray, pick: np.ndarray, body_frame: bool, mean: np.ndarray,
            w: np.ndarray, v_all: np.ndarray, ks: np.ndarray, residuals: bool) -> tuple[np.ndarray, np.ndarray]:
    """One PCA model's prediction of its target in each frame, for each component count in ``ks``.

    Parameters
    ----------
    pts, seen_in : (n, P, 3) predictor positions (mm) and (n, P) whether each is measured, per frame.
    pick : the model's three moving-frame predictors (indices into P), or an empty array for none; a frame
        without all three is not predicted.
    body_frame : positions relative to the measured predictors' mean (shifted by the training offset).
    mean, w : (3 P + 3,) the training mean and weight of each coordinate (predictors', then the target's).
    v_all : (3 P + 3, k_top) the components, largest first.
    ks : component counts.
    residuals : whether to compute ``res`` (NaN throughout otherwise).

    Returns
    -------
    out : (len(ks), n, 3) target positions, NaN where a frame's measured predictors resolve fewer than k
        components (or the frame is not predicted).
    res : (len(ks), n) RMS residual of each frame's fit to its weighted predictor coordinates (NaN likewise, and
        throughout without ``residuals``).
    """
    n, n_p = seen_in.shape
    n_pc = 3 * n_p
    seen = seen_in.copy()
    x = pts.copy()
    rots = np.zeros((n, 3, 3))
    origins = np.zeros((n, 3))
    if pick.size:
        stand_in = np.eye(3) * 100.0
        for f in range(n):
            if not (seen[f, pick[0]] and seen[f, pick[1]] and seen[f, pick[2]]):
                seen[f, :] = False
                _triad(stand_in, 0, 1, 2, rots[f], origins[f])
            else:
                _triad(pts[f], pick[0], pick[1], pick[2], rots[f], origins[f])
            _local_row(pts[f], rots[f], origins[f], x[f])
    n_seen = np.zeros(n, dtype=np.int64)
    for f in range(n):
        for p in range(n_p):
            n_seen[f] += seen[f, p]
    ctr = _body_centres(x, seen, mean, n_seen) if body_frame else np.zeros((n, 3))
    out = np.full((ks.size, n, 3), np.nan)
    res = np.full((ks.size, n), np.nan)
    keys = _pattern_keys(seen)
    order = np.argsort(keys, kind="mergesort")
    start = 0
    while start < n:
        stop = start + 1
        while stop < n and keys[order[stop]] == keys[order[start]]:
            stop += 1
        _predict_pattern(x, seen, ctr, rots, origins, pick.size > 0, mean, w, v_all, ks, n_seen,
                         order[start:stop], n_pc, residuals, out, res)
        start = stop
    return out, res


@kernel
def _measured_coords(seen_row: np.ndarray) -> np.ndarray:
    """The coordinate indices (3 p + axis) of the predictors measured in a row of ``seen``."""
    sel = np.empty(3 * seen_row.size, dtype=np.int64)
    m_sel = 0
    for p in range(seen_row.size):
        if seen_row[p]:
            for j in range(3):
                sel[m_sel] = 3 * p + j
                m_sel += 1
    return sel[:m_sel]


@kernel
def _pattern_fit(v_all: np.ndarray, sel: np.ndarray, n_pc: int, ks: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """The least-squares machinery of one pattern of measured coordinates ``sel``: Q's columns (m_sel, ·), the
    number of resolved components, and for each k of ``ks`` (up to that number) the target as weights on the
    frame's weighted coordinates, ``M[:, :k] Q[:, :k]ᵀ`` (len(ks), 3, m_sel)."""
    k_top = v_all.shape[1]
    a = np.empty((sel.size, k_top))
    for i in range(sel.size):
        for col in range(k_top):
            a[i, col] = v_all[sel[i], col]
    tau = np.zeros(min(sel.size, k_top))
    _householder(a, tau)
    n_good = _good_columns(a, k_top)
    q_cols = _form_q(a, tau)
    weights = np.zeros((ks.size, 3, sel.size))
    if n_good == 0:
        return q_cols, weights, 0
    maps = _target_maps(a, v_all[n_pc:], n_good)
    for q in range(ks.size):
        for j in range(3):
            for col in range(min(ks[q], n_good)):
                for i in range(sel.size):
                    weights[q, j, i] += maps[j, col] * q_cols[i, col]
    return q_cols, weights, n_good


@kernel
def _predict_pattern(x: np.ndarray, seen: np.ndarray, ctr: np.ndarray, rots: np.ndarray, origins: np.ndarray,
                     moving: bool, mean: np.ndarray, w: np.ndarray, v_all: np.ndarray, ks: np.ndarray,
                     n_seen: np.ndarray, frames: np.ndarray, n_pc: int, residuals: bool,
                     out: np.ndarray, res: np.ndarray) -> None:
    """:func:`predict` for ``frames``, which share one pattern of measured predictors: one QR of the
    components' rows of those predictors (:func:`_pattern_fit`), then each frame's target and residual."""
    sel = _measured_coords(seen[frames[0]])
    if sel.size == 0:
        return
    q_cols, weights, n_good = _pattern_fit(v_all, sel, n_pc, ks)
    if n_good == 0:
        return
    z = np.empty(sel.size)
    explained = np.zeros(n_good + 1)
    for f in frames:
        for i in range(sel.size):
            z[i] = ((x[f, sel[i] // 3, sel[i] % 3] - ctr[f, sel[i] % 3]) - mean[sel[i]]) * w[sel[i]]
        if residuals:
            _explained(q_cols, z, n_good, explained)
        for q in range(ks.size):
            if ks[q] > n_good:
                continue
            if residuals:
                res[q, f] = np.sqrt(max(explained[0] - explained[ks[q]], 0.0) / (3 * n_seen[f]))
            _target(weights[q], z, w, mean, ctr[f], n_pc, out[q, f])
            if moving:
                local = out[q, f].copy()
                for j in range(3):
                    out[q, f, j] = (rots[f, j, 0] * local[0] + rots[f, j, 1] * local[1] + rots[f, j, 2] * local[2]
                                    + origins[f, j])


@kernel
def _target(weights: np.ndarray, z: np.ndarray, w: np.ndarray, mean: np.ndarray, ctr: np.ndarray, n_pc: int,
            out: np.ndarray) -> None:
    """The target (3,) in the model's coordinates from a frame's weighted coordinates ``z``, into ``out``."""
    for j in range(3):
        s = 0.0
        for i in range(z.size):
            s += weights[j, i] * z[i]
        out[j] = s / w[n_pc + j] + mean[n_pc + j] + ctr[j]


@kernel
def _explained(q_cols: np.ndarray, z: np.ndarray, n_good: int, explained: np.ndarray) -> None:
    """Into ``explained``: at 0, |z|²; at k = 1..n_good, the squared norm of z's projection on the first k
    columns of Q."""
    total = 0.0
    for i in range(z.size):
        total += z[i] * z[i]
    explained[0] = total
    acc = 0.0
    for col in range(n_good):
        c = 0.0
        for i in range(z.size):
            c += q_cols[i, col] * z[i]
        acc += c * c
        explained[col + 1] = acc


# ------------------------------------------------------------------------------------------------ rigid fill

@kernel
def _nearest_complete(known_m: np.ndarray, valid: np.ndarray, cols: np.ndarray, n_cols: int, start: int,
                      step: int) -> int:
    """The first frame from ``start`` in direction ``step`` (±1) where ``known_m`` is set and the first
    ``n_cols`` markers of ``cols`` are measured; -1 when none."""
    f = start
    while 0 <= f < known_m.size:
        if known_m[f]:
            for i in range(n_cols):
                if not valid[f, cols[i]]:
                    break
            else:
                return f
        f += step
    return -1


@kernel
def _centroid(xyz: np.ndarray, f: int, cols: np.ndarray, n_cols: int) -> np.ndarray:
    """Mean position (3,) of the first ``n_cols`` markers of ``cols`` in frame ``f``."""
    c = np.zeros(3)
    for i in range(n_cols):
        for j in range(3):
            c[j] += xyz[f, cols[i], j]
    return c / n_cols


@kernel
def _spread_enough(xyz: np.ndarray, r: int, cols: np.ndarray, n_cols: int, min_spread: float,
                   min_plane: float) -> bool:
    """Whether the mates (the first ``n_cols`` of ``cols``) fix a rotation in reference frame ``r``: two, farther
    apart than ``min_spread`` mm; more, spanning a plane (the centred set's second singular value above
    ``min_spread`` and ``min_plane`` times its first)."""
    if n_cols == 2:
        d = 0.0
        for j in range(3):
            d += (xyz[r, cols[1], j] - xyz[r, cols[0], j]) ** 2
        return np.sqrt(d) > min_spread
    c = _centroid(xyz, r, cols, n_cols)
    pts = np.empty((n_cols, 3))
    for i in range(n_cols):
        for j in range(3):
            pts[i, j] = xyz[r, cols[i], j] - c[j]
    sv = np.linalg.svd(pts)[1]
    return sv[1] > max(min_spread, min_plane * sv[0])


@kernel
def _carry(xyz: np.ndarray, r: int, f: int, m: int, cols: np.ndarray, n_cols: int, out: np.ndarray) -> None:
    """Where marker ``m``, fixed to the mates (the first ``n_cols`` of ``cols``) as they were in frame ``r``, is in
    frame ``f``: the least-squares rotation of the reference mates onto frame ``f``'s (Horn's, det +1), or for two
    mates the smallest rotation of their axis (no twist about it), about the centroids. Into ``out`` (3,)."""
    c_ref = _centroid(xyz, r, cols, n_cols)
    c_cur = _centroid(xyz, f, cols, n_cols)
    rot = np.zeros((3, 3))
    if n_cols == 2:
        _axis_rotation(xyz, r, f, cols, rot)
    else:
        # the cross-covariance S = Σ aᵢ bᵢᵀ of the centred reference (a) and current (b) mates, and half their
        # summed squared sizes, which bounds the eigenvalue Horn's closed form starts from
        s = np.zeros((3, 3))
        size = 0.0
        for i in range(n_cols):
            for a in range(3):
                da = xyz[r, cols[i], a] - c_ref[a]
                size += da * da + (xyz[f, cols[i], a] - c_cur[a]) ** 2
                for b in range(3):
                    s[a, b] += da * (xyz[f, cols[i], b] - c_cur[b])
        horn_rotation(s, 0.5 * size, rot, np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4)))
    for a in range(3):
        out[a] = c_cur[a]
        for b in range(3):
            out[a] += rot[a, b] * (xyz[r, m, b] - c_ref[b])


@kernel
def _axis_rotation(xyz: np.ndarray, r: int, f: int, cols: np.ndarray, rot: np.ndarray) -> None:
    """The smallest rotation (3, 3) taking the axis between two mates in frame ``r`` onto theirs in frame ``f``
    (Rodrigues; the identity when the axes agree), into ``rot``."""
    u = xyz[r, cols[1]] - xyz[r, cols[0]]
    v = xyz[f, cols[1]] - xyz[f, cols[0]]
    u = u / np.sqrt(np.sum(u * u))
    v = v / np.sqrt(np.sum(v * v))
    k = np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])
    sin = np.sqrt(np.sum(k * k))
    cos = np.sum(u * v)
    for a in range(3):
        rot[a, a] = 1.0
    if sin > 1e-12:
        k /= sin
        ang = np.arctan2(sin, cos)
        c, s = np.cos(ang), np.sin(ang)
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        for a in range(3):
            for b in range(3):
                rot[a, b] = c * (1.0 if a == b else 0.0) + s * kx[a, b] + (1.0 - c) * k[a] * k[b]


@kernel
def _blend(p0: np.ndarray | None, p1: np.ndarray | None, f: int, b0: int, b1: int, out: np.ndarray) -> None:
    """Frame ``f``'s prediction into ``out`` (3,): ``p0`` (from reference ``b0``) and ``p1`` (from ``b1``)
    blended by time between them, or the one there is (None: none from that side)."""
    if p0 is not None and p1 is not None:
        w = min(max((f - b0) / (b1 - b0), 0.0), 1.0)
        for j in range(3):
            out[j] = (1.0 - w) * p0[j] + w * p1[j]
    elif p0 is not None:
        out[:] = p0
    elif p1 is not None:
        out[:] = p1


@kernel
def _mates_seen(valid: np.ndarray, f: int, mates: np.ndarray, sub: np.ndarray) -> tuple[int, np.int64]:
    """The ``mates`` measured in frame ``f`` into the start of ``sub``: their count and their set as bits."""
    n_sub = 0
    key = np.int64(0)
    for j in range(mates.size):
        if valid[f, mates[j]]:
            sub[n_sub] = mates[j]
            n_sub += 1
            key |= np.int64(1) << j
    return n_sub, key


@kernel
def _reference(xyz: np.ndarray, valid: np.ndarray, known_m: np.ndarray, sub: np.ndarray, n_sub: int, start: int,
               step: int, min_spread: float, min_plane: float) -> int:
    """The reference frame searched from ``start`` in direction ``step`` (:func:`_nearest_complete`), or -1 when
    there is none or its mates do not fix a rotation (:func:`_spread_enough`)."""
    r = _nearest_complete(known_m, valid, sub, n_sub, start, step)
    if r >= 0 and not _spread_enough(xyz, r, sub, n_sub, min_spread, min_plane):
        return -1
    return r


@kernel
def rigid_predict(xyz: np.ndarray, valid: np.ndarray, known_m: np.ndarray, m: int, mates: np.ndarray,
                  starts: np.ndarray, stops: np.ndarray, lo: np.ndarray, hi: np.ndarray, min_spread: float,
                  min_plane: float) -> np.ndarray:
    """The rigid-cluster prediction of marker ``m`` over each interval's span ``[lo[i], hi[i])``, the spans one
    after the other: (Σ (hi − lo), 3) mm, NaN where a frame cannot be predicted.

    In each frame the ``mates`` measured there (at least two) are fitted to their positions in two reference
    frames: the nearest before ``starts[i]`` and at or after ``stops[i]`` where ``known_m`` is set and those
    mates are measured, each used only where the mates fix a rotation there (:func:`_spread_enough`). The two
    predictions are blended by time across the interval; with one usable reference, it alone."""
    total = 0
    for i in range(lo.size):
        total += hi[i] - lo[i]
    out = np.full((total, 3), np.nan)
    sub = np.empty(mates.size, dtype=np.int64)
    p0 = np.empty(3)
    p1 = np.empty(3)
    row = 0
    for i in range(lo.size):
        key_before = np.int64(-1)
        b0 = b1 = -1
        for f in range(lo[i], hi[i]):
            n_sub, key = _mates_seen(valid, f, mates, sub)
            if n_sub >= 2:
                if key != key_before:       # the references of this interval for this set of mates
                    b0 = _reference(xyz, valid, known_m, sub, n_sub, starts[i] - 1, -1, min_spread, min_plane)
                    b1 = _reference(xyz, valid, known_m, sub, n_sub, stops[i], 1, min_spread, min_plane)
                    key_before = key
                if b0 >= 0:
                    _carry(xyz, b0, f, m, sub, n_sub, p0)
                if b1 >= 0:
                    _carry(xyz, b1, f, m, sub, n_sub, p1)
                _blend(p0 if b0 >= 0 else None, p1 if b1 >= 0 else None, f, b0, b1, out[row])
            row += 1
    return out
