"""The frames stage's rotation kernels give scipy's ``Rotation`` results bit for bit (the outputs' bytes rest on it)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gazepipe.stages.frames.kernels import Rot


def _rotations(seed: int) -> Rotation:
    """Random rotations with the hard cases: tiny angles (the Taylor branch), angles near π, negative w, identity."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return Rotation.concatenate([
        Rotation.random(500, random_state=seed),
        Rotation.from_rotvec(rng.normal(size=(200, 3)) * 1e-4),
        Rotation.from_rotvec(axes * (np.pi - rng.uniform(0.0, 1e-6, 200))[:, None]),
        Rotation.from_quat(-Rotation.random(100, random_state=seed + 1).as_quat()),
        Rotation.identity(3),
    ])


def test_stack_operations_match_scipy_bit_for_bit():
    a, b = _rotations(1), _rotations(2)
    ra, rb = Rot(a.as_quat()), Rot(b.as_quat())
    assert np.array_equal((ra * rb).q, (a * b).as_quat())
    assert np.array_equal((ra[:1] * rb).q, (a[:1] * b).as_quat())
    assert np.array_equal((ra.inv() * rb[3]).q, (a.inv() * b[3]).as_quat())
    assert np.array_equal(ra.magnitude(), a.magnitude())
    assert np.array_equal(ra.as_rotvec(), a.as_rotvec())
    assert np.array_equal(ra.as_matrix(), a.as_matrix())
    assert np.array_equal(Rot.from_rotvec(a.as_rotvec()).q, Rotation.from_rotvec(a.as_rotvec()).as_quat())
    assert np.array_equal(ra[:300].mean().q[0], a[:300].mean().as_quat())


def test_from_matrix_matches_scipy_including_matrices_it_orthonormalises():
    m = (_rotations(3) * _rotations(4)).as_matrix()
    m[:5] *= 1.001                                   # not orthonormal: scipy projects them first
    assert np.array_equal(Rot.from_matrix(m).q, Rotation.from_matrix(m).as_quat())
    with pytest.raises(ValueError):
        Rot.from_matrix(-np.eye(3)[None])            # a reflection is refused, as by scipy


def test_single_rotations_give_scalars_and_vectors():
    a = _rotations(5)
    r = Rot(a.as_quat())
    assert isinstance((r[0].inv() * r[7]).magnitude(), float)
    assert (r[0].inv() * r[7]).magnitude() == (a[0].inv() * a[7]).magnitude()
    assert np.array_equal((r[0].inv() * r[7]).as_rotvec(), (a[0].inv() * a[7]).as_rotvec())
    with pytest.raises(ValueError):
        r[:3] * r[:4]


def _sliding_median(x: np.ndarray, half: int) -> np.ndarray:
    """The median over each row's ``half`` neighbours on either side, the ends repeated (numpy, by definition)."""
    padded = np.concatenate([np.repeat(x[:1], half, axis=0), x, np.repeat(x[-1:], half, axis=0)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1, axis=0)
    return np.median(windows, axis=-1)


def test_running_median_is_the_sliding_median_and_scipys():
    from scipy import ndimage

    from gazepipe.stages.frames.continuity import _median_rows

    rng = np.random.default_rng(7)
    for n in (1, 2, 9, 40, 300):
        for x in (rng.normal(size=(n, 3)), np.round(rng.normal(size=n), 1)):     # ties too
            for half in (1, 3, 8):
                got = _median_rows(x, half)
                assert np.array_equal(got, _sliding_median(x, half))
                if n > 2 * half:      # scipy before 1.16 gives 0 where the series is shorter than the window
                    size = (2 * half + 1,) + (1,) * (x.ndim - 1)
                    assert np.array_equal(got, ndimage.median_filter(x, size=size, mode="nearest"))


def test_horn_rigid_fit_is_kabschs_rotation():
    """The frames' compiled closed-form fit recovers the true rotation of a noiseless cluster and gives Kabsch's
    SVD rotation on noisy ones (3 to 6 markers, any rotation) to rounding."""
    from gazepipe.stages.frames.stage import rigid_fit
    from gazepipe.stages.geometry import kabsch

    rng = np.random.default_rng(11)
    truth = Rotation.random(400, random_state=3).as_matrix()
    for k in (3, 4, 6):
        ref = rng.normal(size=(k, 3)) * 60.0
        clean = np.einsum("nij,kj->nki", truth, ref) + rng.normal(size=(400, 1, 3)) * 500.0
        assert np.abs(rigid_fit(ref, clean) - truth).max() < 1e-12
        noisy = clean + rng.normal(size=clean.shape) * 0.5
        fit = rigid_fit(ref, noisy)
        assert np.abs(fit - kabsch(ref, noisy)).max() < 1e-12
        assert np.abs(np.linalg.det(fit) - 1.0).max() < 1e-12


def test_horn_rigid_fit_keeps_its_digits_on_nearly_collinear_clusters():
    """Where the closed form's eigenvalue is not well apart from the next (markers nearly in a line), the fit
    still recovers the true rotation to what the cluster's shape allows, and a cluster of coincident markers
    gives the identity (no NaN)."""
    from gazepipe.stages.frames.stage import rigid_fit

    truth = Rotation.random(300, random_state=5).as_matrix()
    rng = np.random.default_rng(2)
    line = np.array([[0.0, 0, 0], [100, 0, 0], [200, 0, 0], [50, 0, 0]])
    for spread, tol in ((10.0, 1e-12), (1.0, 1e-10), (0.1, 1e-8)):
        ref = line + rng.normal(size=line.shape) * spread
        assert np.abs(rigid_fit(ref, np.einsum("nij,kj->nki", truth, ref)) - truth).max() < tol
    assert np.array_equal(rigid_fit(np.zeros((3, 3)), np.ones((2, 3, 3))), np.broadcast_to(np.eye(3), (2, 3, 3)))


def test_adjugate4_is_det_times_inverse():
    from gazepipe.stages.rotation_kernels import _adjugate4

    rng = np.random.default_rng(4)
    for _ in range(20):
        a = rng.normal(size=(4, 4))
        adj = np.empty((4, 4))
        det = _adjugate4(a, adj)
        assert det == pytest.approx(np.linalg.det(a), rel=1e-12)
        assert np.allclose(adj, np.linalg.det(a) * np.linalg.inv(a), rtol=1e-10, atol=1e-12)


def test_wahba_rotations_are_the_svd_solution():
    """Horn's closed form on a general matrix M gives the SVD's rotation U·diag(1, 1, det UVᵀ)·Vᵀ maximising
    tr(RᵀM): from two markers and a weak prior (nearly rank one: the Jacobi side) to full clusters."""
    from gazepipe.stages.frames.kernels import wahba_rotations

    rng = np.random.default_rng(9)
    prior = Rotation.random(500, random_state=4).as_matrix()
    for k in (2, 3, 5):
        m = rng.normal(size=(500, 3, k)) @ rng.normal(size=(500, k, 3)) * 50.0 + 1e-3 * prior
        u, _, vt = np.linalg.svd(m)
        d = np.ones((len(m), 3))
        d[:, 2] = np.sign(np.linalg.det(u @ vt))
        assert np.abs(wahba_rotations(m) - (u * d[:, None, :]) @ vt).max() < 1e-11
