"""The swap references' compiled statistics against numpy's own functions on the same numbers."""

import numpy as np
import pytest

from gazepipe.stages.clean.kernels import _median_of, _quantile_of, chiral_triples
from gazepipe.stages.geometry import norm3


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


def _judged_take(seed, n_s=120, n_m=9):
    """A rigid body of ``n_m`` markers moving about, some samples missing and a few displaced, with each
    marker's references (its five nearest others) and two chiral triples."""
    from gazepipe.stages.clean.swaps import References, with_tolerances

    rng = np.random.default_rng(seed)
    body = rng.normal(size=(n_m, 3)) * 150.0
    xyz = body[None] + rng.normal(size=(n_s, n_m, 3)) * 2.0 + np.cumsum(rng.normal(size=(n_s, 1, 3)), axis=0)
    off = rng.random((n_s, n_m)) < 0.05
    xyz[off] += rng.normal(size=(int(off.sum()), 3)) * 120.0
    valid = rng.random((n_s, n_m)) > 0.1
    xyz[~valid] = np.nan
    dist = np.linalg.norm(body[:, None] - body[None], axis=2)
    index = np.argsort(dist, axis=1)[:, 1:6].astype(np.int64)
    index[0, 3:] = -1                                              # a marker with fewer references
    distance = np.take_along_axis(dist, index, axis=1)
    spread = np.full(index.shape, 1.5)
    chiral = np.stack([index[:, :3], index[:, 1:4]], axis=1)
    chiral[0] = -1
    vol = np.einsum("mjk,mjk->mj", body[chiral[..., 0]] - body[:, None],
                    np.cross(body[chiral[..., 1]] - body[:, None], body[chiral[..., 2]] - body[:, None]))
    hand = np.where(chiral[..., 0] >= 0, np.sign(vol), 0.0)
    refs = with_tolerances(References(index, distance, spread, np.full(n_m, np.inf), chiral, hand), 6.0)
    refs.tolerance[-1] = np.inf                                    # a marker never judged
    return xyz, valid, refs


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_screen_is_the_misfits_against_the_tolerances(seed):
    from gazepipe.stages.clean import swaps

    xyz, valid, refs = _judged_take(seed)
    n_m = valid.shape[1]
    worst, median = swaps._misfit(xyz, xyz, valid, np.arange(n_m), refs, exclude=None)
    with np.errstate(invalid="ignore"):
        expect = valid & (worst > refs.tolerance[None]), valid & (median > refs.tolerance[None])
    rows = np.arange(3, 100, 2)
    suspect, displaced = swaps._screen(xyz, valid, refs, rows)
    np.testing.assert_array_equal(suspect, expect[0][rows])
    np.testing.assert_array_equal(displaced, expect[1][rows])
    assert suspect.any() and displaced.any() and not suspect.all()
    assert np.isinf(worst).any()                                   # a handedness turned somewhere


def test_misfits_are_the_sorted_deviations_largest_and_lower_median():
    from gazepipe.stages.clean import swaps

    xyz, valid, refs = _judged_take(4)
    n_m = valid.shape[1]
    worst, median = swaps._misfit(xyz, xyz, valid, np.arange(n_m), refs, exclude=None)
    for s in range(0, 120, 7):
        for m in range(n_m):
            cols = refs.index[m]
            use = (cols >= 0) & valid[s, np.maximum(cols, 0)]
            d = norm3(xyz[s, m] - xyz[s, cols[use]])
            dev = np.sort(np.abs(d - refs.distance_mm[m, use]) / refs.spread_mm[m, use])
            dev = dev[np.isfinite(dev)]
            if dev.size < 2:
                assert np.isnan(median[s, m]) and np.isnan(worst[s, m])
                continue
            assert median[s, m] == dev[(dev.size - 1) // 2]
            assert worst[s, m] == dev[-1] or np.isposinf(worst[s, m])


def _vouched_by_arrays(x, trusted, refs, cols, pair):
    """:func:`gazepipe.stages.clean.swaps._vouched_for` as (n, K, R) array code."""
    from gazepipe.stages.clean.swaps import MAX_REFERENCE_SPREAD_MM, MIN_REFERENCES, _misfit

    seen = trusted.copy()
    seen[:, pair] = False
    worst = _misfit(x[:, cols], x, seen, cols, refs, exclude=None)[0]
    idx = refs.index[cols]
    steady = (idx >= 0) & (refs.spread_mm[cols] <= MAX_REFERENCE_SPREAD_MM) & ~np.isin(idx, pair)
    at = np.where(steady, idx, 0)
    d = np.linalg.norm(x[:, cols][:, :, None] - x[:, at], axis=-1)
    with np.errstate(invalid="ignore"):
        within = np.abs(d - refs.distance_mm[cols][None]) <= refs.tolerance[cols][None, :, None] \
            * refs.spread_mm[cols][None]
        tri, hand = refs.chiral[cols], refs.handedness[cols]
        o = x[:, cols][:, :, None]
        u, v, w = (x[:, tri[..., i]] - o for i in range(3))
        vol = np.einsum("nkjc,nkjc->nkj", u, np.cross(v, w)) / (np.linalg.norm(u, axis=-1)
                                                                 * np.linalg.norm(v, axis=-1)
                                                                 * np.linalg.norm(w, axis=-1))
        corners = seen[:, tri].all(axis=-1) & (tri >= 0).all(axis=-1) & (hand != 0)
        kept = (corners & (np.abs(vol) >= 0.05) & (np.sign(vol) == hand)).any(axis=-1)
        placed = ((within & steady[None] & seen[:, at]).sum(axis=2) >= MIN_REFERENCES) | kept
        return (worst <= refs.tolerance[cols][None]) & placed


@pytest.mark.parametrize("seed", [0, 3])
def test_what_vouches_for_a_reference_matches_an_array_reading(seed):
    from gazepipe.stages.clean.swaps import _vouched_for

    xyz, valid, refs = _judged_take(seed)
    cols = np.array([1, 2, 4, 6, 8], dtype=np.int64)
    got = _vouched_for(xyz, valid, refs, cols, [3, 5])
    np.testing.assert_array_equal(got, _vouched_by_arrays(xyz, valid, refs, cols, [3, 5]))
    assert got.any() and not got.all()


def test_twins_scores_are_the_median_difference_of_sorted_distances():
    from gazepipe.stages.clean.kernels import twin_scores

    rng = np.random.default_rng(9)
    n_m = 8
    d = rng.random((n_m, n_m)) * 300.0
    d[rng.random((n_m, n_m)) < 0.2] = np.nan
    np.fill_diagonal(d, np.nan)
    known = np.isfinite(d)
    score = twin_scores(d, known, 2)
    for m in range(n_m):
        for q in range(n_m):
            both = known[m] & known[q]
            both[[m, q]] = False
            if not known[m, q] or both.sum() < 2:
                assert np.isposinf(score[m, q])
            else:
                assert score[m, q] == np.median(np.abs(np.sort(d[m, both]) - np.sort(d[q, both])))


@pytest.mark.parametrize("kind", ["ties", "sorted", "reversed", "long"])
def test_order_statistics_of_awkward_orders_are_numpys(kind):
    rng = np.random.default_rng(len(kind))
    for n in (1, 2, 3, 8, 33) if kind != "long" else (999, 2000):
        values = {"ties": rng.integers(0, 3, size=n).astype(float), "sorted": np.sort(rng.normal(size=n)),
                  "reversed": np.sort(rng.normal(size=n))[::-1].copy(), "long": rng.normal(size=n)}[kind]
        assert _median_of(values.copy(), n) == np.median(values)
        for q in (0.0, 0.05, 0.5, 0.95, 1.0):
            assert _quantile_of(values.copy(), n, q) == np.quantile(values, q)
