"""Tests of the clean stage: filter design, gap-respecting low-pass, stabilisation, rest detection, cropping."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import signal

from gazepipe.errors import StageError
from gazepipe.model import Markers, MarkerSet, Segment
from gazepipe.stages.clean.filters import lowpass_runs, zero_phase_sos
from gazepipe.stages.clean.rests import crop_bounds, rest_periods
from gazepipe.stages.clean.stabilise import stabilise
from gazepipe.stages.clean.stage import CleanParams, clean_markers

NOISE = 0.5   # mm, per coordinate
THRESH = 6.0  # mm/s, Pejsa's rest threshold (the default)

SUBJECT = {   # lab positions (mm, z up) of the subject markers in the still pose, relative to the root
    "SACR": [0, 0, 0], "PEL1": [0, 120, 30], "PEL2": [0, -120, 30], "PEL3": [-100, 0, 60],
    "SPN1": [-80, 60, 300], "SPN2": [-80, -60, 300], "SPN3": [-90, 0, 420],
    "HFL": [60, 70, 700], "HFR": [60, -70, 700], "HBL": [-80, 70, 700], "HBR": [-80, -70, 700],
    "HTOP": [0, 0, 770],
}
MOVING = {"SPN3": 0.3, "HFL": 1.0, "HFR": 1.0, "HBL": 1.0, "HBR": 1.0, "HTOP": 1.0}   # share of the motion


def markerset() -> MarkerSet:
    segs = (Segment("pelvis", ("PEL1", "PEL2", "PEL3")), Segment("spine", ("SPN1", "SPN2", "SPN3"), "pelvis"),
            Segment("head", ("HFL", "HFR", "HBL", "HBR", "HTOP"), "spine"))
    return MarkerSet(path="markerset.toml", up_axis="z", units="mm", root="SACR", target="POLE",
                     clapper=("CLAP1", "CLAP2"), segments=segs)


def min_jerk(n: int, rate: float, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-jerk position s (0 → 1) over frames [a, b) and its analytic rate ds/dt (1/s), per frame."""
    t = np.arange(n) / rate
    dur = (b - a) / rate
    tau = np.clip((t - a / rate) / dur, 0.0, 1.0)
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    ds = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / dur
    return s, ds


def take(rate: float, moves: list[tuple[int, int, float]], n: int, seed: int = 0, drift=(0.0, 0.0)):
    """Subject markers still but for min-jerk moves (start frame, stop frame, amplitude mm along lab y of the
    moving markers; moves return by giving a negative amplitude). The whole body also translates by ``drift``
    (mm/s along x, y) which stabilisation must remove, and the target and clapper move all the time.

    Returns markers and the analytic mean subject speed (mm/s) after stabilisation, per frame.
    """
    rng = np.random.default_rng(seed)
    labels = list(SUBJECT) + ["POLE", "CLAP1", "CLAP2"]
    t = np.arange(n) / rate
    xyz = np.zeros((n, len(labels), 3))
    speed = np.zeros(n)
    for i, lab in enumerate(SUBJECT):
        xyz[:, i] = SUBJECT[lab]
    for a, b, amp in moves:
        s, ds = min_jerk(n, rate, a, b)
        for lab, share in MOVING.items():
            xyz[:, labels.index(lab), 1] += share * amp * s
        speed += abs(amp) * ds * sum(MOVING.values()) / len(SUBJECT)
    xyz[:, len(SUBJECT)] = np.stack([800 + 300 * np.sin(t), 500 * np.cos(0.7 * t), 1500 + 0 * t], 1)
    xyz[:, len(SUBJECT) + 1] = [500, 900, 1000]
    xyz[:, len(SUBJECT) + 2] = np.stack([500 + 40 * np.sin(3 * t), 900 + 0 * t, 1000 + 0 * t], 1)
    xyz[:, :, 0] += drift[0] * t[:, None] + 2000
    xyz[:, :, 1] += drift[1] * t[:, None] - 700
    xyz[:, :, 2] += 950
    xyz += rng.normal(0, NOISE, xyz.shape)
    return Markers(labels=labels, xyz=xyz, valid=np.ones((n, len(labels)), bool), rate_hz=rate), speed


def truth_bounds(speed: np.ndarray) -> list[tuple[int, int]]:
    """Runs of frames whose analytic speed is below the threshold (the true still frames)."""
    still = np.concatenate([[False], speed < THRESH, [False]]).astype(np.int8)
    d = np.flatnonzero(np.diff(still))
    return list(zip(d[0::2].tolist(), d[1::2].tolist(), strict=True))


P = CleanParams(remove_spikes=False)


# ------------------------------------------------------------------------------------------------ filter

@pytest.mark.parametrize("order", [2, 3])
@pytest.mark.parametrize(("fc", "fs"), [(6.0, 120.0), (6.0, 30.0), (10.0, 29.97)])
def test_corrected_cutoff_is_minus_3db_of_the_double_pass(fc, fs, order):
    """Measure the amplitude of sines after sosfiltfilt: 1/√2 at the requested cutoff."""
    sos = zero_phase_sos(fc, fs, order)
    t = np.arange(int(60 * fs)) / fs
    mid = slice(len(t) // 4, 3 * len(t) // 4)        # away from the edges

    def gain(f: float) -> float:
        y = signal.sosfiltfilt(sos, np.sin(2 * np.pi * f * t))
        x = np.sin(2 * np.pi * f * t)
        return float(np.sqrt(np.mean(y[mid] ** 2) / np.mean(x[mid] ** 2)))

    assert gain(fc) == pytest.approx(1 / np.sqrt(2), abs=0.005)
    assert gain(0.3 * fc) > 0.99
    assert gain(min(2 * fc, 0.45 * fs)) < 0.5


def test_lowpass_never_crosses_gaps():
    rng = np.random.default_rng(1)
    n = 300
    xyz = rng.normal(0, 1, (n, 2, 3))
    xyz[:, 0] += np.where(np.arange(n) < 150, 0.0, 1000.0)[:, None]  # a jump hidden inside a gap
    valid = np.ones((n, 2), bool)
    valid[140:160, 0] = False
    valid[280:292, 1] = False        # leaves an 8-sample run at the end: too short for the padding (9)
    xyz[~valid] = np.nan
    sos = zero_phase_sos(6.0, 120.0)
    out, short = lowpass_runs(xyz, valid, sos)
    pad = 3 * (2 * len(sos) + 1)
    np.testing.assert_array_equal(out[:140, 0], signal.sosfiltfilt(sos, xyz[:140, 0], axis=0, padlen=pad))
    np.testing.assert_array_equal(out[160:, 0], signal.sosfiltfilt(sos, xyz[160:, 0], axis=0, padlen=pad))
    assert np.isnan(out[140:160, 0]).all()
    assert np.abs(out[:140, 0]).max() < 5 and np.abs(out[160:, 0] - 1000).max() < 5   # no leak of the jump
    assert short == 1
    np.testing.assert_array_equal(out[292:, 1], xyz[292:, 1])


def test_clean_lowpass_at_or_above_half_the_rate_is_a_stage_error_naming_the_parameter():
    mk, _ = take(120.0, [(240, 360, 200.0)], 720)
    with pytest.raises(StageError, match=r"clean.lowpass_hz 60 Hz is not below half this take's rate \(120 Hz\)"):
        clean_markers(mk, markerset(), "gaze_shift", CleanParams(remove_spikes=False, lowpass_hz=60.0), take="t")


def test_clean_lowpass_option_filters_and_reports():
    mk, _ = take(120.0, [(240, 360, 200.0)], 720)
    raw = clean_markers(mk, markerset(), "gaze_shift", P)
    lp = clean_markers(mk, markerset(), "gaze_shift", CleanParams(remove_spikes=False, lowpass_hz=6.0))
    assert lp.qc["lowpass"]["cutoff_hz"] == 6.0 and lp.qc["lowpass"]["runs_unfiltered"] == 0
    # high-frequency noise drops: sample-to-sample jitter of a still marker
    j_raw = np.std(np.diff(raw.markers.xyz[-100:, 1], axis=0))
    j_lp = np.std(np.diff(lp.markers.xyz[-100:, 1], axis=0))
    assert j_lp < 0.2 * j_raw


# ------------------------------------------------------------------------------------------------ stabilise

def test_stabilisation_puts_root_at_origin_and_keeps_shape():
    mk, _ = take(120.0, [(240, 360, 200.0)], 720, drift=(300.0, -150.0))
    res = clean_markers(mk, markerset(), "gaze_follow", P)     # a walking subject: never at rest
    out = res.markers
    np.testing.assert_array_equal(out.xyz[:, out.index("SACR")], 0.0)
    src = mk.xyz[res.frames]
    np.testing.assert_allclose(np.linalg.norm(out.xyz[:, 3] - out.xyz[:, 7], axis=1),
                               np.linalg.norm(src[:, 3] - src[:, 7], axis=1), atol=1e-9)
    assert out.labels == mk.labels


def test_stabilise_root_missing_and_heading():
    rng = np.random.default_rng(5)
    xyz = rng.normal(0, 100, (20, 4, 3))
    xyz[5, 0] = np.nan
    out = stabilise(xyz, 0)
    assert np.isnan(out[5]).all() and np.isfinite(np.delete(out, 5, axis=0)).all()
    up = np.array([0.0, 0.0, 1.0])
    h = stabilise(xyz, 0, up, (1, 2))
    left = h[:, 1] - h[:, 2]
    ok = np.isfinite(left).all(1)
    assert ok.sum() == 19
    assert np.all(left[ok, 0] > 0) and np.allclose(left[ok, 1], 0, atol=1e-9)   # left along +X
    np.testing.assert_allclose(left[ok, 2], (xyz[ok, 1] - xyz[ok, 2])[:, 2])      # vertical untouched
    np.testing.assert_allclose(np.linalg.norm(h[ok], axis=2), np.linalg.norm(out[ok], axis=2))
    # in place: the same bits, written into the array given (the clean stage's own working copy)
    for args in [(), (up, (1, 2))]:
        work = xyz.copy()
        assert stabilise(work, 0, *args, in_place=True) is work
        assert np.array_equal(work, stabilise(xyz, 0, *args), equal_nan=True)


def test_root_marker_absent_is_stage_error():
    mk, _ = take(120.0, [(240, 360, 200.0)], 720)
    mk2 = Markers(labels=["X" + lab for lab in mk.labels], xyz=mk.xyz, valid=mk.valid, rate_hz=mk.rate_hz)
    with pytest.raises(StageError, match="SACR"):
        clean_markers(mk2, markerset(), "gaze_shift", P, path="a.c3d", take="t")


# ------------------------------------------------------------------------------------------------ rests

def test_rest_periods_merge_and_minimum():
    rate = 60.0
    v = np.full(200, 50.0)
    v[0:30] = 1.0          # 0.5 s rest
    v[40:45] = 1.0         # 5 frames: separated from the above by 10 frames = 1/6 s → not merged (< is strict)
    v[100:120] = 1.0       # 20 frames
    v[129:150] = 1.0       # gap of 9 frames < 10 → merges with the previous
    v[170:180] = 1.0       # 10 frames = 0.167 s < 0.25 s → dropped
    v[60] = np.nan
    r = rest_periods(v, rate, THRESH, 1 / 6, 0.25)
    assert r == [(0, 30), (100, 150)]


def test_crop_bounds_rules():
    v = np.zeros(100)
    assert crop_bounds([(0, 20), (60, 100)], v, "gaze_shift")[0] == (20, 100)
    assert crop_bounds([(0, 20), (60, 80)], v, "gaze_shift")[0] == (20, 80)
    assert crop_bounds([(0, 20), (60, 100)], v, "gaze_follow")[0] == (20, 60)
    (b, w) = crop_bounds([(30, 50)], v, "gaze_follow")
    assert b == (0, 100) and len(w) == 2
    # a gaze shift whose second rest was hidden: kept whole, with a warning (gaze_map leaves it out), not failed
    (b, w) = crop_bounds([(0, 20)], v, "gaze_shift")
    assert b == (0, 100) and len(w) == 1 and "needs two" in w[0]
    with pytest.raises(ValueError):
        crop_bounds([(0, 100)], v, "gaze_follow")


def test_rest_bounds_on_a_speed_profile():
    """A synthetic speed profile with ramps: rests end/start exactly where it crosses the threshold."""
    rate = 30.0
    v = np.concatenate([np.full(40, 2.0), np.linspace(2.0, 302.0, 31), np.full(30, 302.0),
                        np.linspace(302.0, 2.0, 31), np.full(50, 2.0)])
    below = np.flatnonzero(v < THRESH)
    first_end = int(below[below < 100].max()) + 1        # last still frame of the ramp up, + 1
    second_start = int(below[below > 100].min())
    r = rest_periods(v, rate, THRESH, 1 / 6, 0.25)
    assert r == [(0, first_end), (second_start, len(v))]
    assert crop_bounds(r, v, "gaze_shift")[0] == (first_end, len(v))
    assert crop_bounds(r, v, "gaze_follow")[0] == (first_end, second_start)


# Markers with 0.5 mm noise (the stabilised speed sees the root's noise too) against the noise-free analytic
# speed's threshold crossing: the speed filter's smear moves bounds by ~0.1 s (the price of a noise floor
# below the threshold, see CleanParams.rest_filter_hz); 0.15 s is the tolerance. Noise alone moves them by at
# most 1/30 s (second test).
TOL_S = 0.15


@pytest.mark.parametrize("rate", [30.0, 29.97, 120.0])
@pytest.mark.parametrize(("amp", "dur"), [(120.0, 0.6), (250.0, 1.1)])
def test_gaze_shift_crop_bounds(rate, amp, dur):
    n = int(6 * rate)
    a = int(1.5 * rate)
    mk, speed = take(rate, [(a, a + int(dur * rate), amp), (int(4.5 * rate), int((4.5 + dur) * rate), -amp)], n,
                     seed=3)
    res = clean_markers(mk, markerset(), "gaze_shift", P)
    truth = truth_bounds(speed)
    tol = TOL_S * rate
    assert len(res.rests) == 3
    for (ga, gb), (ta, tb) in zip(res.rests, truth, strict=True):
        assert abs(ga - ta) <= tol and abs(gb - tb) <= tol
    assert abs(res.crop[0] - truth[0][1]) <= tol and abs(res.crop[1] - truth[1][1]) <= tol
    assert abs(res.crop[0] - truth[0][1]) <= max(1, round(rate / 30))   # refined: within 1/30 s
    assert res.markers.n_frames == res.crop[1] - res.crop[0] == len(res.frames)
    assert res.markers.first_frame == mk.first_frame + res.crop[0]
    np.testing.assert_array_equal(res.frames, np.arange(*res.crop))
    assert res.qc["crop"] == list(res.crop) and res.qc["rests"] == [list(r) for r in res.rests]
    # the neutral frames are the first rest, uncropped
    assert res.neutral is not None and res.neutral.n_frames == res.rests[0][1] - res.rests[0][0]
    # the noise floor stays below the threshold away from the movements
    far = np.convolve(speed > 0, np.ones(int(rate)), mode="same") == 0
    assert np.nanmax(res.speed_mm_s[far]) < 0.9 * THRESH


def test_a_whole_body_step_is_motion():
    """Rests are the subject still in the room (SPEC §3.2): a whole-body step of 40 mm right after the gaze
    shift (the markers still relative to each other, 30–60 mm/s in the room) is motion, so the second rest
    starts after the step and the crop runs to its end, instead of a short "rest" during the step ending it."""
    rate = 29.97
    n = int(8 * rate)
    a, b = int(1.5 * rate), int(2.3 * rate)
    mk, _ = take(rate, [(a, b, 150.0)], n, seed=4)
    step1 = b + int(1.3 * rate)
    s, _ = min_jerk(n, rate, b, step1)
    xyz = mk.xyz.copy()
    xyz[:, : len(SUBJECT), 0] += 40.0 * s[:, None]          # the whole subject, not the target or clapper
    res = clean_markers(Markers(labels=mk.labels, xyz=xyz, valid=mk.valid, rate_hz=rate), markerset(),
                        "gaze_shift", P)
    assert len(res.rests) == 2, res.rests
    assert abs(res.rests[0][1] - a) <= 2 and res.rests[1][0] >= step1 - 8, res.rests
    assert res.crop == (res.rests[0][1], res.rests[1][1])


def test_missing_markers_do_not_end_a_rest():
    """A frame's speed is the mean over the markers present: one unfilled marker changes nothing; a stretch
    with fewer than half the subject's markers is unknown and does not split the rest around it."""
    rate = 29.97
    n = int(6 * rate)
    a = int(1.5 * rate)
    mk, speed = take(rate, [(a, a + int(0.6 * rate), 120.0), (int(4.0 * rate), int(4.6 * rate), -120.0)], n,
                     seed=5)
    full = clean_markers(mk, markerset(), "gaze_shift", P)
    xyz = mk.xyz.copy()
    one = mk.labels.index("PEL2")
    xyz[100:140, one] = np.nan                               # in the second rest, left unfilled below
    half = [mk.labels.index(lab) for lab in list(SUBJECT)[: len(SUBJECT) // 2 + 1]]
    xyz[int(3.0 * rate):int(3.3 * rate), half] = np.nan    # inside the second rest: most markers lost
    cut = Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(axis=2), rate_hz=rate)
    res = clean_markers(cut, markerset(), "gaze_shift", replace(P, max_gap_s=0.0))
    assert np.isnan(res.speed_mm_s[int(3.0 * rate) + 2:int(3.3 * rate) - 2]).all()
    assert np.isfinite(res.speed_mm_s[100:140]).all()
    assert len(res.rests) == len(full.rests) == 3
    for (ga, gb), (fa, fb) in zip(res.rests, full.rests, strict=True):
        assert abs(ga - fa) <= 1 and abs(gb - fb) <= 1
    assert abs(res.crop[0] - full.crop[0]) <= 1 and abs(res.crop[1] - full.crop[1]) <= 1


def test_a_move_hidden_by_an_occlusion_still_splits_the_rests():
    """Most markers lost across a whole move: the frames are unknown, but the subject is 120 mm from where it
    was on the other side of them, so they are not joined into one rest; the first rest ends where the
    occlusion begins (the move's onset is unseen) and the second is unchanged."""
    rate = 29.97
    n = int(6 * rate)
    a, b = int(1.5 * rate), int(1.5 * rate) + int(0.6 * rate)
    mk, _ = take(rate, [(a, b, 120.0), (int(4.0 * rate), int(4.6 * rate), -120.0)], n, seed=5)
    full = clean_markers(mk, markerset(), "gaze_shift", P)
    xyz = mk.xyz.copy()
    half = [mk.labels.index(lab) for lab in list(SUBJECT)[: len(SUBJECT) // 2 + 1]]
    xyz[a - 5:b + 5, half] = np.nan
    cut = Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(axis=2), rate_hz=rate)
    res = clean_markers(cut, markerset(), "gaze_shift", replace(P, max_gap_s=0.0))
    assert len(res.rests) == len(full.rests) == 3
    assert a - 6 <= res.crop[0] <= full.crop[0] and abs(res.crop[1] - full.crop[1]) <= 1


@pytest.mark.parametrize(("amp", "dur"), [(120.0, 0.6), (60.0, 0.5)])
def test_rest_end_refined_without_bias(amp, dur):
    """The end of a rest (a motion's onset) against the noise-free speed's first frame at the threshold, over
    ten noise draws at 29.97 Hz: the Gaussian-smoothed speed alone ends it ~2 frames early; refined, the median
    error is within half a frame and every end within one frame. The still frames themselves do not change:
    the rest starts are the unrefined ones."""
    from dataclasses import replace

    rate = 29.97
    n = int(6 * rate)
    a = int(1.5 * rate)
    raw, ref = [], []
    for seed in range(10):
        mk, speed = take(rate, [(a, a + int(dur * rate), amp), (int(4.5 * rate), int((4.5 + dur) * rate), -amp)],
                         n, seed=seed)
        truth = truth_bounds(speed)
        r0 = clean_markers(mk, markerset(), "gaze_shift", replace(P, rest_refine=False)).rests
        r1 = clean_markers(mk, markerset(), "gaze_shift", P).rests
        assert len(r0) == len(r1) == len(truth) == 3
        assert [x[0] for x in r1] == [x[0] for x in r0]
        raw += [r0[k][1] - truth[k][1] for k in (0, 1)]
        ref += [r1[k][1] - truth[k][1] for k in (0, 1)]
    assert np.median(raw) <= -1.5, raw                     # the bias being removed
    assert abs(np.median(ref)) <= 0.5 and np.abs(ref).max() <= 1, ref


def test_refinement_keeps_noise_and_motion_alone():
    """Noise alone is one rest over the whole take (nothing to refine, nothing split); motion alone has none."""
    rate = 29.97
    n = int(4 * rate)
    mk, _ = take(rate, [], n, seed=5)
    assert clean_markers(mk, markerset(), "neutral", P).rests == [(0, n)]
    moves = [(k, k + int(0.5 * rate), 150.0 * (-1) ** k) for k in range(-5, n, int(0.4 * rate))]
    mk, speed = take(rate, moves, n, seed=6)
    assert speed.min() > THRESH
    assert clean_markers(mk, markerset(), "neutral", P).rests == []


def test_refine_onset_on_a_known_speed():
    """On a noise-free smoothed quadratic-then-linear rise over a flat floor, the refined end of the rest is the
    first frame where the unsmoothed speed reaches the threshold, while the smoothed speed crosses earlier."""
    from scipy import ndimage

    from gazepipe.stages.clean.rests import refine_onset, rest_periods

    rate = 30.0
    sigma = np.sqrt(np.log(2.0)) / (2.0 * np.pi * 1.75) * rate
    t = np.arange(200, dtype=float)
    for t0 in (80.0, 80.3, 80.7):
        d = np.clip(t - t0, 0.0, None)
        true = np.where(d < 4.0, 1.5 * d * d, 24.0 + 12.0 * (d - 4.0))        # mm/s
        obs = ndimage.gaussian_filter1d(true, sigma, mode="nearest") + 2.0   # + a 2 mm/s noise floor
        want = int(np.flatnonzero(true >= THRESH)[0])
        b = rest_periods(obs, rate, THRESH, 1 / 6, 0.25)[0][1]
        assert b <= want - 1
        assert refine_onset(obs, b, sigma, THRESH, 0, len(obs)) == want


@pytest.mark.parametrize("rate", [30.0, 120.0])
def test_rest_bounds_robust_to_noise(rate):
    """Five noise draws give bounds within 1/30 s of one another (one frame at 30 Hz)."""
    n = int(6 * rate)
    a = int(1.5 * rate)
    moves = [(a, a + int(0.8 * rate), 150.0), (int(4.5 * rate), int(5.3 * rate), -150.0)]
    bounds = np.array([[b for r in clean_markers(take(rate, moves, n, seed=s)[0], markerset(), "gaze_shift",
                                                 P).rests for b in r] for s in range(5)])
    assert np.ptp(bounds, axis=0).max() <= max(1, round(rate / 30))


@pytest.mark.parametrize("rate", [30.0, 120.0])
def test_gaze_follow_drops_leading_and_trailing_rest(rate):
    n = int(8 * rate)
    moves = [(int(1.0 * rate), int(2.0 * rate), 200.0), (int(2.0 * rate), int(3.5 * rate), -300.0),
             (int(3.5 * rate), int(6.5 * rate), 100.0)]
    mk, speed = take(rate, moves, n, seed=4)
    res = clean_markers(mk, markerset(), "gaze_follow", P)
    truth = truth_bounds(speed)
    assert abs(res.crop[0] - truth[0][1]) <= TOL_S * rate
    assert abs(res.crop[1] - truth[-1][0]) <= TOL_S * rate
    assert res.qc["warnings"] == []


def test_gaze_follow_without_leading_rest_warns():
    rate = 60.0
    n = 300
    mk, _ = take(rate, [(-60, 120, 400.0)], n, seed=6)
    res = clean_markers(mk, markerset(), "gaze_follow", P)
    assert res.crop[0] == 0
    assert any("leading rest" in w for w in res.qc["warnings"])


def test_gaze_shift_without_rests_fails():
    rate = 60.0
    n = 300
    moves = [(-30, 100, 300.0), (100, 200, -300.0), (200, 330, 300.0)]
    mk, _ = take(rate, moves, n, seed=7)
    with pytest.raises(StageError) as e:
        clean_markers(mk, markerset(), "gaze_shift", P, path="mocap/s.c3d", take="shift_1")
    msg = str(e.value)
    assert "\n" not in msg and "shift_1" in msg and "mocap/s.c3d" in msg and "rest" in msg


def test_target_and_clapper_do_not_count_for_rest():
    """The target and clapper move all the time in these takes; rests are still found."""
    mk, _ = take(60.0, [(120, 200, 200.0)], 400, seed=8)
    res = clean_markers(mk, markerset(), "gaze_shift", P)
    assert len(res.rests) == 2


def test_qc_and_fill_codes_on_complete_data():
    mk, _ = take(60.0, [(120, 200, 200.0)], 400, seed=9)
    res = clean_markers(mk, markerset(), "gaze_shift", P)
    assert res.fill_code.dtype == np.int8 and (res.fill_code == 0).all()
    q = res.qc["markers"]["HFL"]
    assert q["gaps"] == 0 and q["unfilled"] == 0 and q["samples"]["measured"] == 400
    assert res.qc["root_missing_frames"] == 0 and res.qc["spikes_removed"] == 0


def test_deterministic():
    mk, _ = take(60.0, [(120, 200, 200.0)], 400, seed=9)
    a = clean_markers(mk, markerset(), "gaze_shift", CleanParams(remove_spikes=False, lowpass_hz=8.0))
    b = clean_markers(mk, markerset(), "gaze_shift", CleanParams(remove_spikes=False, lowpass_hz=8.0))
    assert a.markers.xyz.tobytes() == b.markers.xyz.tobytes() and a.crop == b.crop


# ------------------------------------------------------------------------------------------------ gaps, spikes

def test_gaps_filled_and_root_gap_unfilled():
    rate = 60.0
    mk, _ = take(rate, [(120, 200, 200.0)], 400, seed=10)
    truth = mk.xyz.copy()
    xyz, valid = mk.xyz.copy(), mk.valid.copy()
    hfl, root = mk.index("HFL"), mk.index("SACR")
    valid[150:160, hfl] = False                     # short gap: filled
    valid[300:380, root] = False                    # 80 frames > max_gap_s = 1 s: stays a gap
    xyz[~valid] = np.nan
    gapped = Markers(labels=mk.labels, xyz=xyz, valid=valid, rate_hz=rate)
    res = clean_markers(gapped, markerset(), "neutral", replace(P, max_gap_s=1.0))
    code = res.fill_code
    assert np.all((code[150:160, hfl] >= 1) & (code[150:160, hfl] <= 4))
    # filled samples close to the truth (stabilised)
    err = np.linalg.norm(res.markers.xyz[150:160, hfl] - (truth[150:160, hfl] - truth[150:160, root]), axis=1)
    assert err.max() < 10.0
    # no root marker → the whole frame is unfilled and NaN
    assert (code[300:380] == 5).all() and np.isnan(res.markers.xyz[300:380]).all()
    assert not res.markers.valid[300:380].any() and res.markers.valid[:300].all()
    assert res.qc["root_missing_frames"] == 80
    q = res.qc["markers"]
    assert q["HFL"]["gaps"] == 1 and q["HFL"]["longest_gap_frames"] == 10 and q["HFL"]["unfilled"] == 0
    assert sum(q["HFL"]["samples"].values()) == 400
    assert q["SACR"]["unfilled"] == 80 and q["SACR"]["longest_gap_s"] == pytest.approx(80 / rate)
    assert sorted(g["marker"] for g in res.qc["gaps"]) == ["HFL", "SACR"]


def test_lowpass_in_clean_respects_unfilled_gaps():
    rate = 60.0
    mk, _ = take(rate, [(120, 200, 200.0)], 400, seed=11)
    xyz, valid = mk.xyz.copy(), mk.valid.copy()
    m = mk.index("HTOP")
    valid[250:330, m] = False                       # longer than 1 s: unfilled
    xyz[~valid] = np.nan
    res = clean_markers(Markers(labels=mk.labels, xyz=xyz, valid=valid, rate_hz=rate), markerset(), "neutral",
                        CleanParams(remove_spikes=False, lowpass_hz=6.0, max_gap_s=1.0))
    out = res.markers.xyz[:, m]
    assert np.isnan(out[250:330]).all() and np.isfinite(out[:250]).all() and np.isfinite(out[330:]).all()
    # the run after the gap equals filtering that run alone
    stab = xyz[:, m] - xyz[:, mk.index("SACR")]
    sos = zero_phase_sos(6.0, rate)
    np.testing.assert_allclose(out[330:], signal.sosfiltfilt(sos, stab[330:], axis=0, padlen=9), atol=1e-9)


def test_spike_removed_and_filled():
    rate = 60.0
    mk, _ = take(rate, [(120, 200, 200.0)], 400, seed=12)
    xyz = mk.xyz.copy()
    m = mk.index("HTOP")
    clean_value = xyz[300, m] - xyz[300, mk.index("SACR")]
    xyz[300, m] += [400.0, -300.0, 200.0]           # a ghost marker swap for one frame
    res = clean_markers(Markers(labels=mk.labels, xyz=xyz, valid=mk.valid, rate_hz=rate), markerset(), "neutral",
                        CleanParams())
    assert res.qc["spikes_removed"] >= 1 and res.qc["markers"]["HTOP"]["spikes_removed"] >= 1
    assert res.fill_code[300, m] != 0
    assert np.linalg.norm(res.markers.xyz[300, m] - clean_value) < 5.0


# ------------------------------------------------------------------------------------------------ sample session

from tests.helpers import SAMPLE  # noqa: E402


@pytest.fixture(scope="module")
def sample_session(tmp_path_factory):
    """The sample session with its ground truth."""
    return SAMPLE


def test_sample_gaze_shift_crop_bounds(sample_session):
    """Every gaze_shift take's crop within 2 frames of the truth (rests of the noise-free markers)."""
    from gazepipe.io.capture import read_markers
    from gazepipe.io.session_toml import load_session
    from gazepipe.synth.truth import load_truth

    ses = load_session(sample_session / "session.toml")
    shifts = [t for t in ses.takes if t.kind == "gaze_shift"]
    assert shifts
    for t in shifts:
        truth = load_truth(sample_session, t.id)["crop"]
        res = clean_markers(read_markers(t.mocap), ses.markerset, t.kind, CleanParams(), take=t.id)
        assert abs(res.crop[0] - truth[0]) <= 2 and abs(res.crop[1] - truth[1]) <= 2, (t.id, res.crop, truth)


def test_rest_speed_in_chunks_of_markers_is_the_same_bits(monkeypatch):
    """The mean speed is computed a few markers at a time (bounded memory): any chunk size, and naming the
    subject's columns instead of copying them, gives the one-chunk result to the bit, gaps and all."""
    from gazepipe.stages.clean import rests

    rng = np.random.default_rng(4)
    t = np.arange(900) / 30.0
    xyz = 1000.0 + 80.0 * np.sin(t[:, None, None] * rng.uniform(0.2, 2.0, (1, 20, 3))) \
        + rng.normal(0.0, 0.5, (900, 20, 3))
    valid = rng.random((900, 20)) > 0.05
    xyz[~valid] = np.nan
    cols = np.array([0, 2, 3, 5, 7, 8, 9, 11, 12, 13, 17, 19])
    monkeypatch.setattr(rests, "_SPEED_MARKERS", 1000)
    whole = rests.mean_speed(xyz[:, cols], valid[:, cols], 30.0, 1.75, min_share=0.5)
    for chunk in (1, 3, 8):
        monkeypatch.setattr(rests, "_SPEED_MARKERS", chunk)
        got = rests.mean_speed(xyz, valid, 30.0, 1.75, min_share=0.5, markers=cols)
        assert np.array_equal(got, whole, equal_nan=True)
    assert np.isfinite(whole).mean() > 0.9 and np.nanmax(whole) > 10.0      # moving, and mostly known
