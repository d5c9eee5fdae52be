"""The clock map under the clapper's hazards (SPEC §3.4): every clap found is a measurement with a timing
uncertainty, the map is their weighted fit with the nominal ratio as a prior, a clap is set aside only when it
disagrees with the others and the camera tolerance (never for a low detector score), and the report's clock_map
check fails when the map cannot be shown within 5 ms over the crop, naming the clap that limits it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gazepipe.io.capture import read_markers
from gazepipe.io.video import FrameReader, probe_video
from gazepipe.report.checks import Thresholds, sync_checks
from gazepipe.stages.sync.clap import Clap, mocap_claps
from gazepipe.stages.sync.clock import BOUND_SIGMAS, choose_clock, fit_clock
from gazepipe.stages.sync.qc import SyncQC
from gazepipe.stages.sync.stage import sync_take
from gazepipe.stages.sync.video import VideoClap
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.motion import _clapper_distance
from gazepipe.synth.session import CLAP_HAZARDS
from gazepipe.synth.skeleton import CLAPPER_MARKERS

MS = 1e-3


def _mc(t: float, conf: float = 1.0, sd_ms: float = 1.0) -> Clap:
    return Clap(time_s=t, frame=t * 30.0, confidence=conf, closing_speed_mm_s=2000.0, open_mm=150.0,
                shut_mm=25.0, margin_mm=1.0, timing_s=sd_ms * MS)


def _vc(t: float, conf: float = 1.0, sd_ms: float = 1.0, timed_by: str = "displacement") -> VideoClap:
    return VideoClap(time_s=t, frame=t * 60.0, confidence=conf, peak=10.0, still=1.0, window=(0, 1),
                     timed_by=timed_by, timing_s=sd_ms * MS)


OFFSET, RATIO = 2.0, 1.0005             # t_mocap = 2 + 1.0005 · t_video


def _pair(tv: float, mocap_conf: float = 1.0, video_conf: float = 1.0, sd_ms: float = 1.0) -> tuple[Clap, VideoClap]:
    return _mc(OFFSET + RATIO * tv, mocap_conf, sd_ms), _vc(tv, video_conf, sd_ms)


def _pred_sd(tv: np.ndarray, sd: np.ndarray, prior_sd: float, t: float) -> float:
    """The weighted line's standard deviation at t, written out: the inverse normal matrix."""
    w = 1.0 / sd ** 2
    m = np.array([[w.sum(), (w * tv).sum()], [(w * tv).sum(), (w * tv * tv).sum() + 1.0 / prior_sd ** 2]])
    g = np.array([1.0, t])
    return float(np.sqrt(g @ np.linalg.inv(m) @ g))


def test_two_claps_set_offset_and_ratio_and_the_bound_follows_their_timing():
    (m1, v1), (m2, v2) = _pair(1.0), _pair(50.0)
    c = choose_clock([m1, m2], [v1, v2], video_span=(0.0, 55.0), video="v.mp4")
    assert c.used == [True, True] and not c.warnings and not c.set_aside
    # the prior pulls the ratio towards 1 by (data's variance / prior's) of the way: (40 / 600 ppm)² of 500 ppm
    assert c.clock.ratio == pytest.approx(RATIO, abs=5e-6) and c.clock.offset_s == pytest.approx(OFFSET, abs=2e-4)
    # each pair timed to sqrt(1² + 1²) ms; the bound is BOUND_SIGMAS standard deviations of the fitted line (with the
    # ratio's prior of 600 ppm) at the video's far end
    sd = np.full(2, np.sqrt(2.0) * MS)
    expected = BOUND_SIGMAS * _pred_sd(np.array([1.0, 50.0]), sd, 600e-6, 55.0) * 1000.0
    assert c.bound_ms == pytest.approx(expected, rel=1e-6) and c.bound_at_s == 55.0
    assert c.limiting == 1                        # the far end leans on the nearer clap, clap 2


def test_a_low_confidence_clap_whose_timing_is_right_is_kept():
    """A second clap found with video confidence 0.19 (and mocap 0.07) but timed right sets the ratio with the
    first: no warning, the map within its bound, and 5 ms over the video where one clap and the nominal rate
    would be 25 ms off at the far end."""
    (m1, v1), (m2, v2) = _pair(1.0), _pair(50.0, mocap_conf=0.07, video_conf=0.19)
    c = choose_clock([m1, m2], [v1, v2], video_span=(0.0, 55.0), video="video/t1.mp4")
    assert c.used == [True, True] and not c.warnings
    assert c.clock.ratio == pytest.approx(RATIO, abs=5e-6) and c.bound_ms < 5.0


def test_a_bad_clap_is_set_aside_and_named():
    """Three claps, the middle one 30 ms off (a rival burst): it disagrees with the other two and any camera rate
    within tolerance, so it is set aside with one warning line naming the video and the clap, and the map rests
    on the other two."""
    pairs = [_pair(t) for t in (1.0, 25.0, 50.0)]
    pairs[1][1].time_s += 0.030
    c = choose_clock([p[0] for p in pairs], [p[1] for p in pairs], video_span=(0.0, 55.0), video="video/t2.mp4")
    assert c.set_aside == [1] and c.used == [True, False, True]
    assert len(c.warnings) == 1 and "video/t2.mp4" in c.warnings[0] and "clap 2" in c.warnings[0]
    assert "set aside" in c.warnings[0] and "\n" not in c.warnings[0]
    assert c.clock.ratio == pytest.approx(RATIO, abs=5e-6)


def test_two_claps_that_no_camera_rate_explains_set_one_aside():
    """Two claps 10 s apart whose ratio is 2,167 ppm (a frame dropped between them): beyond the 1,200 ppm cameras
    do by far more than their timing allows, so one is set aside (the less well timed), with a warning; the map
    then rests on one clap and the nominal rate, and cannot be shown within 5 ms far from it."""
    (m1, v1), (m2, v2) = _pair(1.0, sd_ms=0.8), _pair(11.0, sd_ms=1.2)
    v2.time_s -= 1.0 / 60.0
    c = choose_clock([m1, m2], [v1, v2], video_span=(0.0, 12.0), video="v.mp4")
    assert c.set_aside == [1] and c.used == [True, False] and "clap 2" in c.warnings[0]
    assert c.clock.ratio == pytest.approx(1.0, abs=1e-12) and c.limiting is None       # the nominal rate limits
    assert c.bound_ms > 5.0


def test_two_claps_a_camera_rate_explains_are_both_kept():
    """The same claps 1,000 ppm apart (a 59.94 Hz camera labelled 60): consistent, both kept. Ten seconds apart,
    their ratio (±200 ppm) is pulled a tenth of the way to the prior's 1, within the bound."""
    m1, v1 = _mc(OFFSET + 1.001 * 1.0), _vc(1.0)
    m2, v2 = _mc(OFFSET + 1.001 * 11.0), _vc(11.0)
    c = choose_clock([m1, m2], [v1, v2], video_span=(0.0, 12.0))
    assert c.used == [True, True] and not c.set_aside and c.clock.ratio == pytest.approx(1.0009, abs=2e-5)
    ends = np.array([0.0, 12.0])
    assert (np.abs(c.clock.to_mocap(ends) - (OFFSET + 1.001 * ends)) * 1000.0 <= c.bound_ms).all()


def test_one_clap_and_the_prior_bound_grows_with_distance():
    m, v = _pair(5.0, sd_ms=1.0)
    c = choose_clock([m], [v], video_span=(0.0, 45.0))
    sd_at_end = np.hypot(np.sqrt(2.0) * MS, 600e-6 * 40.0)
    assert c.clock.ratio == 1.0 and c.bound_ms == pytest.approx(BOUND_SIGMAS * sd_at_end * 1000.0, rel=1e-9)


def test_the_bound_covers_the_truth():
    """Claps timed with known uncertainties (Gaussian errors of the stated size, clap 2's three times clap 1's):
    over a thousand draws the fitted map is within its bound (BOUND_SIGMAS standard deviations: 90 %) at each
    end of the span in about 90 % of them."""
    rng = np.random.default_rng(4)
    inside = []
    for _ in range(1000):
        ratio = 1.0 + rng.uniform(-8e-4, 8e-4)
        tv = np.array([1.2, 30.0])
        sd = np.array([1.0, 3.0]) * MS
        tm = 0.5 + ratio * tv + rng.normal(0.0, sd)
        fit = fit_clock(tv, tm, sd, 600e-6)
        span = (2.5, 28.0)
        err = np.abs(fit.to_mocap(np.array(span)) - (0.5 + ratio * np.array(span))) * 1000.0
        bound = BOUND_SIGMAS * fit.sd_s(np.array(span)) * 1000.0
        inside.extend(err <= bound)
    assert 0.87 <= np.mean(inside) <= 0.93


def test_no_pair_at_all_is_an_error():
    with pytest.raises(ValueError):
        choose_clock([_mc(1.0)], [None], video_span=(0.0, 10.0))


def _record(claps: list[dict], **over) -> dict:
    used = [j + 1 for j, c in enumerate(claps) if c["used"]]
    rec = {"offset_s": 1.0, "offset_at_video_zero_s": 1.0, "ratio": 1.0, "drift_ppm": 0.0,
           "drift_ms_over_take": 0.0, "residual_ms": 0.0, "claps": claps, "frames_without_video": 0,
           "frames_decoded": 300, "video_frames": 3000, "video_span_s": [0.0, 50.0], "n_claps": len(used),
           "clock_bound_ms": 0.0, "clock_ref_s": 25.0, "clock_cov": [1e-6, 0.0, 1e-10], "clock_prior_ppm": 600.0,
           "clock_bound_sigmas": BOUND_SIGMAS, "claps_used": used, "warnings": []}
    rec.update(over)
    return rec


def _clap_record(mocap_s: float, video_s: float, used: bool = True, timed_by: str = "displacement",
                 video_ms: float = 1.0) -> dict:
    return {"mocap_s": mocap_s, "mocap_confidence": 1.0, "mocap_timing_ms": 1.0, "video_s": video_s,
            "video_confidence": 0.3, "video_match": 0.9, "video_timing_ms": video_ms, "video_timed_by": timed_by,
            "mocap_gap_frames": 0, "used": used, "set_aside": not used}


def _checks(rec: dict, crop_s: tuple[float, float] | None = None) -> dict:
    return {c.id: c for c in sync_checks(SyncQC.from_record(rec), True, 1500, 30.0, Thresholds(), crop_s)}


def test_clock_map_check_over_the_crop_fails_beyond_5_ms_naming_the_limiting_clap():
    """One clap used (clap 2 set aside): the map is known near clap 1 only. Over a crop that stays near it the
    check passes; over one reaching 40 s from it, the unmeasured ratio (600 ppm) makes the bound exceed 5 ms and
    the check fails naming the nominal rate and the clap set aside; with two claps, the limiting clap is named
    with its timing."""
    claps = [_clap_record(1.0, 0.0), _clap_record(50.0, 49.0, used=False)]
    tv = np.array([0.0])
    fit = fit_clock(tv, tv + 1.0, np.array([np.sqrt(2.0) * MS]), 600e-6)
    warn = "v.mp4: clap 2 (mocap 50.00 s, video 49.00 s) set aside: it is +30.0 ms off"
    rec = _record(claps, clock_ref_s=fit.ref_s, clock_cov=list(fit.cov), warnings=[warn])
    got = _checks(rec, crop_s=(1.5, 4.0))
    assert got["clock_map"].severity == "pass" and "over the crop" in got["clock_map"].message
    got = _checks(rec, crop_s=(1.5, 41.0))
    assert got["clock_map"].severity == "fail"
    assert "nominal rate" in got["clock_map"].message and "clap 2" in got["clock_map"].message
    assert got["clock_map"].value == pytest.approx(BOUND_SIGMAS * np.hypot(np.sqrt(2.0), 0.6 * 40.0), rel=1e-6)

    claps = [_clap_record(1.0, 0.0), _clap_record(50.0, 49.0, timed_by="burst", video_ms=9.6)]
    sd = np.array([np.sqrt(2.0), np.hypot(1.0, 9.6)]) * MS
    fit = fit_clock(np.array([0.0, 49.0]), np.array([1.0, 50.0]), sd, 600e-6)
    rec = _record(claps, clock_ref_s=fit.ref_s, clock_cov=list(fit.cov))
    got = _checks(rec, crop_s=(2.0, 48.0))
    assert got["clock_map"].severity == "fail" and "limited by clap 2" in got["clock_map"].message
    assert "burst" in got["clock_map"].message
    assert _checks(rec, crop_s=(2.0, 10.0))["clock_map"].severity == "pass"   # far from clap 2's weight


def test_clock_drift_is_skipped_when_not_measurable():
    claps = [_clap_record(1.0, 0.0), _clap_record(50.0, 49.0, used=False)]
    got = _checks(_record(claps))
    assert got["clock_drift"].severity == "skipped" and "not measurable" in got["clock_drift"].message
    claps = [_clap_record(1.0, 0.0), _clap_record(50.0, 49.0)]
    assert _checks(_record(claps, drift_ppm=300.0))["clock_drift"].severity == "pass"


def test_a_clapper_marker_missing_across_the_contact_keeps_the_clap():
    """A clapper marker lost for 3 frames from just after the contact used to make the clap vanish; it is found,
    placed within a frame, and its confidence says that its contact was not seen."""
    rate = 29.97
    rng = np.random.default_rng(3)
    n = int(10 * rate)
    t = np.arange(n) / rate
    contacts = np.array([2.0, 7.5])
    d = _clapper_distance(t, contacts, np.array([0.08, 0.08]))
    a = rng.normal(0, 0.4, (n, 3))
    b = np.column_stack([np.zeros(n), np.zeros(n), d]) + rng.normal(0, 0.4, (n, 3))
    vb = np.ones(n, bool)
    k = int(np.floor(contacts[1] * rate))
    vb[k + 1: k + 4] = False              # the closing seen up to the frame before contact, the plateau's start lost
    b[~vb] = np.nan
    found = mocap_claps(a, b, np.ones(n, bool), vb, rate)
    assert len(found) == 2
    assert abs(found[1].time_s - contacts[1]) * rate < 1.0
    assert found[1].gap_frames >= 1 and found[1].confidence < found[0].confidence
    assert found[0].gap_frames == 0


@pytest.fixture(scope="module")
def hazard_session(tmp_path_factory):
    cfg = SynthConfig(follow_poses=("standing",) * 4, follow_duration_s=12.0, shift_targets=(), face_takes=(),
                      clap_hazards=1.0, session_id="claps")
    return generate_session(tmp_path_factory.mktemp("claps"), seed=2, config=cfg)


def test_the_generator_writes_every_clap_hazard(hazard_session):
    truth = json.loads((hazard_session / "truth" / "truth.json").read_text())["takes"]
    kinds = [t["design"]["clap_hazard"]["kind"] for t in truth.values() if t["kind"] == "gaze_follow"]
    assert sorted(kinds) == sorted(CLAP_HAZARDS)
    for take, t in truth.items():
        if t["kind"] != "gaze_follow":
            continue
        hz = t["design"]["clap_hazard"]
        tr = np.load(hazard_session / "truth" / f"{take}.npz")
        probe = probe_video(hazard_session / t["video"]["path"])
        assert probe.n_frames == tr["video_time_s"].size == t["video"]["n_frames"]
        if hz["kind"] == "dropped_frames":
            # the stamps run on at the nominal rate while the exposures skip the dropped frames
            step = np.diff(tr["video_mocap_time_s"]) * 60.0 / t["video"]["ratio"]
            assert t["video"]["dropped_frames"] == hz["frames"] == int(round(step.max())) - 1
        else:
            assert t["video"]["dropped_frames"] == 0
        if hz["kind"] == "clapper_gap":
            raw = read_markers(hazard_session / t["mocap"])
            col = raw.labels.index(CLAPPER_MARKERS[hz["marker"]])
            k = int(np.floor(t["video"]["clap_times_mocap_s"][hz["clap"]] * raw.rate_hz))
            assert not raw.valid[k - hz["start_frames"] + 1, col]


def test_no_take_fails_for_a_clap_and_a_bad_map_is_flagged(hazard_session):
    """Every hazard take syncs (another clap or the nominal rate stands in), and over the crop either the map
    is within 5 ms of the truth or the report's clock_map check fails."""
    truth = json.loads((hazard_session / "truth" / "truth.json").read_text())["takes"]
    for take, t in truth.items():
        if t["kind"] != "gaze_follow":
            continue
        raw = read_markers(hazard_session / t["mocap"])
        a, b = (raw.labels.index(m) for m in CLAPPER_MARKERS)
        video = hazard_session / t["video"]["path"]
        ts = probe_video(video).timestamps_s
        with FrameReader(video, gray=True, scale=0.5, timestamps_s=ts) as rw:
            res = sync_take(raw.xyz[:, a], raw.xyz[:, b], raw.valid[:, a], raw.valid[:, b], raw.rate_hz, ts, rw,
                            video_path=str(video))
        tr = np.load(hazard_session / "truth" / f"{take}.npz")
        crop_s = (t["crop"][0] / raw.rate_hz, (t["crop"][1] - 1) / raw.rate_hz)
        inside = (tr["video_mocap_time_s"] >= crop_s[0]) & (tr["video_mocap_time_s"] <= crop_s[1])
        err_ms = np.abs(res.clock.to_mocap(tr["video_time_s"][inside]) - tr["video_mocap_time_s"][inside]).max() * 1e3
        check = next(c for c in sync_checks(SyncQC.from_record(res.qc), True, t["n_frames"], raw.rate_hz, Thresholds(),
                                            crop_s) if c.id == "clock_map")
        assert err_ms <= 5.0 or check.severity == "fail", (take, t["design"]["clap_hazard"], err_ms)


def test_a_clap_timed_by_its_burst_alone_weighs_less():
    """A video clap timed by its closing burst alone is known to a third of a frame's width either side only:
    the map leans on the other clap, and the bound says how little the burst-timed one adds."""
    (m1, v1), (m2, v2) = _pair(1.0), _pair(50.0)
    v2.timed_by, v2.timing_s = "burst", 9.6 * MS
    c = choose_clock([m1, m2], [v1, v2], video_span=(0.0, 55.0), video="video/t3.mp4")
    assert c.used == [True, True] and not c.warnings
    sd = np.array([np.sqrt(2.0), np.hypot(1.0, 9.6)]) * MS
    assert c.bound_ms == pytest.approx(BOUND_SIGMAS * _pred_sd(np.array([1.0, 50.0]), sd, 600e-6, 55.0) * 1000.0,
                                       rel=1e-6)
    assert c.limiting == 1 and c.bound_ms > 5.0
