"""The gap filler decides each gap from its neighbourhood only (SPEC §3.2: cost per gap independent of the take's
length; results independent of where a take is cut), and skips the costly candidates where interpolation is
already at the noise level."""

from __future__ import annotations

import numpy as np
import pytest

from gazepipe.stages.clean.gapfill import (
    NOTE_NOISE_FLOOR,
    _GapSettings,
    fill_gaps,
    interpolation_noise_mm,
    take_statistics,
)
from tests.helpers.captures import RATE, body, hide

#: gaps of every kind the filler treats differently: short (interpolation), medium, long (frame-by-frame
#: average), two markers of one segment at once, and a marker of each swinging segment
GAPS = [(1, 700, 703), (5, 820, 835), (2, 900, 960), (3, 905, 930), (9, 1000, 1075), (6, 1100, 1107)]


def _settings(n_t: int) -> _GapSettings:
    return _GapSettings.for_take(RATE, n_t, ("rigid", "pca", "pchip", "linear"), max_gap_s=3.0, validation=True,
                                 pca_window_s=10.0, blend=True, steady_mates=True, framewise=True)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_gap_is_filled_the_same_wherever_the_take_is_cut(seed: int) -> None:
    # a 60 s take at 60 Hz; the gaps sit in its middle, and the take is cut at several places farther than the
    # filler's reach from them: every fill and record must be the same bits
    truth, measured, clusters = body(3600, seed=seed)
    xyz, valid = hide(measured, GAPS)
    stats = take_statistics(xyz, valid)
    whole = fill_gaps(xyz, valid, RATE, clusters=clusters, max_gap_s=3.0, max_error_mm=5.0, stats=stats)
    reach = _settings(xyz.shape[0]).reach
    first, last = min(s for _, s, _ in GAPS), max(e for _, _, e in GAPS)
    assert first - reach > 0 and last + reach < xyz.shape[0]      # the cuts below really cut something
    for lo, hi in [(first - reach, xyz.shape[0]), (0, last + reach), (first - reach - 37, last + reach + 11)]:
        part = fill_gaps(xyz[lo:hi], valid[lo:hi], RATE, clusters=clusters, max_gap_s=3.0, max_error_mm=5.0,
                         stats=stats)
        assert np.array_equal(part.fill_code, whole.fill_code[lo:hi])
        assert np.array_equal(part.xyz, whole.xyz[lo:hi], equal_nan=True)
        assert np.array_equal(part.error_mm, whole.error_mm[lo:hi], equal_nan=True)
        got = [(g.marker, g.start + lo, g.stop + lo, g.method, g.weights) for g in part.gaps]
        assert got == [(g.marker, g.start, g.stop, g.method, g.weights) for g in whole.gaps]
    # and the fills are right: every gap filled, within a few times the noise of the truth
    assert len(whole.gaps) == len(GAPS) and all(g.method != "unfilled" for g in whole.gaps)
    for m, s, e in GAPS:
        assert np.linalg.norm(whole.xyz[s:e, m] - truth[s:e, m], axis=1).mean() < 3.0


def test_reach_covers_every_window_the_methods_look_through() -> None:
    cfg = _settings(100_000)
    # the PCA training window (10 s), the steady-mates window (2 s) and the hidden stretches of the longest gap
    # (two of 3 s each side)
    assert cfg.reach > cfg.pca_window >= 600
    assert cfg.reach > 2 * (cfg.max_len + 2)


@pytest.mark.parametrize("sigma", [0.1, 0.5, 2.0])
def test_noise_floor_follows_the_markers_noise_while_they_move(sigma: float) -> None:
    # the body walks, turns and swings its segments: the estimate must come from the noise, not the motion.
    # Expected: 2.06 sigma (the mean error of interpolating a hidden sample from noisy anchors), within 10 %
    truth, _, _ = body(1200, seed=3)
    rng = np.random.default_rng(7)
    measured = truth + rng.normal(0.0, sigma, truth.shape)
    valid = np.ones(truth.shape[:2], dtype=bool)
    floor = interpolation_noise_mm(measured, valid)
    assert np.allclose(floor, 2.06 * sigma, rtol=0.1)
    # and it is what interpolation really makes of noise: hide every 10th sample of a still marker
    still = np.full((1200, 1, 3), 100.0) + rng.normal(0.0, sigma, (1200, 1, 3))
    mid = still[1:-1:10, 0]
    interp = (still[0:-2:10, 0] + still[2::10, 0]) / 2.0
    real = np.linalg.norm(mid - interp, axis=1).mean()
    assert real == pytest.approx(interpolation_noise_mm(still, np.ones((1200, 1), bool))[0], rel=0.15)


def test_short_gap_at_noise_level_skips_the_costly_candidates() -> None:
    # a still marker (a foot in stance): its 3-frame gap validates at the noise level by interpolation, so
    # rigid and PCA are not tried (their errors stay NaN in the record) and the fill is within the noise
    truth, measured, clusters = body(1200, seed=4)
    measured[:, 0] = 500.0 + np.random.default_rng(1).normal(0.0, 0.5, (1200, 3))
    truth[:, 0] = 500.0
    xyz, valid = hide(measured, [(0, 600, 603), (5, 600, 660)])
    res = fill_gaps(xyz, valid, RATE, clusters=clusters, max_gap_s=3.0, max_error_mm=5.0)
    short, long_ = res.gaps
    assert short.method in ("linear", "pchip")
    assert np.isnan(short.errors["pca"]) and np.isnan(short.errors["rigid"])
    assert short.reason == NOTE_NOISE_FLOOR           # and the record says why
    assert np.linalg.norm(res.xyz[600:603, 0] - truth[600:603, 0], axis=1).mean() < 1.0
    # a long gap of a moving marker still gets every candidate
    assert np.isfinite(long_.errors["pca"]) and np.isfinite(long_.errors["rigid"])
    assert long_.reason != NOTE_NOISE_FLOOR


def test_take_statistics_are_each_markers_own_whatever_the_grouping() -> None:
    # markers measured throughout are done a few at a time, the others one at a time: each marker's step limit
    # and noise floor must be what its own samples give, computed alone (the definitions, written out here)
    from gazepipe.stages.clean.gapfill import step_limits

    truth, measured, _ = body(900, seed=8)
    xyz = np.concatenate([measured, measured[:, :7] + 5.0], axis=1)          # 19 markers: more than a group
    valid = np.ones(xyz.shape[:2], bool)
    valid[100:140, 3] = valid[500:503, 15] = False
    xyz[~valid] = np.nan
    floor, limits = interpolation_noise_mm(xyz, valid), step_limits(xyz, valid)
    p99, top = np.empty(xyz.shape[1]), np.empty(xyz.shape[1])
    for m in range(xyz.shape[1]):
        d3 = xyz[3:, m] - 3 * xyz[2:-1, m] + 3 * xyz[1:-2, m] - xyz[:-3, m]
        v = d3[valid[3:, m] & valid[2:-1, m] & valid[1:-2, m] & valid[:-3, m]]
        mad = 1.4826 * np.median(np.abs(v - np.median(v, axis=0)), axis=0)
        assert floor[m] == 2 * np.sqrt(2 / np.pi) * np.sqrt(5 / 3) * np.sqrt(np.mean(mad ** 2) / 20)
        step = np.linalg.norm(xyz[1:, m] - xyz[:-1, m], axis=1)
        p99[m] = np.percentile(step[valid[1:, m] & valid[:-1, m]], 99)
        top[m] = step[valid[1:, m] & valid[:-1, m]].max()
    # and never above the fastest step measured anywhere in the take (no fill moves faster than it)
    assert np.allclose(limits, np.fmin(np.fmax(2.5 * p99, 1.5 * p99.max()), top.max()), rtol=1e-12)


def test_filling_in_place_gives_the_same_bits_and_holds_the_take_once() -> None:
    # the clean stage hands the filler its own working copy: the result must be the copy's, written into it
    truth, measured, clusters = body(1200, seed=3)
    xyz, valid = hide(measured, [(1, 300, 303), (5, 420, 435), (2, 500, 560)])
    copied = fill_gaps(xyz, valid, RATE, clusters=clusters, max_gap_s=3.0, max_error_mm=5.0)
    work = np.ascontiguousarray(xyz)
    before = work.copy()
    filled = fill_gaps(work, valid, RATE, clusters=clusters, max_gap_s=3.0, max_error_mm=5.0, in_place=True)
    assert filled.xyz is work
    assert np.array_equal(filled.xyz, copied.xyz, equal_nan=True)
    assert np.array_equal(filled.error_mm, copied.error_mm, equal_nan=True)
    assert not np.array_equal(work, before, equal_nan=True)             # the gaps were written into it
    untouched = fill_gaps(before, valid, RATE, clusters=clusters, max_gap_s=3.0, max_error_mm=5.0)
    assert np.array_equal(untouched.xyz, copied.xyz, equal_nan=True) and np.isnan(before[300:303, 1]).all()


def test_error_limits_by_marker_say_what_the_full_array_says() -> None:
    from gazepipe.stages.clean.gapfill import ErrorLimits, gap_limit

    rng = np.random.default_rng(2)
    column = rng.uniform(5.0, 80.0, 50)
    column[[9, 30, 31]] = np.nan
    full = np.full((50, 4), 5.0)
    full[:, 2] = column
    limits = ErrorLimits(5.0, {2: column})
    for m in range(4):
        for s, e in [(0, 3), (10, 12), (29, 33), (31, 32), (45, 50), (20, 21)]:
            assert gap_limit(limits, m, s, e) == gap_limit(full, m, s, e)


def _high_rate_body(rate: float, seconds: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """:func:`body`'s motion captured at ``rate`` Hz (its noise-free trajectories resampled by cubic splines, then
    0.5 mm of noise): (truth, measured, clusters)."""
    from scipy.interpolate import CubicSpline

    n_low = int(seconds * RATE) + 4
    truth_low, _, clusters = body(n_low, seed=seed)
    t = np.arange(int(seconds * rate)) / rate
    truth = CubicSpline(np.arange(n_low) / RATE, truth_low, axis=0)(t)
    rng = np.random.default_rng(seed + 100)
    return truth, truth + rng.normal(0, 0.5, truth.shape), clusters


def test_window_statistics_at_a_high_rate_are_those_of_the_whole_window() -> None:
    """A window in seconds holds 60,000 frames at 6 kHz: distance_stats reads at most WINDOW_SAMPLES evenly spaced
    ones, and its mean and spread of each marker's distance are those of every frame (to 2 % of the spread)."""
    from gazepipe.stages.clean.fill_methods import WINDOW_SAMPLES, distance_stats, sample_step

    truth, measured, _ = _high_rate_body(6000.0, 12.0)
    valid = np.ones(measured.shape[:2], dtype=bool)
    valid[30000:30050, 2] = False
    s, e, window = 30000, 30050, 12000
    cand = np.array([0, 1, 3, 5, 9], dtype=np.int64)
    mu, sd = distance_stats(measured, valid, 2, cand, s, e, window)
    assert sample_step(e - s + 2 * window, WINDOW_SAMPLES) > 1             # the window really is read sparsely
    rows = np.r_[s - window:s, e:e + window]
    d = np.linalg.norm(measured[rows][:, cand] - measured[rows][:, [2]], axis=2)
    assert np.all(np.abs(mu - d.mean(axis=0)) < 0.02 * d.std(axis=0) + 0.05)
    assert np.all(np.abs(sd - d.std(axis=0)) < 0.02 * d.std(axis=0) + 0.05)


def test_pca_trains_on_a_bounded_number_of_evenly_spaced_frames() -> None:
    """PCA's training window is in seconds: at a high rate its frames are read every k-th, at most PCA_MAX_TRAIN,
    each one where the marker and every predictor are measured."""
    from gazepipe.stages.clean.fill_methods import PCA_MAX_TRAIN, _pca_training

    _, measured, _ = _high_rate_body(3000.0, 8.0)
    valid = np.ones(measured.shape[:2], dtype=bool)
    valid[12000:12030, 4] = False
    valid[5000:5200, 7] = False
    chosen = _pca_training(measured, valid, 4, valid[:, 4], 12000, 12030, (0, 24000), 20, 12)
    assert chosen is not None
    preds, train = chosen
    assert 0.9 * PCA_MAX_TRAIN < train.size <= PCA_MAX_TRAIN
    assert (train % 6 == 0).all() and np.median(np.diff(train)) == 6     # every 6th frame, where measured
    assert valid[train, 4].all() and valid[np.ix_(train, preds)].all()


def test_short_gaps_at_a_high_rate_are_filled_right() -> None:
    """At 6 kHz (a window in seconds holds tens of thousands of frames, read at a few thousand samples) short gaps
    of 1 to 40 samples are filled within a few times the noise of the truth, each with a finite estimate, and
    most are kept under a 5 mm limit (the estimates of the swinging segments' markers run high: their edge
    velocities come from 0.2 s of curved motion, as at any rate)."""
    truth, measured, clusters = _high_rate_body(6000.0, 4.0, seed=1)
    rng = np.random.default_rng(2)
    gaps = []
    for m in range(12):
        for start in rng.choice(np.arange(1000, 23000, 200), 3, replace=False):
            gaps.append((m, int(start), int(start + rng.integers(1, 41))))
    xyz, valid = hide(measured, gaps)
    res = fill_gaps(xyz, valid, 6000.0, clusters=clusters, max_error_mm=5.0)
    assert sorted((g.marker, g.start, g.stop) for g in res.gaps) == sorted(gaps)
    filled = [g for g in res.gaps if g.method != "unfilled"]
    assert len(filled) >= 0.75 * len(gaps)
    for g in filled:
        err = np.linalg.norm(res.xyz[g.start:g.stop, g.marker] - truth[g.start:g.stop, g.marker], axis=1).mean()
        assert err < 2.5, (g.marker, g.start, g.stop, err)
        assert np.isfinite(g.error_mm) and g.error_mm > 0.5 * err
