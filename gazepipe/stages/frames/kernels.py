"""The frames stage's compiled rotation kernels and :class:`Rot`, a stack of rotations built on them.

The rotation fill and the continuity check compose, invert and measure stacks of a few to a few thousand rotations
thousands of times per take; scipy's ``Rotation`` spends most of that in per-call dispatch (array-API promotion,
checks, a new object per result). :class:`Rot` keeps the same scalar-last unit quaternions (``x, y, z, w``) in a
plain (N, 4) array and runs each operation as one compiled loop written as scipy's own Cython loop is (the same
operations in the same order, libm's ``sin``, ``cos`` and ``atan2``), so the results are the same bits.

Each kernel is the one implementation of its step, compiled by numba on its first call in a process
(``cache=True``, ``fastmath`` off, ``error_model="numpy"``; see :mod:`gazepipe.stages.clean.kernels`). Rows are
rotations (usually frames of a take); angles are radians.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gazepipe.stages.jit import kernel
from gazepipe.stages.rotation_kernels import horn_rotation


@kernel
def compose(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) of ``p * q`` (apply q, then p); p or q may have one row, which is broadcast.
    scipy's ``Rotation.__mul__``: the Hamilton product, then each row divided by its norm."""
    n = q.shape[0] if p.shape[0] == 1 else p.shape[0]
    out = np.empty((n, 4))
    for i in range(n):
        a = p[0] if p.shape[0] == 1 else p[i]
        b = q[0] if q.shape[0] == 1 else q[i]
        c0 = a[1] * b[2] - a[2] * b[1]
        c1 = a[2] * b[0] - a[0] * b[2]
        c2 = a[0] * b[1] - a[1] * b[0]
        x = a[3] * b[0] + b[3] * a[0] + c0
        y = a[3] * b[1] + b[3] * a[1] + c1
        z = a[3] * b[2] + b[3] * a[2] + c2
        w = a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2]
        norm = math.sqrt((x * x + y * y + z * z) + w * w)
        out[i, 0] = x / norm
        out[i, 1] = y / norm
        out[i, 2] = z / norm
        out[i, 3] = w / norm
    return out


@kernel
def magnitude(q: np.ndarray) -> np.ndarray:
    """Rotation angles (n,) in [0, π] of unit quaternions q (n, 4) (scipy's ``Rotation.magnitude``)."""
    n = q.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = 2 * math.atan2(math.sqrt(q[i, 0] * q[i, 0] + q[i, 1] * q[i, 1] + q[i, 2] * q[i, 2]),
                                abs(q[i, 3]))
    return out


@kernel
def as_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) of unit quaternions q (n, 4), angle in [0, π] (scipy's ``Rotation.as_rotvec``)."""
    n = q.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        x, y, z, w = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        if w < 0 or (w == 0 and x < 0) or (w == 0 and x == 0 and y < 0) or (w == 0 and x == 0 and y == 0
                                                                                and z < 0):
            x, y, z, w = -x, -y, -z, -w
        angle = 2 * math.atan2(math.sqrt(x * x + y * y + z * z), w)
        if angle <= 1e-3:
            angle2 = angle * angle
            scale = 2 + angle2 / 12 + 7 * angle2 * angle2 / 2880
        else:
            scale = angle / math.sin(angle / 2)
        out[i, 0] = scale * x
        out[i, 1] = scale * y
        out[i, 2] = scale * z
    return out


@kernel
def from_rotvec(v: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) of rotation vectors v (n, 3) (scipy's ``Rotation.from_rotvec``)."""
    n = v.shape[0]
    out = np.empty((n, 4))
    for i in range(n):
        angle = math.sqrt(v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2])
        if angle <= 1e-3:
            angle2 = angle * angle
            scale = 0.5 - angle2 / 48 + angle2 * angle2 / 3840
        else:
            scale = math.sin(angle / 2) / angle
        out[i, 0] = scale * v[i, 0]
        out[i, 1] = scale * v[i, 1]
        out[i, 2] = scale * v[i, 2]
        out[i, 3] = math.cos(angle / 2)
    return out


@kernel
def as_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of unit quaternions q (n, 4) (scipy's ``Rotation.as_matrix``)."""
    n = q.shape[0]
    m = np.empty((n, 3, 3))
    for i in range(n):
        x, y, z, w = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        x2, y2, z2, w2 = x * x, y * y, z * z, w * w
        xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
        m[i, 0, 0] = x2 - y2 - z2 + w2
        m[i, 1, 0] = 2 * (xy + zw)
        m[i, 2, 0] = 2 * (xz - yw)
        m[i, 0, 1] = 2 * (xy - zw)
        m[i, 1, 1] = - x2 + y2 - z2 + w2
        m[i, 2, 1] = 2 * (yz + xw)
        m[i, 0, 2] = 2 * (xz + yw)
        m[i, 1, 2] = 2 * (yz - xw)
        m[i, 2, 2] = - x2 - y2 + z2 + w2
    return m


@kernel
def _from_orthogonal(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit quaternions (n, 4) of rotation matrices m (n, 3, 3) by scipy's method (the largest of the diagonal and
    the trace picks the formula), and which rows pass scipy's checks (n,): a positive determinant and
    m·mᵀ within ``isclose(·, I, atol=1e-12)``; rows that fail are left to scipy."""
    n = m.shape[0]
    out = np.empty((n, 4))
    fine = np.empty(n, dtype=np.bool_)
    for i in range(n):
        good = True
        for r in range(3):
            for c in range(3):
                g = m[i, r, 0] * m[i, c, 0] + m[i, r, 1] * m[i, c, 1] + m[i, r, 2] * m[i, c, 2]
                e = 1.0 if r == c else 0.0
                if not abs(g - e) <= 1e-12 + 1e-5 * abs(e):
                    good = False
        det = (m[i, 0, 0] * (m[i, 1, 1] * m[i, 2, 2] - m[i, 1, 2] * m[i, 2, 1])
               - m[i, 0, 1] * (m[i, 1, 0] * m[i, 2, 2] - m[i, 1, 2] * m[i, 2, 0])
               + m[i, 0, 2] * (m[i, 1, 0] * m[i, 2, 1] - m[i, 1, 1] * m[i, 2, 0]))
        fine[i] = good and det > 0.5
        d0, d1, d2 = m[i, 0, 0], m[i, 1, 1], m[i, 2, 2]
        d3 = d0 + d1 + d2
        choice, vmax = 0, d0
        if d1 > vmax:
            choice, vmax = 1, d1
        if d2 > vmax:
            choice, vmax = 2, d2
        if d3 > vmax:
            choice = 3
        if choice != 3:
            a = choice
            b = (a + 1) % 3
            c = (b + 1) % 3
            out[i, a] = 1 - d3 + 2 * m[i, a, a]
            out[i, b] = m[i, b, a] + m[i, a, b]
            out[i, c] = m[i, c, a] + m[i, a, c]
            out[i, 3] = m[i, c, b] - m[i, b, c]
        else:
            out[i, 0] = m[i, 2, 1] - m[i, 1, 2]
            out[i, 1] = m[i, 0, 2] - m[i, 2, 0]
            out[i, 2] = m[i, 1, 0] - m[i, 0, 1]
            out[i, 3] = 1 + d3
        norm = math.sqrt((out[i, 0] * out[i, 0] + out[i, 1] * out[i, 1] + out[i, 2] * out[i, 2])
                         + out[i, 3] * out[i, 3])
        for k in range(4):
            out[i, k] /= norm
    return out, fine


@kernel
def running_median(x: np.ndarray, half: int) -> np.ndarray:
    """Running median down the columns of x (n, m) over ``2·half + 1`` rows, the edges repeating the end rows
    (``scipy.ndimage.median_filter(x, size=(2·half + 1, 1), mode="nearest")``; an odd count: the median is one of
    the values, so the same numbers), x finite."""
    n, m = x.shape
    w = 2 * half + 1
    out = np.empty((n, m))
    buf = np.empty(w)                     # the window's values, sorted
    for c in range(m):
        for k in range(w):
            buf[k] = x[min(max(k - half, 0), n - 1), c]
        buf.sort()
        out[0, c] = buf[half]
        for i in range(1, n):
            old = x[min(max(i - 1 - half, 0), n - 1), c]
            new = x[min(i + half, n - 1), c]
            j = 0
            while buf[j] != old:          # the value leaving the window ...
                j += 1
            while j > 0 and buf[j - 1] > new:          # ... its slot taken by the one entering, kept sorted
                buf[j] = buf[j - 1]
                j -= 1
            while j < w - 1 and buf[j + 1] < new:
                buf[j] = buf[j + 1]
                j += 1
            buf[j] = new
            out[i, c] = buf[half]
    return out


@kernel
def horn_rotations(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotations (N, 3, 3) with b[n] − centroid ≈ R[n] · a[n] (Horn's closed form,
    :func:`gazepipe.stages.rotation_kernels.horn_rotation`), and the centroids (N, 3).

    ``a`` (N, K, 3) or (1, K, 3) shared: the reference clusters about their centroids; ``b`` (N, K, 3) the observed
    ones, each centred here on its centroid (the markers summed in order, over K: numpy's ``mean(axis=1)``).
    The same rotation as Kabsch's SVD with its sign correction (det R = +1), to rounding."""
    n, k = b.shape[0], b.shape[1]
    out = np.empty((n, 3, 3))
    centre = np.empty((n, 3))
    s = np.empty((3, 3))
    nmat, work, adj = np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4))
    for f in range(n):
        ar = a[0] if a.shape[0] == 1 else a[f]
        cx, cy, cz = b[f, 0, 0], b[f, 0, 1], b[f, 0, 2]
        for i in range(1, k):
            cx += b[f, i, 0]
            cy += b[f, i, 1]
            cz += b[f, i, 2]
        cx, cy, cz = cx / k, cy / k, cz / k
        centre[f, 0], centre[f, 1], centre[f, 2] = cx, cy, cz
        sxx = sxy = sxz = syx = syy = syz = szx = szy = szz = size = 0.0
        for i in range(k):
            ax, ay, az = ar[i, 0], ar[i, 1], ar[i, 2]
            bx, by, bz = b[f, i, 0] - cx, b[f, i, 1] - cy, b[f, i, 2] - cz
            sxx += ax * bx
            sxy += ax * by
            sxz += ax * bz
            syx += ay * bx
            syy += ay * by
            syz += ay * bz
            szx += az * bx
            szy += az * by
            szz += az * bz
            size += (ax * ax + ay * ay + az * az) + (bx * bx + by * by + bz * bz)
        s[0, 0], s[0, 1], s[0, 2] = sxx, sxy, sxz
        s[1, 0], s[1, 1], s[1, 2] = syx, syy, syz
        s[2, 0], s[2, 1], s[2, 2] = szx, szy, szz
        horn_rotation(s, 0.5 * size, out[f], nmat, work, adj)
    return out, centre


@kernel
def wahba_rotations(m: np.ndarray) -> np.ndarray:
    """Rotations (F, 3, 3) R maximising tr(Rᵀ·M) for each matrix ``m`` (F, 3, 3) (Wahba's problem: M the
    weighted sum of observed-times-reference outer products, Σ bᵢ aᵢᵀ, and any prior's weighted rotation):
    :func:`gazepipe.stages.rotation_kernels.horn_rotation` of Mᵀ, its eigenvalue bounded by √3·‖M‖ (the sum of M's singular values at most).
    The rotation of the SVD U·diag(1, 1, det(U·Vᵀ))·Vᵀ, to rounding."""
    n = m.shape[0]
    out = np.empty((n, 3, 3))
    s = np.empty((3, 3))
    nmat, work, adj = np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4))
    for f in range(n):
        size = 0.0
        for r in range(3):
            for c in range(3):
                s[r, c] = m[f, c, r]
                size += m[f, c, r] * m[f, c, r]
        horn_rotation(s, math.sqrt(3.0 * size), out[f], nmat, work, adj)
    return out


def from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) of rotation matrices m (n, 3, 3), as scipy's ``Rotation.from_matrix`` gives them
    (rows not orthonormal to 1e-12, which scipy first orthonormalises, and rows it refuses go to scipy)."""
    m = np.ascontiguousarray(m, dtype=np.float64)
    q, fine = _from_orthogonal(m)
    if not fine.all():
        from scipy.spatial.transform import Rotation

        q[~fine] = Rotation.from_matrix(m[~fine]).as_quat()
    return q


#: a quaternion's conjugate (the inverse rotation): ``x, y, z`` negated
_CONJUGATE = np.array([-1.0, -1.0, -1.0, 1.0])


class Rot:
    """A stack of rotations as unit quaternions ``x, y, z, w`` (n, 4): the part of scipy's ``Rotation`` the frames
    stage uses (indexing, ``*``, ``inv``, ``magnitude``, ``as_rotvec``, ``as_matrix``, ``mean``), the same bits.
    An integer index gives a single rotation, whose ``magnitude`` is a float and ``as_rotvec`` a (3,) vector."""

    __slots__ = ("q", "single")

    def __init__(self, q: np.ndarray, single: bool = False) -> None:
        self.q = q
        self.single = single

    @classmethod
    def from_matrix(cls, m: np.ndarray) -> Rot:
        return cls(from_matrix(m))

    @classmethod
    def from_rotvec(cls, v: np.ndarray) -> Rot:
        v = np.asarray(v, dtype=np.float64)
        if v.ndim == 1:
            return cls(from_rotvec(np.ascontiguousarray(v[None])), single=True)
        return cls(from_rotvec(np.ascontiguousarray(v)))

    def __len__(self) -> int:
        return int(self.q.shape[0])

    def __getitem__(self, idx: Any) -> Rot:
        if isinstance(idx, (int, np.integer)):
            return Rot(self.q[idx][None], single=True)
        return Rot(self.q[idx])

    def __mul__(self, other: Rot) -> Rot:
        if len(self) != len(other) and 1 not in (len(self), len(other)):
            raise ValueError(f"cannot compose {len(self)} rotations with {len(other)}")
        return Rot(compose(self.q, other.q), single=self.single and other.single)

    def inv(self) -> Rot:
        return Rot(self.q * _CONJUGATE, single=self.single)

    def magnitude(self) -> Any:
        out = magnitude(self.q)
        return float(out[0]) if self.single else out

    def as_rotvec(self) -> np.ndarray:
        out = as_rotvec(self.q)
        return out[0] if self.single else out

    def as_matrix(self) -> np.ndarray:
        out = as_matrix(self.q)
        return out[0] if self.single else out

    def wxyz(self) -> np.ndarray:
        """Quaternions ``w, x, y, z``, canonical (w ≥ 0; scipy's ``as_quat(canonical=True, scalar_first=True)``),
        (n, 4), or (4,) for a single rotation."""
        q = self.q
        w, x, y, z = q[:, 3], q[:, 0], q[:, 1], q[:, 2]
        flip = (w < 0) | ((w == 0) & ((x < 0) | ((x == 0) & ((y < 0) | ((y == 0) & (z < 0))))))
        out = np.where(flip[:, None], -q, q)[:, [3, 0, 1, 2]]
        return out[0] if self.single else out

    def mean(self) -> Rot:
        """scipy's ``Rotation.mean`` of the stack (a single rotation), computed as scipy computes it (the
        eigenvector of the largest eigenvalue of Σ q·qᵀ, numpy's ``eigh``) without building a ``Rotation``."""
        q = self.q
        k = np.dot(np.ones(len(q)) * q.T, q)
        return Rot(np.linalg.eigh(k)[1][:, -1][None].copy(), single=True)
