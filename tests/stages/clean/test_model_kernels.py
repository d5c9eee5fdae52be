"""The filler's compiled model kernels against the array arithmetic they stand for."""

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
