"""Horn's least-squares rotation between two point clusters, compiled: the frames stage's segment fits and
rotation fill, and the clean stage's rigid fill, call it frame by frame from their own kernels.

The rotation is the unit quaternion of the largest eigenvalue of Horn's symmetric 4×4 matrix of the clusters'
cross-covariance, found by Theobald's closed form (QCP) and, where the eigenvalues crowd, Jacobi's rotations: the
same rotation as Kabsch's SVD with its sign correction (det R = +1) to rounding, in a fraction of its time.
Compiled as :mod:`gazepipe.stages.jit` says.
"""

from __future__ import annotations

import math

import numpy as np

from gazepipe.stages.jit import kernel


@kernel
def _largest_eigvec4(a: np.ndarray) -> np.ndarray:
    """Unit eigenvector (4,) of the largest eigenvalue of the symmetric 4×4 matrix ``a`` (overwritten): cyclic
    Jacobi rotations until the off-diagonal part is below the rounding of the diagonal."""
    v = np.eye(4)
    for _ in range(50):
        off = 0.0
        scale = 0.0
        for i in range(4):
            scale += a[i, i] * a[i, i]
            for j in range(i + 1, 4):
                off += a[i, j] * a[i, j]
        if off <= 1e-36 * scale or off == 0.0:
            break
        for p in range(3):
            for r in range(p + 1, 4):
                apr = a[p, r]
                if apr == 0.0:
                    continue
                theta = (a[r, r] - a[p, p]) / (2.0 * apr)
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(4):                     # a ← Jᵀ a J, v ← v J (rows/columns p and r)
                    akp, akr = a[k, p], a[k, r]
                    a[k, p] = c * akp - s * akr
                    a[k, r] = s * akp + c * akr
                for k in range(4):
                    apk, ark = a[p, k], a[r, k]
                    a[p, k] = c * apk - s * ark
                    a[r, k] = s * apk + c * ark
                for k in range(4):
                    vkp, vkr = v[k, p], v[k, r]
                    v[k, p] = c * vkp - s * vkr
                    v[k, r] = s * vkp + c * vkr
    best = 0
    for i in range(1, 4):
        if a[i, i] > a[best, best]:
            best = i
    return v[:, best]


#: where the largest eigenvalue of Horn's matrix stands apart from the others by at least this (the adjugate's
#: largest diagonal entry over E0³, E0 the bound on the eigenvalue), the closed form's rotation is within
#: about 8·2⁻⁵²/r² ≈ 2e-13 of the exact one (measured on clusters from collinear to round); closer than that it
#: is left to Jacobi's rotations, which lose only about the square root as many digits. Real clusters: r ≥ 0.35
QCP_MIN_SEPARATION = 0.1


@kernel
def _adjugate4(a: np.ndarray, adj: np.ndarray) -> float:
    """The adjugate (4, 4) of the 4×4 matrix ``a`` into ``adj`` (det(a)·a⁻¹, by the Laplace expansion over the
    2×2 minors of rows 0–1 and rows 2–3); returns det(a)."""
    s0 = a[0, 0] * a[1, 1] - a[1, 0] * a[0, 1]
    s1 = a[0, 0] * a[1, 2] - a[1, 0] * a[0, 2]
    s2 = a[0, 0] * a[1, 3] - a[1, 0] * a[0, 3]
    s3 = a[0, 1] * a[1, 2] - a[1, 1] * a[0, 2]
    s4 = a[0, 1] * a[1, 3] - a[1, 1] * a[0, 3]
    s5 = a[0, 2] * a[1, 3] - a[1, 2] * a[0, 3]
    c5 = a[2, 2] * a[3, 3] - a[3, 2] * a[2, 3]
    c4 = a[2, 1] * a[3, 3] - a[3, 1] * a[2, 3]
    c3 = a[2, 1] * a[3, 2] - a[3, 1] * a[2, 2]
    c2 = a[2, 0] * a[3, 3] - a[3, 0] * a[2, 3]
    c1 = a[2, 0] * a[3, 2] - a[3, 0] * a[2, 2]
    c0 = a[2, 0] * a[3, 1] - a[3, 0] * a[2, 1]
    adj[0, 0] = a[1, 1] * c5 - a[1, 2] * c4 + a[1, 3] * c3
    adj[0, 1] = -a[0, 1] * c5 + a[0, 2] * c4 - a[0, 3] * c3
    adj[0, 2] = a[3, 1] * s5 - a[3, 2] * s4 + a[3, 3] * s3
    adj[0, 3] = -a[2, 1] * s5 + a[2, 2] * s4 - a[2, 3] * s3
    adj[1, 0] = -a[1, 0] * c5 + a[1, 2] * c2 - a[1, 3] * c1
    adj[1, 1] = a[0, 0] * c5 - a[0, 2] * c2 + a[0, 3] * c1
    adj[1, 2] = -a[3, 0] * s5 + a[3, 2] * s2 - a[3, 3] * s1
    adj[1, 3] = a[2, 0] * s5 - a[2, 2] * s2 + a[2, 3] * s1
    adj[2, 0] = a[1, 0] * c4 - a[1, 1] * c2 + a[1, 3] * c0
    adj[2, 1] = -a[0, 0] * c4 + a[0, 1] * c2 - a[0, 3] * c0
    adj[2, 2] = a[3, 0] * s4 - a[3, 1] * s2 + a[3, 3] * s0
    adj[2, 3] = -a[2, 0] * s4 + a[2, 1] * s2 - a[2, 3] * s0
    adj[3, 0] = -a[1, 0] * c3 + a[1, 1] * c1 - a[1, 2] * c0
    adj[3, 1] = a[0, 0] * c3 - a[0, 1] * c1 + a[0, 2] * c0
    adj[3, 2] = -a[3, 0] * s3 + a[3, 1] * s1 - a[3, 2] * s0
    adj[3, 3] = a[2, 0] * s3 - a[2, 1] * s1 + a[2, 2] * s0
    return s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0


@kernel
def _largest_root(c2: float, c1: float, c0: float, upper: float) -> float:
    """The largest root of λ⁴ + c2·λ² + c1·λ + c0, all of whose roots are real and at most ``upper``: Newton's
    steps down from ``upper`` (above the largest root the quartic is increasing and convex, so each step stays
    above it) until a step is below the rounding of λ."""
    lam = upper
    for _ in range(60):
        x2 = lam * lam
        b = (x2 + c2) * lam
        a = b + c1
        delta = (a * lam + c0) / (2.0 * x2 * lam + b + a)
        if not abs(delta) < math.inf:
            break
        lam -= delta
        if delta <= 1e-15 * lam:
            break
    return lam


@kernel
def horn_rotation(s: np.ndarray, e0: float, out: np.ndarray, nmat: np.ndarray, work: np.ndarray,
                   adj: np.ndarray) -> None:
    """Into ``out`` (3, 3), the rotation R maximising tr(R·S) for the cross-covariance ``s`` (3, 3) of two clusters
    (S = Σ aᵢ bᵢᵀ, b ≈ R·a): the unit quaternion of the largest eigenvalue of Horn's symmetric 4×4 matrix of S;
    ``e0`` bounds that eigenvalue from above (half the two clusters' summed squared sizes, or √3·‖S‖). ``nmat``,
    ``work`` and ``adj`` (4, 4) are scratch.

    Theobald's closed form (QCP): the eigenvalue as the largest root of the characteristic polynomial
    λ⁴ − 2‖S‖²λ² − 8 det(S)·λ + det(N), then the eigenvector as the adjugate of N − λI (a multiple of v·vᵀ),
    its row of the largest diagonal entry. Where that entry says the eigenvalue is not well apart from the
    others (:data:`QCP_MIN_SEPARATION`), Jacobi's rotations (:func:`_largest_eigvec4`)."""
    sxx, sxy, sxz = s[0, 0], s[0, 1], s[0, 2]
    syx, syy, syz = s[1, 0], s[1, 1], s[1, 2]
    szx, szy, szz = s[2, 0], s[2, 1], s[2, 2]
    nmat[0, 0] = sxx + syy + szz
    nmat[0, 1] = nmat[1, 0] = syz - szy
    nmat[0, 2] = nmat[2, 0] = szx - sxz
    nmat[0, 3] = nmat[3, 0] = sxy - syx
    nmat[1, 1] = sxx - syy - szz
    nmat[1, 2] = nmat[2, 1] = sxy + syx
    nmat[1, 3] = nmat[3, 1] = szx + sxz
    nmat[2, 2] = -sxx + syy - szz
    nmat[2, 3] = nmat[3, 2] = syz + szy
    nmat[3, 3] = -sxx - syy + szz
    c2 = -2.0 * (sxx * sxx + sxy * sxy + sxz * sxz + syx * syx + syy * syy + syz * syz + szx * szx + szy * szy
                 + szz * szz)
    c1 = -8.0 * (sxx * (syy * szz - syz * szy) - sxy * (syx * szz - syz * szx) + sxz * (syx * szy - syy * szx))
    lam = _largest_root(c2, c1, _adjugate4(nmat, adj), e0)
    for i in range(4):
        for j in range(4):
            work[i, j] = nmat[i, j] - lam if i == j else nmat[i, j]
    _adjugate4(work, adj)
    best = 0
    for i in range(1, 4):
        if abs(adj[i, i]) > abs(adj[best, best]):
            best = i
    if abs(adj[best, best]) > QCP_MIN_SEPARATION * e0 * e0 * e0:
        w, x, y, z = adj[best, 0], adj[best, 1], adj[best, 2], adj[best, 3]
    else:
        v = _largest_eigvec4(nmat)
        w, x, y, z = v[0], v[1], v[2], v[3]
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    out[0, 0] = w * w + x * x - y * y - z * z
    out[0, 1] = 2 * (x * y - w * z)
    out[0, 2] = 2 * (x * z + w * y)
    out[1, 0] = 2 * (x * y + w * z)
    out[1, 1] = w * w - x * x + y * y - z * z
    out[1, 2] = 2 * (y * z - w * x)
    out[2, 0] = 2 * (x * z - w * y)
    out[2, 1] = 2 * (y * z + w * x)
    out[2, 2] = w * w - x * x - y * y + z * z
