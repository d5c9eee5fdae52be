"""The eyes stage: gating, slerp fill, cyclopean gaze, camera → head → character axes, camera estimate.

Most tests run on a synthetic take built from a known truth (``bench/_av.py``, shared with
``bench/bench_eyes.py``): a camera rotation, head rotations, a target that jumps between goals, eyes that follow
it 0.2 s late, OpenFace-like per-eye vectors with angular noise, confidence dips, blinks with junk gaze,
success == 0 rows with junk gaze, and a video clock with an offset and a rate error against the mocap clock.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench._av import (
    LAG_S,
    MOCAP_HZ,
    SAMPLE,
    VIDEO_HZ,
    Scene,
    eyes_on_truth,
    make_scene,
    sample_scene,
    tangent_noise,
    true_camera_rotation,
)
from gazepipe.errors import StageError
from gazepipe.io.tracks import EyeTrack
from gazepipe.stages.eyes.camera import (
    CAMERA_FACING_FACE,
    camera_to_character,
    camera_to_head,
    combine_camera_estimates,
    estimate_camera_rotation,
)
from gazepipe.stages.eyes.gate import cyclopean, gate
from gazepipe.stages.eyes.params import EyesParams
from gazepipe.stages.eyes.stage import eyes_take
from gazepipe.stages.geometry import angle_between, from_wxyz, slerp_vectors, to_wxyz
from tests.helpers import TESTS


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _deg(a: np.ndarray) -> np.ndarray:
    return np.rad2deg(a)



def expected_gate(eye: EyeTrack, min_conf: float = 0.8, max_gap_samples: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Raw validity and filled rows by the rules, written out plainly (rows are consecutive video frames)."""
    n = eye.n_frames
    raw = [bool(eye.success[i]) and eye.confidence[i] >= min_conf and not bool(eye.blink[i]) for i in range(n)]
    filled = [False] * n
    i = 0
    while i < n:
        if raw[i]:
            i += 1
            continue
        j = i
        while j < n and not raw[j]:
            j += 1
        if i > 0 and j < n and j - i <= max_gap_samples:
            filled[i:j] = [True] * (j - i)
        i = j
    return np.array(raw), np.array(filled)


def _track(gaze: np.ndarray, **kw) -> EyeTrack:
    n = gaze.shape[0]
    args = dict(time_s=np.arange(n) / VIDEO_HZ, frame=np.arange(1, n + 1), success=np.ones(n, bool),
                confidence=np.full(n, 0.95), gaze_left=gaze.copy(), gaze_right=gaze.copy(), blink=np.zeros(n, bool))
    args.update(kw)
    return EyeTrack(**args)


def _arc(n: int, deg_per_sample: float = 0.5) -> np.ndarray:
    """Directions moving along a great circle at constant speed (camera axes, near the lens axis)."""
    ang = np.deg2rad(-10 + deg_per_sample * np.arange(n))
    return np.stack([np.sin(ang), np.zeros(n), -np.cos(ang)], 1)


# ---------------------------------------------------------------------------------------------------------------


def test_gate_rules_exact_on_hand_made_rows():
    g = _arc(8)
    eye = _track(g, success=np.array([1, 0, 1, 1, 1, 1, 1, 1], bool),
                 confidence=np.array([0.95, 0.95, 0.8, 0.7999, 0.95, np.nan, 0.95, 0.95]),
                 blink=np.array([0, 0, 0, 0, 1, 0, 0, 0], bool))
    eye.gaze_right[6] = np.nan
    out = gate(eye, min_confidence=0.8, max_eye_gap_s=0.0)
    # 0 ok, 1 success, 2 conf exactly 0.8 passes, 3 just below fails, 4 blink, 5 NaN conf, 6 no vector, 7 ok
    assert out.reason.tolist() == [0, 1, 0, 2, 3, 2, 4, 0]
    assert out.valid.tolist() == [True, False, True, False, False, False, False, True]
    assert not out.filled.any()
    assert np.isnan(out.gaze[~out.valid]).all()
    assert out.qc["gated_share"] == pytest.approx(5 / 8)
    assert out.qc["gated_by"] == pytest.approx({"success": 1 / 8, "confidence": 2 / 8, "blink": 1 / 8,
                                                "no_gaze": 1 / 8})


def test_gate_fills_only_short_bracketed_runs():
    n = 40
    g = _arc(n)
    conf = np.full(n, 0.95)
    conf[0:2] = 0.1      # leading run: never extrapolated
    conf[5:11] = 0.1     # 6 samples = 0.1 s at 60 Hz: filled
    conf[15:22] = 0.1    # 7 samples: too long
    conf[37:] = 0.1      # trailing run
    eye = _track(g, confidence=conf)
    out = gate(eye, min_confidence=0.8, max_eye_gap_s=0.1)
    assert np.flatnonzero(out.filled).tolist() == list(range(5, 11))
    assert not out.valid[[0, 1, *range(15, 22), 37, 38, 39]].any()
    # on a constant-speed great circle, slerp between the bracketing samples reproduces the truth
    err = _deg(angle_between(out.gaze[5:11], g[5:11]))
    assert err.max() < 1e-9
    assert out.qc["filled_samples"] == 6
    assert out.qc["longest_invalid_run_s"] == pytest.approx(7 / VIDEO_HZ)
    # filled rows carry the lower confidence of their two valid neighbours
    assert np.all(out.confidence[5:11] == 0.95)


def test_gate_counts_missing_video_rows_in_the_gap():
    n = 30
    g = _arc(n)
    keep = np.ones(n, bool)
    keep[10:14] = False                 # 4 video frames never written
    conf = np.full(n, 0.95)
    conf[14:17] = 0.1                   # plus 3 low-confidence rows: 7 frames in all, longer than 0.1 s
    eye = _track(g[keep], time_s=(np.arange(n) / VIDEO_HZ)[keep], frame=np.arange(1, n + 1)[keep],
                 confidence=conf[keep], blink=np.zeros(keep.sum(), bool))
    out = gate(eye, max_eye_gap_s=0.1)
    assert not out.filled.any()
    assert out.qc["missing_video_frames"] == 4
    assert out.qc["longest_invalid_run_s"] == pytest.approx(7 / VIDEO_HZ)


def test_cyclopean_is_the_normalised_mean():
    rng = np.random.default_rng(1)
    left = _unit(rng.normal(size=(50, 3)) + [0, 0, -3])
    right = _unit(rng.normal(size=(50, 3)) + [0, 0, -3])
    c = cyclopean(left, right)
    assert np.allclose(np.linalg.norm(c, axis=1), 1.0)
    assert np.allclose(_unit((left + right) / 2), c)
    # symmetric vergence on a target straight ahead: the cyclopean vector points straight ahead
    v = np.array([[0.03, 0.0, -1.0]])
    assert np.allclose(cyclopean(_unit(v), _unit(v * [-1, 1, 1])), [[0, 0, -1]])
    left[3] = np.nan
    assert np.isnan(cyclopean(left, right)[3]).all()


def test_slerp_vectors_moves_along_the_great_arc():
    p = np.array([[1.0, 0, 0], [0, 0, 1.0]])
    q = np.array([[0, 1.0, 0], [0, 0, 1.0]])
    out = slerp_vectors(p, q, np.array([1 / 3, 0.5]))
    assert np.allclose(out[0], [np.cos(np.pi / 6), np.sin(np.pi / 6), 0])
    assert np.allclose(out[1], [0, 0, 1])


def test_slerp_vectors_antipodal_and_missing_rows():
    """An antipodal pair has no unique arc: the eye gate keeps the first vector, the video resampling (which
    must not invent a direction) gives NaN; a NaN input row is NaN either way, the other rows are unaffected."""
    from gazepipe.stages.geometry import slerp_vectors as slerp

    p = np.array([[1.0, 0, 0], [np.nan, 0, 0], [0, 1.0, 0]])
    q = np.array([[-1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    f = np.array([0.5, 0.5, 0.5])
    first, nan = slerp(p, q, f), slerp(p, q, f, antipodal="nan")
    assert np.array_equal(first[0], [1.0, 0, 0])
    assert np.isnan(nan[0]).all()
    assert np.isnan(first[1]).all() and np.isnan(nan[1]).all()
    half = [0, np.sqrt(0.5), np.sqrt(0.5)]
    assert np.allclose(first[2], half) and np.allclose(nan[2], half)
    assert slerp(np.empty((0, 3)), np.empty((0, 3)), np.empty(0)).shape == (0, 3)
    with pytest.raises(ValueError, match="antipodal"):
        slerp(p, q, f, antipodal="zero")


def test_camera_in_front_of_the_face_worked_example():
    """A camera facing the subject: R = Ry(180°) · Rz(180°) = diag(1, −1, −1), quaternion (0, 1, 0, 0)."""
    r = Rotation.from_euler("Y", 180, degrees=True) * Rotation.from_euler("Z", 180, degrees=True)
    assert np.allclose(r.as_matrix(), np.diag([1.0, -1.0, -1.0]))
    assert np.allclose(np.abs(to_wxyz(r)), np.abs(CAMERA_FACING_FACE))
    cam = np.array([[0.0, 0.0, -1.0],    # looking into the lens
                    [1.0, 0.0, 0.0],     # looking toward the image's right = the subject's left
                    [0.0, -1.0, 0.0]])   # looking toward the image's top = up
    head = camera_to_head(cam, CAMERA_FACING_FACE)
    assert np.allclose(head, [[0, 0, 1], [1, 0, 0], [0, 1, 0]])   # head: forward, left (+X), up (+Y)
    # then into the character frame: a head turned 90° to its left looks along the character's +X
    turned = to_wxyz(Rotation.from_euler("Y", 90, degrees=True))
    char = camera_to_character(cam[:1], CAMERA_FACING_FACE, turned[None, :])
    assert np.allclose(char, [[1, 0, 0]])


def test_camera_to_character_matches_the_truth_and_keeps_nan():
    sc = make_scene(3, duration_s=6.0, noise_deg=0.0)
    q = sc.joints.quat[:, 1]
    cam_dirs = sc.cam.inv().apply(sc.eye_dir_head)
    out = camera_to_character(cam_dirs, to_wxyz(sc.cam), q)
    ok = ~sc.head_missing
    assert np.allclose(out[ok], sc.eye_dir_char[ok], atol=1e-12)
    assert np.isnan(out[~ok]).all()


def test_estimated_camera_rotation_within_one_degree():
    for seed in (0, 1):
        sc = make_scene(seed, noise_deg=2.5)
        res = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock)
        err = _deg((from_wxyz(res.camera_rotation) * sc.cam.inv()).magnitude())
        assert err < 1.0, (seed, err)
        assert res.camera_source == "estimated"
        # the residual is the gaze noise's order of magnitude: not zero, not a misfit
        assert 0.3 < res.qc["camera_residual_deg"] < 4.0
        assert res.qc["camera_frames_used"] >= 100


def test_pursuit_needs_and_finds_the_eye_lag():
    """A target that never stops: the eyes trail it by 0.2 s; pairing gaze with the current target biases the
    camera rotation by degrees, pairing it with the target 0.2 s earlier does not."""
    sc = make_scene(11, noise_deg=2.5, pursuit=True)
    res = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock)
    err = _deg((from_wxyz(res.camera_rotation) * sc.cam.inv()).magnitude())
    assert err < 1.0
    assert res.qc["eye_lag_s"] == pytest.approx(LAG_S, abs=1.5 / MOCAP_HZ)
    no_lag = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock, params=EyesParams(max_lag_s=0.0))
    assert _deg((from_wxyz(no_lag.camera_rotation) * sc.cam.inv()).magnitude()) > err + 0.5


def test_estimate_camera_rotation_direct_with_outliers():
    rng = np.random.default_rng(7)
    cam = true_camera_rotation()
    tdir = _unit(rng.normal(size=(400, 3)) * [0.4, 0.25, 0.1] + [0, 0, 1])
    gaze = tangent_noise(rng, cam.inv().apply(tdir), 2.0)
    gaze[:60] = _unit(rng.normal(size=(60, 3)))                  # 15 % gross outliers
    est = estimate_camera_rotation(gaze, tdir)
    assert _deg((from_wxyz(est.quat) * cam.inv()).magnitude()) < 0.5
    assert est.n_used < 400
    with pytest.raises(ValueError, match="fixation"):
        estimate_camera_rotation(gaze[:10], tdir[:10])


def test_eyes_take_accuracy_and_no_gated_sample_leaks():
    sc = make_scene(2, noise_deg=2.5)
    res = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock)
    v = res.valid
    err = _deg(angle_between(res.eye_dir_char[v], sc.eye_dir_char[v]))
    assert np.median(err) < 2.0
    assert np.percentile(err, 99) < 6.0
    # junk (blinks 25° low, lost tracking random) would show far above this
    assert err.max() < 12.0
    err_h = _deg(angle_between(res.eye_dir_head[v], sc.eye_dir_head[v]))
    assert np.median(err_h) < 2.0

    # every valid mocap frame has two valid (measured or filled) video neighbours, by the rules written out
    raw, filled = expected_gate(sc.eye)
    ok_video = raw | filled
    tv = sc.clock.offset_s + sc.clock.ratio * sc.eye.time_s
    i0 = np.searchsorted(tv, sc.mocap_time_s, side="right") - 1
    inside = (i0 >= 0) & (i0 < len(tv) - 1)
    assert not v[~inside].any()
    assert np.all(ok_video[i0[v]] & ok_video[i0[v] + 1])
    # and every covered frame with two such neighbours and a head rotation is valid
    both = np.zeros_like(v)
    both[inside] = ok_video[i0[inside]] & ok_video[i0[inside] + 1]
    assert np.array_equal(v, both & ~sc.head_missing)
    assert np.isnan(res.eye_dir_char[~v]).all()

    # QC figures against the scene
    assert res.qc["frames_without_coverage"] == int(np.count_nonzero(~inside))
    assert res.qc["gated_share"] == pytest.approx(np.mean(~raw))
    assert res.qc["filled_samples"] == int(filled.sum())
    assert res.qc["gated_by"]["blink"] == pytest.approx(np.mean(sc.eye.blink & sc.eye.success
                                                                & (sc.eye.confidence >= 0.8)))


def test_gated_video_directions_within_two_degrees_of_truth():
    sc = make_scene(4, noise_deg=2.5)
    g = gate(sc.eye)
    err = _deg(angle_between(g.gaze[g.valid], sc.video_eye_cam[g.valid]))
    assert np.median(err) < 2.0
    assert err.max() < 12.0


def test_configured_rotation_is_used_and_checked():
    sc = make_scene(5, duration_s=20.0)
    truth = to_wxyz(sc.cam)
    res = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock, camera_rotation=truth)
    assert res.camera_source == "configured"
    assert np.allclose(res.camera_rotation, truth)
    assert res.qc["camera_residual_deg"] < 3.0
    # a wrong configured rotation shows in the residual
    wrong = to_wxyz(Rotation.from_euler("y", 10, degrees=True) * sc.cam)
    bad = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock, camera_rotation=wrong)
    assert bad.qc["camera_residual_deg"] > 6.0


def test_no_extrapolation_and_confidence_is_min_of_neighbours():
    sc = make_scene(6, duration_s=10.0, offset_s=2.0)
    res = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock, camera_rotation=to_wxyz(sc.cam))
    tv = sc.clock.offset_s + sc.clock.ratio * sc.eye.time_s
    before = sc.mocap_time_s < tv[0]
    after = sc.mocap_time_s > tv[-1]
    assert before.sum() >= 59 and after.sum() >= 29
    assert not res.valid[before | after].any()
    assert not res.covered[before | after].any() and res.covered[~(before | after)].all()
    assert np.isnan(res.confidence[before | after]).all()
    g = res.gated
    i0 = np.searchsorted(tv, sc.mocap_time_s[res.covered], side="right") - 1
    assert np.array_equal(res.confidence[res.covered], np.minimum(g.confidence[i0], g.confidence[i0 + 1]))


def test_same_inputs_give_identical_outputs():
    a = eyes_take(*_args(make_scene(8, duration_s=15.0)))
    b = eyes_take(*_args(make_scene(8, duration_s=15.0)))
    for name in ("eye_dir_char", "eye_dir_head", "valid", "confidence", "camera_rotation"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes()
    assert a.qc == b.qc


def _args(sc: Scene) -> tuple:
    return sc.eye, sc.joints, sc.mocap_time_s, sc.clock


def test_too_few_fixations_is_a_stage_error():
    sc = make_scene(9, duration_s=10.0)
    sc.eye.confidence[:] = 0.1
    with pytest.raises(StageError, match="camera rotation"):
        eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock, take="t1")
    with pytest.raises(StageError, match="mocap times"):
        eyes_take(sc.eye, sc.joints, sc.mocap_time_s[:-1], sc.clock, camera_rotation=CAMERA_FACING_FACE)


def test_params_are_honoured():
    sc = make_scene(10, duration_s=10.0)
    strict = gate(sc.eye, min_confidence=0.95, max_eye_gap_s=0.0)
    loose = gate(sc.eye, min_confidence=0.8, max_eye_gap_s=0.2)
    assert strict.valid.sum() < loose.valid.sum()
    assert strict.qc["filled_samples"] == 0
    raw, filled = expected_gate(sc.eye, 0.8, 12)
    assert np.array_equal(loose.valid, raw | filled)
    assert EyesParams().min_confidence == 0.8 and EyesParams().max_eye_gap_s == 0.1




@pytest.mark.parametrize("take", ["follow_standing_01", "follow_sitting_01"])
def test_against_the_sample_sessions_truth(take):
    sc, truth_char = sample_scene(take)
    res = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock)
    assert _deg((from_wxyz(res.camera_rotation) * sc.cam.inv()).magnitude()) < 1.0
    v = res.valid
    assert v.mean() > 0.8
    err = _deg(angle_between(res.eye_dir_char[v], truth_char[v]))
    assert np.median(err) < 2.0
    assert err.max() < 12.0


def test_combine_camera_estimates():
    truth = true_camera_rotation()
    offsets = Rotation.from_euler("xyz", [[0.5, 0, 0], [-0.5, 0, 0], [0, 0.3, 0]], degrees=True)
    quats = to_wxyz(offsets * truth)
    q, worst = combine_camera_estimates(quats, weights=np.array([1.0, 1.0, 2.0]))
    assert _deg((from_wxyz(q) * truth.inv()).magnitude()) < 0.2
    assert 0.4 < worst < 0.7
    q1, worst1 = combine_camera_estimates(quats[:1])
    assert np.allclose(np.abs(q1), np.abs(quats[0])) and worst1 < 1e-6


CORPUS_OPENFACE = TESTS / "data" / "corpus" / "openface" / "pyfeat_OpenFace_Test.csv"


def test_real_openface_file_gates_by_its_own_columns():
    import pandas as pd

    from gazepipe.io.openface import read_openface

    df = pd.read_csv(CORPUS_OPENFACE, skipinitialspace=True)
    df.columns = [c.strip() for c in df.columns]
    ok = (df["success"] == 1) & (df["confidence"] >= 0.8)
    blink = ok & (df["AU45_c"] == 1)
    g = gate(read_openface(CORPUS_OPENFACE))
    assert g.n_samples == len(df)
    assert g.qc["gated_share"] == pytest.approx(np.mean(~ok | blink))
    assert g.qc["gated_by"]["blink"] == pytest.approx(blink.mean())
    # the subject's right eye is gaze_0; where measured, the cyclopean vector is the mean of the file's two
    meas = g.valid & ~g.filled
    g0 = df[["gaze_0_x", "gaze_0_y", "gaze_0_z"]].to_numpy()
    g1 = df[["gaze_1_x", "gaze_1_y", "gaze_1_z"]].to_numpy()
    expect = _unit(_unit(g0) + _unit(g1))
    assert np.allclose(g.gaze[meas], expect[meas], atol=1e-9)


def check_generated_openface(session: Path, take: str) -> None:
    """The generator's own OpenFace CSV of ``take`` through read_openface and the eyes stage, against its truth:
    the gate keeps exactly the rows the generator marks valid, no gated-out row reaches a valid frame, the
    camera rotation is found within 1°, the eye direction within 2° median."""
    tr, eye, res = eyes_on_truth(session, take)
    sc = tr["scalars"]
    g = res.gated
    truth_valid = np.asarray(tr["eyes_valid"], dtype=bool)
    assert np.array_equal(g.valid & ~g.filled, truth_valid)
    raw, filled = expected_gate(SimpleNamespace(n_frames=truth_valid.size, success=truth_valid,
                                                confidence=np.ones(truth_valid.size),
                                                blink=np.zeros(truth_valid.size, bool)))
    assert np.array_equal(g.filled, filled)
    tv = sc["video"]["offset_s"] + sc["video"]["ratio"] * eye.time_s
    i0 = np.searchsorted(tv, tr["time_s"][res.valid], side="right") - 1
    assert np.all((raw | filled)[i0] & (raw | filled)[i0 + 1])
    assert res.qc["frames_without_coverage"] == sc["video"]["mocap_frames_without_video"]

    cam = from_wxyz(np.asarray(tr["session"]["camera_to_head_quat"]))
    assert _deg((from_wxyz(res.camera_rotation) * cam.inv()).magnitude()) < 1.0
    v = res.valid
    assert v.mean() > 0.8
    err = _deg(angle_between(res.eye_dir_char[v], tr["eye_dir_char"][v].astype(np.float64)))
    assert np.median(err) < 2.0
    assert err.max() < 10.0


@pytest.mark.parametrize("take", ["follow_standing_01", "follow_standing_02", "follow_sitting_01"])
def test_generated_openface_against_truth(take):
    check_generated_openface(SAMPLE, take)


def test_millisecond_timestamps_keep_the_nominal_rate():
    """OpenFace rounds timestamps to 1 ms: a 60 Hz track must still fill 6-frame (0.1 s) runs, a 59.94 Hz one
    must not (6 frames last 0.1001 s)."""
    n = 3000
    for rate, fills in ((60.0, True), (60000 / 1001, False)):
        conf = np.full(n, 0.95)
        conf[1000:1006] = 0.1
        eye = _track(np.tile([0.0, 0.0, -1.0], (n, 1)), time_s=np.round(np.arange(n) / rate, 3), confidence=conf)
        g = gate(eye)
        assert g.rate_hz == pytest.approx(rate, rel=1e-12)
        assert g.filled[1000:1006].all() == fills
