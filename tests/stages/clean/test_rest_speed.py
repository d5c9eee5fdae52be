"""The clean stage's rest speed: it records the trace its rests and crop were found on (``rest_speed``), so the
report plots what the stage used instead of recomputing it (SPEC §7); a marker's leap from its rigid cluster (a
label exchange, a ghost) is no speed, so crops survive every hazard at once."""

from __future__ import annotations

import io
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from gazepipe.dag import run_pipeline
from gazepipe.io.session_toml import load_session
from gazepipe.pipeline.events import EventLog


def test_the_rest_speed_trace_is_the_subjects_speed_on_every_frame_of_the_take(tiny_session, tmp_path):
    out = tmp_path / "out"
    summary = run_pipeline([load_session(tiny_session / "session.toml")], out, executor="serial", until="clean",
                           log=EventLog(fmt="json", stream=io.StringIO()))
    assert summary.exit_code == 0, [o.error for o in summary.failed]
    table = pq.read_table(out / "takes" / "tiny" / "t0" / "rest_speed.parquet")
    assert table.column("frame").to_pylist() == list(range(90))          # the uncropped take: 90 frames
    speed = table.column("speed_mm_s").to_numpy(zero_copy_only=False)
    # the tiny subject sways 20 mm along (1, 0.5, 0) at 0.3 Hz (tests/conftest.py tiny_motion): its markers'
    # mean speed is 20·2π·0.3·√1.25·|cos(2π·0.3·t + φ)| mm/s; the phase comes from the seed, so compare the
    # trace's shape through its peak (the stage smooths at rest_filter_hz = 1.75 Hz, far above 0.3 Hz)
    inner = speed[10:-10]
    assert np.isfinite(inner).all()
    peak = 20 * 2 * np.pi * 0.3 * np.sqrt(1.25)
    assert abs(np.max(inner) - peak) < 0.1 * peak, (np.max(inner), peak)
    assert np.min(inner) < 0.3 * peak     # it slows down at each end of the sway


def test_the_crop_survives_every_hazard_at_once(tmp_path):
    """A generated 16 s gaze_follow take with every hazard at once (label swaps, occlusion bursts, a clapper
    hazard, 1-3 s occlusions of trunk and neck markers, dense gaps, ghost spikes), cleaned alone (too short to
    judge its swaps by itself: none is repaired): two chest markers exchange names inside the final rest, and
    the leap of each no longer splits it (it ended the crop 57 frames late). Both crop bounds are within 3
    frames of the truth."""
    from gazepipe.io.capture import read_markers
    from gazepipe.stages.clean.stage import CleanParams, clean_markers
    from gazepipe.synth import SynthConfig, generate_session

    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=16.0, shift_targets=(), neutral_s=2.0,
                      face_takes=(), head_camera=False, spikes_per_marker_min=1.0, long_gaps=4,
                      gaps_per_marker_min=3.0, label_swaps=2, occlusion_bursts=3, clap_hazards=1.0)
    folder = generate_session(tmp_path / "s", seed=1, config=cfg)
    session = load_session(folder / "session.toml")
    take = session.take("follow_standing_01")
    truth = np.load(folder / "truth" / "follow_standing_01.npz")
    crop = json.loads((folder / "truth" / "truth.json").read_text())["takes"]["follow_standing_01"]["crop"]
    assert len(truth["swaps"]) == 2 and truth["spike_mask"].any()
    res = clean_markers(read_markers(take.mocap), session.markerset, take.kind, CleanParams(), take=take.id)
    assert "swaps_not_checked" in res.qc
    assert abs(res.crop[0] - crop[0]) <= 3 and abs(res.crop[1] - crop[1]) <= 3, (res.crop, crop)


def test_a_markers_leap_from_its_cluster_is_no_speed():
    """Two of a rigid cluster's four still markers exchange names for 20 frames (a leap of 120 mm each way, in
    and out): their samples at the leaps are left out of the speed (position_jumps), so the subject's mean
    speed stays still; without the cluster it leaps past the rest threshold."""
    from gazepipe.stages.clean.rests import position_jumps, rest_speed

    rng = np.random.default_rng(0)
    ref = np.array([[60.0, 0, 0], [-60, 0, 0], [0, 80, 0], [0, 0, 90]])
    xyz = np.broadcast_to(ref, (120, 4, 3)) + rng.normal(0.0, 0.5, (120, 4, 3))
    xyz[50:70, [0, 1]] = xyz[50:70, [1, 0]]
    present = np.ones((120, 4), bool)
    jumps = position_jumps(xyz, present, [[0, 1, 2, 3]])
    assert np.flatnonzero(jumps.any(axis=1)).tolist() == [50, 70] and jumps[[50, 70]][:, :2].all()
    still, hidden = rest_speed(xyz, present, 30.0, 1.75, 6.0, clusters=[[0, 1, 2, 3]])
    assert np.nanmax(still) < 6.0 and not hidden.any()
    leapt, _ = rest_speed(xyz, present, 30.0, 1.75, 6.0)
    assert np.nanmax(leapt) > 6.0


def test_frames_filled_through_time_for_most_markers_are_hidden_but_keep_their_speed():
    """Six still markers; over frames 40-80 four of them are filled through time (``seen`` False: a PCHIP or
    linear fill across an occlusion of most of the body), the other two measured. Their speed stays what the fills give (a best guess: the rest goes on), but those frames
    are hidden, and the crop bound that lies against them is said to be off by up to that many frames
    (:func:`hidden_at`). Two of six filled through time is no hiding."""
    from gazepipe.stages.clean.rests import hidden_at, rest_speed

    rng = np.random.default_rng(1)
    ref = rng.uniform(-100.0, 100.0, (6, 3))
    xyz = np.broadcast_to(ref, (120, 6, 3)) + rng.normal(0.0, 0.5, (120, 6, 3))
    present = np.ones((120, 6), bool)
    seen = present.copy()
    seen[40:80, :4] = False
    speed, hidden = rest_speed(xyz, present, 30.0, 1.75, 6.0, seen=seen)
    assert np.isfinite(speed).all() and np.nanmax(speed) < 6.0
    assert np.flatnonzero(hidden).tolist() == list(range(40, 80))
    assert hidden_at(hidden, 40) == 40 and hidden_at(hidden, 80) == 40 and hidden_at(hidden, 90) == 0
    unseen, _ = rest_speed(xyz, present, 30.0, 1.75, 6.0)
    np.testing.assert_array_equal(unseen, speed)
    seen[40:80, 2:4] = True
    assert not rest_speed(xyz, present, 30.0, 1.75, 6.0, seen=seen)[1].any()


def test_a_motion_only_fills_through_time_show_is_hidden():
    """Two of six markers filled through time (a PCHIP fill across an occlusion of the head) glide 60 mm over
    frames 20-80 while the four seen stay still: the mean speed says the subject moves (about 10 mm/s, above
    the 6 mm/s rest threshold), but only the fills say so, and those frames are hidden (the crop bound there
    may be off). Seen markers moving the same way are motion, not hidden."""
    from gazepipe.stages.clean.rests import rest_speed

    rng = np.random.default_rng(2)
    ref = rng.uniform(-100.0, 100.0, (6, 3))
    xyz = np.broadcast_to(ref, (120, 6, 3)) + rng.normal(0.0, 0.3, (120, 6, 3))
    glide = np.clip((np.arange(120) - 20) / 60.0, 0.0, 1.0) * 60.0
    xyz[:, :2, 0] += glide[:, None]
    present = np.ones((120, 6), bool)
    seen = present.copy()
    seen[10:90, :2] = False
    speed, hidden = rest_speed(xyz, present, 30.0, 1.75, 6.0, seen=seen)
    moving = np.flatnonzero(speed >= 6.0)
    assert 25 <= moving.size and np.isin(moving, np.arange(15, 85)).all()
    assert hidden[moving].all() and not hidden[:10].any() and not hidden[90:].any()
    speed2, hidden2 = rest_speed(xyz, present, 30.0, 1.75, 6.0, seen=present)
    np.testing.assert_array_equal(speed2, speed)
    assert not hidden2.any()


def test_median_across_markers_is_nanmedians():
    import warnings

    from gazepipe.stages.clean.rests import _median_across

    rng = np.random.default_rng(5)
    for k in (2, 3, 4, 7):
        a = rng.normal(size=(400, k))
        a[rng.random(a.shape) < 0.35] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)        # all-NaN rows: NaN, as both give
            expect = np.nanmedian(a, axis=1)
        np.testing.assert_array_equal(_median_across(a), expect)


@pytest.mark.parametrize("n", [1, 3, 7, 8, 9, 16, 127, 128, 129, 300, 1031])
def test_the_compiled_sum_is_numpys_pairwise_sum_to_the_bit(n):
    from gazepipe.stages.clean.kernels import _pairwise_sum

    rng = np.random.default_rng(n)
    rows = rng.normal(size=(6, n)) * 10.0 ** rng.integers(-6, 6, size=(6, n))
    for row, expect in zip(rows, np.sum(rows, axis=-1), strict=True):
        assert _pairwise_sum(np.r_[7.0, row], 1, n) == expect


def test_the_onset_fit_is_the_exhaustive_array_search():
    """:func:`onset_fit` picks the shape, amplitude and onset numpy's per-shape argmin and strict comparison
    across shapes picked (the first at the least squared error), ties included."""
    from gazepipe.stages.clean.kernels import onset_fit

    rng = np.random.default_rng(2)
    shapes = np.abs(rng.normal(size=(4, 9, 13))) * 3.0
    shapes[2] = shapes[1]                                   # a tie across shapes: the first one wins
    amp = 6.0 * np.geomspace(1e-2, 1e2, 21)
    y = np.abs(rng.normal(size=13)) * 20.0
    q, floor = 0.3, 1.7
    best = (np.inf, 0, 0, 0)
    for ik, p in enumerate(shapes):
        g = amp[:, None, None] * p[None]
        sse = np.sum((np.sqrt(g * g + (q * floor) ** 2) + (1.0 - q) * floor - y) ** 2, axis=-1)
        ia, it = np.unravel_index(int(np.argmin(sse)), sse.shape)
        if sse[ia, it] < best[0]:
            best = (float(sse[ia, it]), int(ia), ik, int(it))
    assert onset_fit(shapes, amp, (q * floor) ** 2, (1.0 - q) * floor, y) == (best[2], best[1], best[3])
    shapes[:] = shapes[best[2]]                             # every shape the best: the first one
    assert onset_fit(shapes, amp, (q * floor) ** 2, (1.0 - q) * floor, y) == (0, best[1], best[3])


def _jumps_by_arrays(xyz, present, clusters):
    """:func:`position_jumps` as array code: numpy's nanmedian, norm and scipy's median filter."""
    import warnings

    from scipy import ndimage

    from gazepipe.stages.clean.rests import _JUMP_SIDE, JUMP_MM, JUMP_SPREAD

    out = np.zeros(present.shape, dtype=bool)
    both = present[1:] & present[:-1]
    for c in clusters:
        cols = np.asarray(c)
        ok = both[:, cols]
        rows = np.flatnonzero(ok.sum(axis=1) >= 2)
        if cols.size < 2 or rows.size == 0:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            s = np.where(ok[..., None], xyz[1:, cols] - xyz[:-1, cols], np.nan)[rows]
            med = np.nanmedian(s, axis=1)
            length = ndimage.median_filter(np.nanmedian(np.linalg.norm(s, axis=2), axis=1),
                                           size=2 * _JUMP_SIDE + 1, mode="nearest")
            dev = np.linalg.norm(s - med[:, None, :], axis=2)
        out[1 + rows[:, None], cols[None, :]] |= ok[rows] & (np.nan_to_num(dev) > JUMP_MM + JUMP_SPREAD
                                                              * length[:, None])
    return out


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_position_jumps_match_an_array_reading(seed):
    from gazepipe.stages.clean.rests import position_jumps

    rng = np.random.default_rng(seed)
    n_t, n_m = 300, 9
    xyz = np.cumsum(rng.normal(size=(n_t, 1, 3)) * 4.0, axis=0) + rng.normal(size=(n_t, n_m, 3))
    leap = rng.random((n_t, n_m)) < 0.03
    xyz[leap] += rng.normal(size=(int(leap.sum()), 3)) * 100.0
    present = rng.random((n_t, n_m)) > 0.2 * seed
    clusters = [[0, 1, 2, 3], [4, 5], [6, 7, 8], [2]]
    got = position_jumps(xyz, present, clusters)
    np.testing.assert_array_equal(got, _jumps_by_arrays(xyz, present, clusters))
    assert got.any()
