"""Spike removal (SPEC §3.2 step 1): short glitches on any marker at any rate, and real motion left alone.

Ground truth comes from ``gazepipe.synth`` sessions with ghost-reflection spikes (15–50 mm, 1–2 frames, any
marker, the truth's ``spike_mask``) and from hand-made trajectories whose every sample is known.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gazepipe.io.capture import read_markers
from gazepipe.io.session_toml import load_markerset
from gazepipe.model import FILL_CODES, Markers, MarkerSet, Segment
from gazepipe.stages.clean.spikes import find_glitches, find_spikes, running_median
from gazepipe.stages.clean.stage import CleanParams, clean_markers
from gazepipe.synth import SynthConfig, generate_session


@pytest.fixture(scope="module", params=[30000.0 / 1001.0, 120.0], ids=["30Hz", "120Hz"])
def spiky_session(request, tmp_path_factory):
    cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=15.0, head_camera=False, face_takes=(),
                      shift_targets=((36.0, 12.0), (-72.0, -12.0)), spikes_per_marker_min=2.0,
                      rate_hz=request.param)
    return generate_session(tmp_path_factory.mktemp("spiky") / "s", seed=5, config=cfg)


def test_ghost_spikes_on_every_kind_of_marker_are_removed_and_nothing_else(spiky_session):
    """At least 95 % of the spike samples go, at most 0.1 % of the other measured samples; the spikes fall on
    the root segment's, the head's and the target's markers as on any other."""
    ms = load_markerset(spiky_session / "markerset.toml")
    spikes = caught = other = flagged = 0
    spiked_markers: set[str] = set()
    for c3d in sorted((spiky_session / "mocap").glob("*.c3d")):
        truth = np.load(spiky_session / "truth" / f"{c3d.stem}.npz")
        mk = read_markers(c3d)
        pos = {lab: i for i, lab in enumerate(mk.labels)}
        clusters = [[pos[n] for n in s.markers if n in pos] for s in ms.segments]
        found = find_spikes(mk.xyz, mk.valid, mk.rate_hz, clusters)
        spiked, measured = truth["spike_mask"], ~truth["gap_mask"]
        spikes += int(spiked.sum())
        caught += int((found & spiked).sum())
        other += int((measured & ~spiked).sum())
        flagged += int((found & measured & ~spiked).sum())
        spiked_markers.update(mk.labels[m] for m in np.nonzero(spiked.any(axis=0))[0])
    assert spikes > 50
    assert {"SACR", "PEL_L", "POLE"} & spiked_markers and any(m.startswith("H") for m in spiked_markers)
    assert caught >= 0.95 * spikes, (caught, spikes)
    assert flagged <= 0.001 * other, (flagged, other)


def _rigid_head(rate: float, seconds: float, deg_s: float) -> tuple[np.ndarray, list[list[int]]]:
    """Five head markers on a head turning back and forth about the vertical at up to ``deg_s``."""
    t = np.arange(int(seconds * rate)) / rate
    angle = np.deg2rad(deg_s) / (2 * np.pi * 0.8) * np.sin(2 * np.pi * 0.8 * t)     # peak speed deg_s
    rot = Rotation.from_euler("z", angle[:, None])
    local = np.array([[75.0, 60, 130], [-75, 60, 130], [75, -80, 130], [-75, -80, 130], [0, -10, 195]])
    xyz = np.stack([rot.apply(p) for p in local], axis=1) + [1000.0, 500.0, 1500.0]
    return xyz + np.random.default_rng(1).normal(0, 0.5, xyz.shape), [[0, 1, 2, 3, 4]]


@pytest.mark.parametrize("rate", [30.0, 60.0, 240.0])
def test_fast_head_turns_and_a_target_that_turns_sharply_are_not_spikes(rate):
    """A head turning at 500°/s, a target carried at 2 m/s that reverses at once, a clapper arm that stops dead
    at contact: real motion, no sample flagged."""
    head, clusters = _rigid_head(rate, 4.0, 500.0)
    t = np.arange(head.shape[0]) / rate
    phase = (t * 1.0) % 2.0                                              # 2 m/s out, 2 m/s back, no easing
    target = np.stack([2000.0 * np.minimum(phase, 2.0 - phase), 300 + 0 * t, 1500 + 0 * t], axis=1)
    arm = np.stack([np.full_like(t, 300.0), 0 * t, 1200 + np.clip(400.0 - 3000.0 * t, 0.0, None)], axis=1)
    xyz = np.concatenate([head, target[:, None], arm[:, None]], axis=1)
    valid = np.ones(xyz.shape[:2], dtype=bool)
    assert not find_glitches(xyz, valid, clusters).any()


def test_a_spike_that_keeps_the_cluster_distances_is_still_caught_on_a_slow_marker():
    """On a slow head, a 20 mm ghost straight up leaves the marker's path (the trajectory test); on a head
    turning at 400°/s (23 mm per frame at 30 Hz, beyond what the trajectory test may call a ghost) a two-frame
    ghost pushed away from the head's centre breaks the distances to its mates (the cluster test)."""
    head, clusters = _rigid_head(30.0, 6.0, 400.0)
    valid = np.ones(head.shape[:2], dtype=bool)
    spiked = head.copy()
    spiked[40, 4, 2] += 20.0                 # HTOP up at a turn's end, where the head is slow
    speed = np.linalg.norm(np.diff(head[:, 0], axis=0), axis=1)
    fast = int(np.argmax(speed[50:150])) + 50
    assert speed[fast] > 20.0
    out = head[fast, 0] - head[fast].mean(axis=0)
    spiked[fast:fast + 2, 0] += 20.0 * out / np.linalg.norm(out)
    found = find_glitches(spiked, valid, clusters)
    assert found[40, 4] and found[fast, 0] and found[fast + 1, 0]
    assert found.sum() == 3


def test_running_median_leaves_nans_out():
    a = np.array([1.0, np.nan, 3.0, 100.0, 5.0, np.nan, 7.0])
    med, count = running_median(a[:, None], 2)
    assert count[:, 0].tolist() == [2, 3, 4, 3, 4, 3, 2]
    assert med[0, 0] == 2.0 and med[2, 0] == 4.0 and med[3, 0] == 5.0 and med[6, 0] == 6.0


def _tiny_take(rate: float = 30.0) -> tuple[Markers, MarkerSet]:
    """A still pelvis (root SACR and three markers) and a head that turns between still spells at both ends."""
    head, _ = _rigid_head(rate, 5.0, 100.0)
    n = head.shape[0]
    still = (np.arange(n) < 30) | (np.arange(n) >= n - 30)
    head[still] = head[still][:1]
    pelvis = np.array([[1000.0, 500.0, 1000.0], [1130.0, 540.0, 1050.0], [870.0, 540.0, 1050.0],
                       [1000.0, 395.0, 1070.0]])
    xyz = np.concatenate([np.broadcast_to(pelvis, (n, 4, 3)), head], axis=1)
    xyz = xyz + np.random.default_rng(3).normal(0, 0.5, xyz.shape)
    labels = ["SACR", "PEL_L", "PEL_R", "PEL_B", "H1", "H2", "H3", "H4", "HTOP"]
    ms = MarkerSet(path="markerset.toml", up_axis="z", units="mm", root="SACR", target=None, clapper=(),
                   segments=(Segment("pelvis", ("PEL_L", "PEL_R", "PEL_B")),
                             Segment("head", ("H1", "H2", "H3", "H4", "HTOP"), parent="pelvis")))
    return Markers(labels=labels, xyz=xyz, valid=np.ones(xyz.shape[:2], bool), rate_hz=rate), ms


def test_clean_marks_removed_spikes_fills_them_and_counts_them():
    mk, ms = _tiny_take()
    truth = mk.xyz.copy()
    mk.xyz[70, 8] += [0.0, 25.0, 0.0]
    res = clean_markers(mk, ms, "gaze_follow", CleanParams())
    row = int(np.flatnonzero(res.frames == 70)[0])
    assert res.spike[row, 8] and res.spike.sum() == 1
    assert res.fill_code[row, 8] not in (FILL_CODES["measured"], FILL_CODES["unfilled"])
    assert res.qc["markers"]["HTOP"]["spikes_removed"] == 1 and res.qc["spikes_removed"] == 1
    # the refilled sample is back near the truth (positions are root-relative after stabilisation)
    back = res.markers.xyz[row, 8] - res.markers.xyz[row, 0]
    assert np.linalg.norm(back - (truth[70, 8] - truth[70, 0])) < 3.0
    off = clean_markers(mk, ms, "gaze_follow", CleanParams(remove_spikes=False))
    assert not off.spike.any() and off.fill_code[row, 8] == FILL_CODES["measured"]


@pytest.mark.parametrize("block", [7, 50, 333])
def test_spike_search_in_blocks_of_frames_is_the_same_bits(spiky_session, monkeypatch, block):
    """The per-frame tests run in blocks of frames (bounded memory for long takes) with margins as wide as their
    windows: any block size gives exactly the mask of one block holding the whole take, on real-looking takes with
    ghosts, gaps and fast motion."""
    from gazepipe.stages.clean import spikes

    folder = spiky_session
    ms = load_markerset(folder / "markerset.toml")
    for c3d in sorted((folder / "mocap").glob("follow_*.c3d")):
        mk = read_markers(c3d, default_units=ms.units)
        pos = {lab.split(":")[-1]: i for i, lab in enumerate(mk.labels)}
        clusters = [[pos[n] for n in s.markers if n in pos] for s in ms.segments]
        valid = mk.valid & np.isfinite(mk.xyz).all(axis=2)
        monkeypatch.setattr(spikes, "_BLOCK_FRAMES", 10**9)
        whole = find_spikes(mk.xyz, mk.valid, mk.rate_hz, clusters)
        excess = spikes.path_excess_mm(mk.xyz, valid, 8.0, 2.0)
        deviation = spikes.cluster_deviation(mk.xyz, valid, clusters)
        monkeypatch.setattr(spikes, "_BLOCK_FRAMES", block)
        assert mk.n_frames > block                          # at least two blocks
        assert np.array_equal(find_spikes(mk.xyz, mk.valid, mk.rate_hz, clusters), whole)
        # the test's own measure, not only its verdict: every sample's margin to the threshold, to the bit
        assert np.array_equal(spikes.path_excess_mm(mk.xyz, valid, 8.0, 2.0), excess, equal_nan=True)
        assert np.array_equal(spikes.cluster_deviation(mk.xyz, valid, clusters), deviation, equal_nan=True)
        assert whole.any()                                   # the takes do have spikes to find


def _medians_by_sorting(win, min_count):
    """Median and finite count over the last axis by numpy's sort (NaN last): the two middle values of the
    finite count averaged; NaN with fewer than ``min_count`` finite values."""
    win = np.sort(win, axis=-1)
    count = np.isfinite(win).sum(axis=-1)
    lo = np.take_along_axis(win, np.maximum(count - 1, 0)[..., None] // 2, axis=-1)[..., 0]
    hi = np.take_along_axis(win, count[..., None] // 2, axis=-1)[..., 0] if win.shape[-1] > 1 else lo
    hi = np.where(count % 2 == 1, lo, hi)
    return np.where(count >= max(min_count, 1), 0.5 * (lo + hi), np.nan), count


def _median5_network(w):
    """The five-value min/max network the running median takes first: median3(e, max(min(a, b), min(c, d)),
    min(max(a, b), max(c, d)))."""
    a, b, c, d, e = (w[..., k] for k in range(5))
    f = np.maximum(np.minimum(a, b), np.minimum(c, d))
    g = np.minimum(np.maximum(a, b), np.maximum(c, d))
    return np.maximum(np.minimum(f, g), np.minimum(e, np.maximum(f, g)))


@pytest.mark.parametrize("half", [0, 1, 2, 3, 5])
def test_running_median_is_the_sorted_windows_median_with_nans_and_infinities(half):
    rng = np.random.default_rng(half)
    a = rng.normal(size=(200, 4, 3)) * 10.0
    r = rng.random(a.shape)
    a[r < 0.15] = np.nan
    a[r > 0.98] = np.inf
    a[(r > 0.96) & (r < 0.97)] = -np.inf
    padded = np.concatenate([np.full((half, 4, 3), np.nan), a, np.full((half, 4, 3), np.nan)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1, axis=0)
    for min_count in (1, 3):
        med, count = running_median(a, half, min_count)
        expect, expect_count = _medians_by_sorting(windows, min_count)
        if half == 2:       # the network's finite middle where it finds one (an infinity among five values)
            fast = _median5_network(windows)
            expect = np.where(np.isfinite(fast), fast, expect)
            expect_count = np.where(np.isfinite(fast), 5, expect_count)
            assert (np.isfinite(fast) & ~np.isfinite(windows).all(axis=-1)).any()
        np.testing.assert_array_equal(med, expect)
        np.testing.assert_array_equal(count, expect_count)
    assert np.isnan(med).any() and np.isfinite(med).any() or half == 0     # one value cannot make three


@pytest.mark.parametrize("width", [1, 2, 4, 7, 16, 17, 300])
def test_line_medians_are_the_sorted_lines_median(width):
    from gazepipe.stages.clean.spikes import _sorted_median

    rng = np.random.default_rng(width)
    a = rng.normal(size=(50, width))
    r = rng.random(a.shape)
    a[r < 0.3] = np.nan
    a[r > 0.97] = np.inf
    med, count = _sorted_median(a, 2)
    expect, expect_count = _medians_by_sorting(a, 2)
    np.testing.assert_array_equal(med, expect)
    np.testing.assert_array_equal(count, expect_count)


def test_cluster_deviation_matches_an_array_reading():
    """Each marker's smallest departure of its distances to its cluster mates from their take medians
    (:func:`_nanmedian`; at least two mates measured), as (T, K, K) array code reads it, infinities and missing
    samples included."""
    import warnings

    from gazepipe.stages.clean.spikes import _nanmedian, cluster_deviation

    rng = np.random.default_rng(4)
    n_t, n_m = 300, 9
    xyz = rng.normal(size=(1, n_m, 3)) * 100.0 + rng.normal(size=(n_t, n_m, 3))
    valid = rng.random((n_t, n_m)) > 0.3
    xyz[rng.random((n_t, n_m)) < 0.01] = np.inf
    clusters = [[0, 1, 2, 3], [4, 5], [6, 7, 8, 1]]
    expect = np.full((n_t, n_m), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for c in clusters[0], clusters[2]:
            idx = np.array(c)
            iu, ju = np.triu_indices(idx.size, 1)
            pairs = np.linalg.norm(xyz[:, idx[iu]] - xyz[:, idx[ju]], axis=2)
            pairs[~(valid[:, idx[iu]] & valid[:, idx[ju]])] = np.nan
            e = np.full((n_t, idx.size, idx.size), np.nan)
            e[:, iu, ju] = e[:, ju, iu] = np.abs(pairs - _nanmedian(pairs, axis=0))
            expect[:, idx] = np.where(np.isfinite(e).sum(axis=2) >= 2, np.fmin.reduce(e, axis=2), np.nan)
    got = cluster_deviation(xyz, valid, clusters)
    np.testing.assert_array_equal(got, expect)
    assert np.isfinite(got).any() and np.isnan(got[:, [4, 5]]).all()
