"""The swap references' compiled statistics against numpy's own functions on the same numbers."""

import numpy as np
import pytest

from gazepipe.stages.clean.kernels import _median_of, _quantile_of, chiral_triples


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11, 57, 500])
def test_quantile_and_median_are_numpys_to_the_bit(n):
    rng = np.random.default_rng(n)
    values = rng.normal(size=n) * 10.0 ** rng.integers(-3, 3, size=n)
    for q in (0.0, 0.05, 0.25, 0.5, 0.95, 1.0):
        assert _quantile_of(values.copy(), n, q) == np.quantile(values, q)
    assert _median_of(values.copy(), n) == np.median(values)


def test_no_values_give_nan():
    assert np.isnan(_quantile_of(np.zeros(3), 0, 0.05))
    assert np.isnan(_median_of(np.zeros(3), 0))


def _volumes(xyz, origin, tri):
    """(S, C) triple products of the directions from ``origin`` (S, 3) to each triple's corners, as a share of
    their lengths' product, with numpy's cross and dot."""
    u, v, w = (xyz[:, tri[:, i]] - origin[:, None] for i in range(3))
    det = np.einsum("sck,sck->sc", u, np.cross(v, w))
    return det / (np.linalg.norm(u, axis=2) * np.linalg.norm(v, axis=2) * np.linalg.norm(w, axis=2))


@pytest.mark.filterwarnings("ignore:All-NaN slice")   # the triple with the twin for a corner
def test_chiral_triples_match_a_numpy_reading():
    rng = np.random.default_rng(7)
    n_s, n_m = 200, 8
    xyz = rng.normal(size=(1, n_m, 3)) * 100.0 + rng.normal(size=(n_s, n_m, 3)) * 20.0
    ok = rng.random((n_s, n_m)) > 0.2
    m, twin = 0, 5
    tri = np.array([[1, 2, 3], [2, 3, 4], [1, 5, 6], [3, 6, 7]], dtype=np.int64)
    seen, median, low, tells = chiral_triples(xyz, ok, m, twin, tri, 0.05)

    rows = ok[:, m]
    vol = _volumes(xyz[rows], xyz[rows, m], tri)
    both_seen = ok[rows][:, tri].all(axis=2)
    vol[~both_seen] = np.nan
    np.testing.assert_array_equal(seen, both_seen.sum(axis=0))
    np.testing.assert_allclose(median, np.nanmedian(vol, axis=0), rtol=1e-12)
    sign = np.sign(np.nanmedian(vol, axis=0))
    np.testing.assert_allclose(low, np.nanquantile(sign * vol, 0.05, axis=0), rtol=1e-12)
    at = ok[rows, twin]
    other = _volumes(xyz[rows][at], xyz[rows][at, twin], tri)
    expect = np.nanquantile(np.minimum(sign * vol[at], -sign * other), 0.05, axis=0)
    expect[(tri == twin).any(axis=1)] = -np.inf       # the twin a corner: it cannot tell
    np.testing.assert_allclose(tells, expect, rtol=1e-12)
    assert np.isneginf(tells[2]) and np.isfinite(tells[[0, 1, 3]]).all()


def test_a_twin_seen_too_rarely_tells_nothing():
    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(50, 6, 3)) * 100.0
    ok = np.ones((50, 6), dtype=bool)
    ok[9:, 5] = False                                  # the twin in 9 frames: fewer than 10
    tells = chiral_triples(xyz, ok, 0, 5, np.array([[1, 2, 3]], dtype=np.int64), 0.05)[3]
    assert np.isneginf(tells).all()


def test_pair_distance_stats_match_numpys_medians():
    from gazepipe.stages.clean.kernels import pair_distance_stats

    rng = np.random.default_rng(11)
    n_s, n_m = 300, 6
    xyz = rng.normal(size=(1, n_m, 3)) * 200.0 + rng.normal(size=(n_s, n_m, 3)) * 5.0
    ok = rng.random((n_s, n_m)) > 0.3
    ok[:, 4] &= np.arange(n_s) < 40                  # marker 4 with marker 0 in fewer than half of 0's frames
    body = np.array([True, True, True, True, True, False])
    median, spread = pair_distance_stats(xyz, ok, body)
    for m in range(5):
        for j in range(5):
            both = ok[:, m] & ok[:, j]
            d = np.linalg.norm(xyz[both, m] - xyz[both, j], axis=1)
            if j == m or both.sum() < max(10, ok[:, m].sum() // 2):
                assert np.isnan(median[m, j])
                continue
            assert median[m, j] == pytest.approx(np.median(d), rel=1e-12)
            assert spread[m, j] == pytest.approx(1.4826 * np.median(np.abs(d - np.median(d))), rel=1e-12)
    assert np.isnan(median[:, 5]).all() and np.isnan(median[5]).all()      # no body marker: no distances
    assert np.isnan(median[0, 4]) and np.isfinite(median[4, 0])             # judged from each end's frames
