"""The filler's compiled kernels (model candidates, take statistics) against the array arithmetic they stand for."""

import numpy as np
import pytest

from gazepipe.stages.clean.model_kernels import centred_weighted, local_coords, training_coords
from gazepipe.stages.geometry import frame_from_points


def _training(seed: int = 0, n: int = 300, k: int = 7) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-100.0, 100.0, (1, k, 3)) + rng.normal(0.0, 20.0, (n, k, 3)) + rng.normal(0, 400, (n, 1, 3))


def test_moving_frame_coordinates_are_the_triads_rotation_of_the_points():
    """Each frame's points in the Gram–Schmidt frame of three of them, about their centroid: rotᵀ (x − c)."""
    xt = _training()
    pick = np.array([1, 3, 4])
    rot = frame_from_points(xt[:, 1], xt[:, 3], xt[:, 4])
    want = np.einsum("nkj,nji->nki", xt - xt[:, pick].mean(axis=1, keepdims=True), rot)
    got = local_coords(xt, pick)
    assert np.abs(got - want).max() < 1e-10
    # a rigid motion of the whole set leaves the coordinates where they were
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.abs(local_coords(xt @ turn.T + 250.0, pick) - got).max() < 1e-9


@pytest.mark.parametrize("body_frame", [True, False])
def test_training_coordinates_and_deviations_are_numpys_to_the_bit(body_frame):
    """The lab- and body-frame coordinates, their means over the frames and the weighted deviations: the same
    bits as numpy's mean and arithmetic (the component counts depend on them)."""
    xt = _training(1)
    n, k = xt.shape[:2]
    picks = np.array([[-1, -1, -1], [0, 2, 5]])
    coords = training_coords(xt, picks, body_frame)
    lab = xt - xt[:, :-1].mean(axis=1, keepdims=True) if body_frame else xt
    assert np.array_equal(coords[0], lab.reshape(n, 3 * k))
    assert np.array_equal(coords[1], local_coords(xt, picks[1]).reshape(n, 3 * k))
    weights = np.random.default_rng(2).uniform(0.01, 1.0, (2, 3 * k))
    mean, z = centred_weighted(coords, weights)
    assert np.array_equal(mean, coords.mean(axis=1))
    assert np.array_equal(z, (coords - coords.mean(axis=1)[:, None]) * weights[:, None])


def _gappy(seed: int, n_t: int = 700, n_m: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Positions (T, M, 3) mm with gaps (NaN where not valid) and the valid mask: one marker measured
    throughout, one never twice in a row, one only a few frames, the rest with random gaps."""
    rng = np.random.default_rng(seed)
    xyz = np.cumsum(rng.normal(0.0, 3.0, (n_t, n_m, 3)), axis=0) + rng.normal(0.0, 0.2, (n_t, n_m, 3))
    valid = rng.random((n_t, n_m)) > 0.15
    valid[:, 0] = True
    valid[:, 1] = np.arange(n_t) % 2 == 0
    valid[:, 2] = False
    valid[100:108, 2] = True
    return np.where(valid[..., None], xyz, np.nan), valid


@pytest.mark.parametrize("seed", [0, 1])
def test_step_statistics_are_numpys_to_the_bit(seed):
    """Each marker's steps between consecutive measured frames: count, 99th percentile, largest."""
    from gazepipe.stages.clean.kernels import step_statistics
    from gazepipe.stages.geometry import norm3

    xyz, valid = _gappy(seed)
    count, p99, top = step_statistics(xyz, valid)
    for m in range(valid.shape[1]):
        both = valid[1:, m] & valid[:-1, m]
        steps = norm3(xyz[1:, m] - xyz[:-1, m])[both]
        assert count[m] == steps.size
        assert top[m] == (steps.max() if steps.size else 0.0)
        if steps.size >= 10:
            assert p99[m] == np.percentile(steps, 99)
        else:
            assert np.isnan(p99[m])


@pytest.mark.parametrize("step", [1, 3])
def test_third_difference_mads_are_numpys_to_the_bit(step):
    """The noise statistic: median absolute deviation of the third differences over runs of four measured
    frames, evenly spaced; NaN for a marker with too few runs."""
    from gazepipe.stages.clean.kernels import third_difference_mads

    xyz, valid = _gappy(2)
    n_t = valid.shape[0]
    mads = third_difference_mads(xyz, valid, step, 20)
    for m in range(valid.shape[1]):
        starts = np.arange(0, n_t - 3, step)
        ok = valid[starts, m] & valid[starts + 1, m] & valid[starts + 2, m] & valid[starts + 3, m]
        lag = [xyz[starts[ok] + i, m] for i in range(4)]
        d3 = lag[3] - 3.0 * lag[2] + 3.0 * lag[1] - lag[0]
        if ok.sum() < 20:
            assert np.isnan(mads[m]).all()
        else:
            assert np.array_equal(mads[m], np.median(np.abs(d3 - np.median(d3, axis=0)), axis=0))


@pytest.mark.parametrize(("n_t", "step"), [(15, 1), (700, 1), (3000, 2), (9000, 7)])
def test_distance_moments_are_the_array_codes_to_the_bit(n_t, step):
    """Count, mean and spread of each candidate's distance to the marker over the frames where both count, as
    the array code summed them (frames contiguous: numpy's pairwise sum) — the mates and links chosen from them
    hinge on exact ties."""
    from gazepipe.stages.clean.kernels import distance_moments, distances

    xyz, valid = _gappy(3, n_t=n_t, n_m=6)
    own = valid[:, 3] & (np.arange(n_t) % 5 != 0)
    cand = np.array([0, 1, 2, 4, 5], dtype=np.int64)
    lo, hi = 3, n_t - 2
    count, mu, sd = distance_moments(xyz, valid, own, 3, cand, lo, hi, step)
    d, both = distances(xyz, valid, own, 3, cand, lo, hi, step)
    d, both = d.T, both.T
    n = both.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        want_mu = np.where(both, d, 0.0).sum(axis=0) / n
        want_sd = np.sqrt(np.where(both, (d - want_mu) ** 2, 0.0).sum(axis=0) / n)
    assert np.array_equal(count, n)
    assert np.array_equal(mu, want_mu, equal_nan=True)
    assert np.array_equal(sd, want_sd, equal_nan=True)
    assert np.isnan(mu[cand == 2]).all() == (n[cand == 2] == 0).all()
