"""sync stage: clapper claps on both clocks, the clock map and resampling, against synthetic ground truth.

The clapper model, its mocap markers, its rendered videos and the counting reader come from ``bench/_av.py``
(shared with ``bench/bench_sync.py``): the arms close with constant acceleration and hit each other at full
speed at the contact instant; videos are rendered on the mocap clock at t_mocap = offset + ratio · t_video, with
motion blur, sensor noise and a slowly moving distractor.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench._av import FPS, OPEN_MM, SHUT_MM, CountingReader, clapper_markers, write_clapper_video
from gazepipe.errors import StageError
from gazepipe.io.video import probe_video
from gazepipe.stages.sync.clap import Clap, mocap_claps
from gazepipe.stages.sync.clock import ClockMap, clock_map, resample_to_mocap
from gazepipe.stages.sync.stage import sync_take
from gazepipe.stages.sync.video import VideoClap, video_claps


# ----------------------------------------------------------------------------------------- mocap claps
@pytest.mark.parametrize("rate,closing", [(29.97, (0.10, 0.20)), (59.94, (0.06, 0.12)), (120.0, (0.06, 0.12)),
                                          (240.0, (0.06, 0.12))])
def test_mocap_clap_instants(rate, closing):
    """Contact instants within 1/10 frame (95th percentile; median 1/20, worst 1/5) with 0.5 mm marker noise,
    for closings over three frames or more. At 240 Hz the marker noise, not the frame, sets the limit: there
    the same bounds hold for frames of 1/120 s."""
    rng = np.random.default_rng(int(rate * 100))
    errs = []
    for _ in range(20):
        n = int(30 * rate)
        contacts = [rng.uniform(1.5, 3.0), rng.uniform(24.0, 28.0)]
        cl = rng.uniform(*closing, size=2)
        a, b, va, vb = clapper_markers(rng, n, rate, contacts, cl, noise_mm=0.5)
        found = mocap_claps(a, b, va, vb, rate)
        assert len(found) == 2
        errs.extend((np.array([c.time_s for c in found]) - contacts) * rate)
        assert all(c.confidence > 0.9 for c in found)
        assert all(abs(c.shut_mm - SHUT_MM) < 1.0 and abs(c.open_mm - OPEN_MM) < 3.0 for c in found)
    errs = np.abs(errs) * min(1.0, 120.0 / rate)
    assert np.median(errs) <= 0.05
    assert np.percentile(errs, 95) <= 0.1
    assert errs.max() <= 0.2, errs.max()


@pytest.mark.parametrize("rate,closing", [(29.97, (0.10, 0.20)), (120.0, (0.06, 0.12))])
def test_a_stick_that_bounces_after_contact_does_not_move_the_clap(rate, closing):
    """SPEC §3.4: the contact is the start of the shut plateau. A stick that bounces open 3–6 mm for one to two
    frames right after contact (a half sine) leaves the contact within 1/5 frame (closings over three frames or
    more, as test_mocap_clap_instants), where taking the first frame within the tight shut margin would put it
    after the bounce (up to 1.2 frames late on these draws)."""
    from gazepipe.synth.motion import CLAP_SHUT_MM, _clapper_distance

    rng = np.random.default_rng(7)
    errs = []
    for _ in range(10):
        n = int(12 * rate)
        contacts = np.array([rng.uniform(1.5, 3.0), rng.uniform(8.0, 10.0)])
        closing_s = rng.uniform(*closing, size=2)
        bounce = np.stack([rng.uniform(3.0, 6.0, 2), rng.uniform(1.0, 2.0, 2) / rate], axis=1)
        t = np.arange(n) / rate
        d = _clapper_distance(t, contacts, closing_s, bounce)
        assert (d > CLAP_SHUT_MM + 2.5).any() and d.min() >= CLAP_SHUT_MM
        a = np.zeros((n, 3)) + rng.normal(0, 0.3, (n, 3))
        b = np.column_stack([np.zeros(n), np.zeros(n), d]) + rng.normal(0, 0.3, (n, 3))
        found = mocap_claps(a, b, np.ones(n, bool), np.ones(n, bool), rate)
        assert len(found) == 2
        errs.extend((np.array([c.time_s for c in found]) - contacts) * rate)
    assert np.abs(errs).max() <= 0.2, errs


@pytest.mark.parametrize("rate", [29.97, 59.94, 120.0])
def test_mocap_clap_timing_covers_its_error(rate):
    """Each mocap clap states how well it is timed (the marker noise carried through the contact's fit, and a
    share of the frame period): over 60 hard claps of 0.05–0.12 s closings, 60–100 % of the full opening, under
    0.2–1.5 mm of marker noise, the error is within two of its standard deviations for at least 90 % of them,
    and the statement is not vacuous (median under a tenth of a frame). (A soft clap, which slows into contact,
    is placed where its fast closing ends, on the video alike: ``bench/bench_claps_truth.py`` shows the pairs.)"""
    from gazepipe.synth.motion import _clapper_distance

    rng = np.random.default_rng(int(rate))
    z, sd = [], []
    for _ in range(30):
        n = int(8 * rate)
        contacts = np.array([rng.uniform(1.5, 2.5), rng.uniform(5.0, 6.0)])
        soft = np.stack([rng.uniform(0.6, 1.0, 2), np.zeros(2)], axis=1)
        t = np.arange(n) / rate
        d = _clapper_distance(t, contacts, rng.uniform(0.05, 0.12, 2), None, soft)
        noise = rng.uniform(0.2, 1.5)
        a = rng.normal(0, noise, (n, 3))
        b = np.column_stack([np.zeros(n), np.zeros(n), d]) + rng.normal(0, noise, (n, 3))
        found = mocap_claps(a, b, np.ones(n, bool), np.ones(n, bool), rate)
        assert len(found) == 2
        z.extend(np.abs([c.time_s - tc for c, tc in zip(found, contacts, strict=True)]) / [c.timing_s for c in found])
        sd.extend(c.timing_s * rate for c in found)
    assert np.mean(np.array(z) <= 2.0) >= 0.9, np.sort(z)[-8:]
    assert np.median(sd) < 0.1


def test_mocap_no_clap_and_gaps():
    rng = np.random.default_rng(3)
    rate, n = 100.0, 2000
    # the clapper carried shut all along: no clap
    a, b, va, vb = clapper_markers(rng, n, rate, [], [], noise_mm=0.5)
    assert mocap_claps(a, b, va, vb, rate) == []
    # opened and closed slowly (2 s): a movement, not a clap
    t = np.arange(n) / rate
    d = SHUT_MM + (OPEN_MM - SHUT_MM) * np.clip(np.sin(np.pi * (t - 5) / 8), 0, 1)
    b2 = a + d[:, None] * np.array([0.0, 0.0, 1.0])
    assert mocap_claps(a, b2, va, vb, rate) == []
    # a clap whose markers are hidden around the contact is not reported; the other one is
    a, b, va, vb = clapper_markers(rng, n, rate, [2.0, 15.0], [0.08, 0.08], noise_mm=0.5)
    va[190:215] = False
    found = mocap_claps(a, b, va, vb, rate)
    assert len(found) == 1 and abs(found[0].time_s - 15.0) < 0.1 / rate


def test_mocap_confidence_falls_with_noise():
    rate = 59.94
    conf = []
    for noise in (0.3, 3.0, 8.0):
        rng = np.random.default_rng(5)
        a, b, va, vb = clapper_markers(rng, 1200, rate, [3.0, 15.0], [0.08, 0.08], noise_mm=noise)
        found = mocap_claps(a, b, va, vb, rate)
        conf.append(min([c.confidence for c in found], default=0.0))
    assert conf[0] == 1.0 and conf[0] > conf[1] > conf[2]


# ----------------------------------------------------------------------------------------- video claps
OFFSET, RATIO = 3.217, 60.0 / 59.94  # the camera's "60 fps" is 59.94 real frames per second
REFINE_FRAMES = 6 + 3 + 10  # looked at again per clap to refine it: before the edge, around it, still after it


@pytest.fixture(scope="module")
def many_claps(tmp_path_factory):
    """40 s of video with a clap every ~4.4 s at random sub-frame instants, and the truth (video clock)."""
    rng = np.random.default_rng(11)
    contacts = OFFSET + RATIO * (np.arange(9) * 4.4 + 2.0 + rng.uniform(0, 1 / FPS, 9))
    closing = rng.uniform(0.06, 0.12, 9)
    path = write_clapper_video(tmp_path_factory.mktemp("v") / "many.mp4", int(40 * FPS), contacts, closing,
                               offset=OFFSET, ratio=RATIO, seed=1)
    return path, (contacts - OFFSET) / RATIO


@pytest.fixture(scope="module")
def two_claps(tmp_path_factory):
    """60 s of video with a clap near the start and one near the end, and their mocap-clock instants."""
    rng = np.random.default_rng(12)
    contacts = OFFSET + RATIO * np.array([2.3, 57.1]) + rng.uniform(0, 1 / FPS, 2)
    closing = np.array([0.07, 0.1])
    path = write_clapper_video(tmp_path_factory.mktemp("v") / "two.mp4", int(60 * FPS), contacts, closing,
                               offset=OFFSET, ratio=RATIO, seed=2)
    return path, contacts, closing


def test_video_clap_instants(many_claps):
    path, truth = many_claps
    probe = probe_video(path)
    rng = np.random.default_rng(4)
    approx = truth + rng.uniform(-0.7, 0.7, truth.size)  # a rough prior
    reader = CountingReader(path, probe.timestamps_s)
    found = video_claps(probe.timestamps_s, reader, approx.tolist(), window_s=1.0)
    assert all(v is not None and v.confidence > 0.5 for v in found)
    err = np.abs(np.array([v.time_s for v in found]) - truth) * FPS
    assert np.median(err) <= 0.25, err
    assert err.max() <= 1.0, err
    # each states its timing: the arm followed into contact, to about a tenth of a frame, which covers the error
    assert all(v.timed_by == "displacement" and v.timing_s * FPS == pytest.approx(0.1) for v in found)
    assert (err <= 2.0 * np.array([v.timing_s * FPS for v in found])).mean() >= 8 / 9, err


def test_thin_fast_arm(tmp_path):
    """An 8-pixel arm moving up to 28 pixels a frame saturates frame differences: the energy edge alone is
    late by a fraction of a frame; the displacement refinement recovers the contact."""
    rng = np.random.default_rng(21)
    truth = np.arange(5) * 2.5 + 1.5 + rng.uniform(0, 1 / FPS, 5)
    path = write_clapper_video(tmp_path / "thin.mp4", int(14 * FPS), truth + 0.5, rng.uniform(0.06, 0.1, 5),
                               offset=0.5, ratio=1.0, seed=4, arm_h=8.0)
    probe = probe_video(path)
    err = {}
    for refine in (False, True):
        found = video_claps(probe.timestamps_s, CountingReader(path, probe.timestamps_s), truth.tolist(),
                            window_s=0.6, refine=refine)
        err[refine] = np.abs(np.array([v.time_s for v in found]) - truth) * FPS
    assert np.median(err[False]) > 0.1  # the saturation is real in this video
    assert err[True].max() <= 0.1


def test_only_windows_are_decoded(many_claps):
    path, truth = many_claps
    probe = probe_video(path)
    reader = CountingReader(path, probe.timestamps_s)
    window_s, post_s = 0.8, 0.3
    found = video_claps(probe.timestamps_s, reader, [float(truth[2])], window_s=window_s, post_s=post_s, chunk=30)
    assert found[0] is not None and abs(found[0].time_s - truth[2]) * FPS <= 1.0
    # the window once, in order: the refinement's frames come from those already decoded
    expected = (2 * window_s + post_s) * FPS + 2
    assert reader.frames <= expected and reader.frames < probe.n_frames / 10
    starts = [c[0] for c in reader.calls]
    assert min(starts) >= (truth[2] - window_s) * FPS - 2
    assert all(b == c for (_, b), (c, _) in zip(reader.calls[:-1], reader.calls[1:], strict=True))
    assert all(stop - start <= 30 for start, stop in reader.calls)


def _mocap_for(contacts, closing, duration_s=70.0, rate=29.97, seed=0):
    rng = np.random.default_rng(seed)
    return (*clapper_markers(rng, int(duration_s * rate), rate, contacts, closing, noise_mm=0.5), rate)


@pytest.mark.parametrize("prior", [True, False])
def test_sync_take_offset_and_ratio(two_claps, prior):
    path, contacts, closing = two_claps
    probe = probe_video(path)
    a, b, va, vb, rate = _mocap_for(contacts, closing)
    reader = CountingReader(path, probe.timestamps_s)
    res = sync_take(a, b, va, vb, rate, probe.timestamps_s, reader,
                    offset_guess_s=OFFSET + 0.6 if prior else None)
    truth_first = contacts[0] - (contacts[0] - OFFSET) / RATIO
    assert res.clock.n_claps == 2
    assert abs(res.clock.offset_at_first_clap_s - truth_first) <= 0.005
    assert abs(res.clock.offset_s - OFFSET) <= 0.005
    assert abs(res.clock.ratio - RATIO) <= 1e-4
    assert res.qc["drift_ppm"] == pytest.approx((RATIO - 1) * 1e6, abs=100)
    # the video starts after the mocap: the frames before offset have no video
    last = OFFSET + RATIO * probe.timestamps_s[-1]
    assert res.frames_without_video == pytest.approx(OFFSET * rate + (70 - last) * rate, abs=2)
    assert reader.frames < probe.n_frames / 2  # at most the bounded search portions, never the whole video
    if prior:
        # each window, with the second before it and the 0.3 s after it that the clapper's profile spans, and
        # the 0.3 s after that to see the burst end
        assert reader.frames <= 2 * ((2 * 1.5 + 1.0 + 0.3 + 0.3) * FPS + 2 + REFINE_FRAMES)


def test_sync_take_errors(two_claps, tmp_path):
    path, contacts, closing = two_claps
    probe = probe_video(path)
    rng = np.random.default_rng(0)
    a, b, va, vb = clapper_markers(rng, 3000, 29.97, [], [], noise_mm=0.5)
    with pytest.raises(StageError) as e:
        sync_take(a, b, va, vb, 29.97, probe.timestamps_s, CountingReader(path, probe.timestamps_s),
                  mocap_path="mocap/t1.c3d", take="t1")
    assert "mocap/t1.c3d" in str(e.value) and "no clap" in str(e.value) and "\n" not in str(e.value)
    # a video without a clap (the clapper stays shut)
    still = write_clapper_video(tmp_path / "still.mp4", 600, [], [], offset=0.0, ratio=1.0)
    pr = probe_video(still)
    a, b, va, vb, rate = _mocap_for(contacts, closing)
    with pytest.raises(StageError) as e:
        sync_take(a, b, va, vb, rate, pr.timestamps_s, CountingReader(still, pr.timestamps_s),
                  video_path="video/t1.mp4", take="t1")
    assert "video/t1.mp4" in str(e.value) and "no clap found in the video" in str(e.value)


# ----------------------------------------------------------------------------------------- clock map
def _clap(t: float) -> Clap:
    return Clap(time_s=t, frame=t * 30, confidence=1.0, closing_speed_mm_s=1e3, open_mm=150, shut_mm=25,
                margin_mm=1)


def _vclap(t: float) -> VideoClap:
    return VideoClap(time_s=t, frame=t * 60, confidence=1.0, peak=10, still=1, window=(0, 1))


def test_clock_map():
    one = clock_map([_clap(5.0)], [_vclap(2.0)])
    assert (one.offset_s, one.ratio, one.n_claps) == (3.0, 1.0, 1)
    off, ratio = 1.25, 1.001
    tv = np.array([2.0, 300.0])
    two = clock_map([_clap(off + ratio * t) for t in tv], [_vclap(t) for t in tv])
    assert two.offset_s == pytest.approx(off, abs=1e-9) and two.ratio == pytest.approx(ratio, rel=1e-12)
    assert two.offset_at_first_clap_s == pytest.approx(off + (ratio - 1) * 2.0, abs=1e-9)
    assert two.drift_ppm == pytest.approx(1000.0) and two.drift_ms(600.0) == pytest.approx(600.0)
    # a missing video clap is skipped
    three = clock_map([_clap(off + ratio * t) for t in (2.0, 100.0, 300.0)], [_vclap(2.0), None, _vclap(300.0)])
    assert three.n_claps == 2 and three.ratio == pytest.approx(ratio, rel=1e-12)


# ----------------------------------------------------------------------------------------- resampling
def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_resample_directions_by_slerp():
    rng = np.random.default_rng(8)
    tv = np.arange(200) / 60.0
    dirs = _unit(rng.normal(size=(200, 3)) + np.array([0, 0, 3.0]))
    clock = ClockMap(offset_s=0.4, ratio=1.001, n_claps=2)
    tm = np.arange(120) / 29.97
    out, covered = resample_to_mocap(tv, dirs, "direction", tm, clock)
    tvm = clock.to_mocap(tv)
    assert covered.tolist() == ((tm >= tvm[0]) & (tm <= tvm[-1])).tolist()
    assert np.all(np.isnan(out[~covered]))
    i = np.searchsorted(tvm, tm[covered], side="right") - 1
    u = (tm[covered] - tvm[i]) / (tvm[i + 1] - tvm[i])
    a, b, r = dirs[i], dirs[i + 1], out[covered]
    ang = lambda x, y: np.arccos(np.clip(np.einsum("ij,ij->i", x, y), -1, 1))  # noqa: E731
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(ang(a, r), u * ang(a, b), atol=1e-9)  # constant angular speed
    np.testing.assert_allclose(ang(r, b), (1 - u) * ang(a, b), atol=1e-9)  # on the great circle
    # a sample hit exactly is returned as is
    ex, _ = resample_to_mocap(tv, dirs, "direction", clock.to_mocap(tv[[5, 17]]), clock)
    np.testing.assert_allclose(ex, dirs[[5, 17]], atol=1e-12)


def test_resample_scalars_confidence_bools_no_extrapolation():
    tv = np.array([0.0, 1.0, 2.0, 3.0])
    clock = ClockMap(offset_s=10.0, ratio=1.0, n_claps=1)
    tm = np.array([9.5, 10.0, 10.25, 11.5, 13.0, 13.5])
    vals = np.array([0.0, 4.0, 8.0, 2.0])
    out, cov = resample_to_mocap(tv, vals, "scalar", tm, clock)
    assert cov.tolist() == [False, True, True, True, True, False]
    np.testing.assert_allclose(out[1:5], [0.0, 1.0, 6.0, 2.0])
    assert np.isnan(out[0]) and np.isnan(out[5])
    conf = np.array([0.9, 0.5, 0.8, 0.95])
    c, _ = resample_to_mocap(tv, conf, "confidence", tm, clock)
    np.testing.assert_allclose(c[1:5], [0.9, 0.5, 0.5, 0.95])
    c2, _ = resample_to_mocap(tv, conf, "confidence", np.array([10.5, 11.5, 12.9]), clock)
    np.testing.assert_allclose(c2, [0.5, 0.5, 0.8])
    ok = np.array([True, False, True, True])
    v, _ = resample_to_mocap(tv, ok, "bool", np.array([9.9, 10.0, 10.5, 11.5, 12.5, 13.0, 13.1]), clock)
    assert v.tolist() == [False, True, False, False, True, True, False]
    # (N, D) scalars interpolate per column
    m, _ = resample_to_mocap(tv, np.column_stack([vals, -vals]), "scalar", np.array([10.25]), clock)
    np.testing.assert_allclose(m, [[1.0, -1.0]])


def test_sync_take_without_prior_falls_back_to_the_tail(tmp_path):
    """The video missed the first clap: the head search finds nothing sure, the last clap is found in the tail,
    the clocks are mapped from that one pair (ratio 1) and the first clap is reported as not used (whatever
    weak motion the head of the video offers for it never sets the clock)."""
    offset, closing = 1.0, np.array([0.08, 0.08])
    contacts = np.array([0.5, 29.0])  # the first clap happens before the video starts (mocap 1.0 s)
    path = write_clapper_video(tmp_path / "tail.mp4", int(30 * FPS), contacts, closing, offset=offset,
                               ratio=1.0, seed=3)
    probe = probe_video(path)
    a, b, va, vb, rate = _mocap_for(contacts, closing, duration_s=32.0, rate=59.94)
    res = sync_take(a, b, va, vb, rate, probe.timestamps_s, CountingReader(path, probe.timestamps_s))
    assert res.video_claps[1] is not None and res.video_claps[1].confidence >= 0.5
    assert res.video_claps[0] is None or res.video_claps[0].confidence < 0.5
    assert res.clock.n_claps == 1 and res.clock.ratio == 1.0 and res.qc["claps_used"] == [2]
    assert abs(res.clock.offset_s - offset) <= 0.005
    assert abs(res.mocap_claps[0].time_s - 0.5) < 0.002
    assert len(res.qc["warnings"]) == 1 and "clap 1" in res.qc["warnings"][0]
    assert ("no video counterpart" in res.qc["warnings"][0] or "set aside" in res.qc["warnings"][0])


def test_a_ghost_spike_on_a_clapper_arm_does_not_move_the_clap(two_claps):
    """A 30 mm ghost on one arm the frame after contact moves the mocap clap 32 ms when taken as measured;
    sync leaves it out and finds the clap and clock map it finds without it."""
    path, contacts, closing = two_claps
    probe = probe_video(path)
    a, b, va, vb, rate = _mocap_for(contacts, closing)
    clean = sync_take(a, b, va, vb, rate, probe.timestamps_s, CountingReader(path, probe.timestamps_s))
    ghost = a.copy()
    ghost[int(contacts[0] * rate) + 1] += [0.0, -30.0, 0.0]
    moved = mocap_claps(ghost, b, va, vb, rate)[0].time_s - mocap_claps(a, b, va, vb, rate)[0].time_s
    assert abs(moved) > 0.02                                            # taken as measured, it moves the clap
    res = sync_take(ghost, b, va, vb, rate, probe.timestamps_s, CountingReader(path, probe.timestamps_s))
    assert abs(res.mocap_claps[0].time_s - clean.mocap_claps[0].time_s) < 0.003
    assert res.clock.offset_s == pytest.approx(clean.clock.offset_s, abs=0.003)


def test_claps_that_bounce_are_timed_on_the_mocap_and_the_video(tmp_path):
    """Generated gaze_follow takes whose clapper stick bounces open 3–6 mm after every contact (on the markers
    and in the head-camera video): both claps of every take within 1/5 of a mocap frame on the mocap and 1/4 of
    a video frame on the video, and the clock map within 5 ms over the crop (the frames that feed the datasets,
    SPEC §3.4)."""
    import json

    from gazepipe.io.capture import read_markers
    from gazepipe.io.video import FrameReader
    from gazepipe.synth import SynthConfig, generate_session

    cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=10.0, face_takes=(), shift_targets=(),
                      neutral_s=0.0, clap_rebounds=1.0)
    folder = generate_session(tmp_path / "s", seed=2, config=cfg)
    truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    for take, t in truth.items():
        v = t["video"]
        mk = read_markers(str(folder / t["mocap"]))
        a, b = mk.labels.index("CLAP1"), mk.labels.index("CLAP2")
        path = str(folder / v["path"])
        ts = probe_video(path).timestamps_s
        with FrameReader(path, gray=True, scale=0.5, timestamps_s=ts) as rw:
            res = sync_take(mk.xyz[:, a], mk.xyz[:, b], mk.valid[:, a], mk.valid[:, b], mk.rate_hz, ts, rw)
        assert all(mm >= 3.0 for mm, _ in t["design"]["clap_rebound"])
        m_err = (np.array([c.time_s for c in res.mocap_claps]) - v["clap_times_mocap_s"]) * mk.rate_hz
        v_err = (np.array([c.time_s for c in res.video_claps]) - v["clap_times_video_s"]) * v["fps"]
        assert np.abs(m_err).max() <= 0.2 and np.abs(v_err).max() <= 0.25, (take, m_err, v_err)
        crop_v = (np.array([t["crop"][0], t["crop"][1] - 1]) / mk.rate_hz - v["offset_s"]) / v["ratio"]
        tv = np.linspace(*crop_v, 100)
        clock_err = np.abs(res.clock.to_mocap(tv) - (v["offset_s"] + v["ratio"] * tv)).max()
        assert clock_err <= 0.005, (take, clock_err)


def test_a_take_that_lost_its_first_clap_pairs_its_last_with_the_videos_last(two_claps):
    """The mocap saw only the second clap (the first one's closing hidden): searched in the video's head it
    would pair with the video's first clap, 55 s off; a clap in the take's second half is looked for in the
    video's tail instead, and the map rests on it with the nominal ratio."""
    path, contacts, closing = two_claps
    probe = probe_video(path)
    a, b, va, vb, rate = _mocap_for(contacts[1:], closing[1:])
    res = sync_take(a, b, va, vb, rate, probe.timestamps_s, CountingReader(path, probe.timestamps_s))
    assert len(res.mocap_claps) == 1 and res.clock.n_claps == 1
    truth_video = (contacts[1] - OFFSET) / RATIO
    assert abs(res.video_claps[0].time_s - truth_video) < 0.005


def test_a_wobble_on_the_open_plateau_keeps_the_displacement_refinement(monkeypatch):
    """A partly hidden arm's displacement wobbles by a few hundredths while it is open; the approach is followed
    from the plateau's last frame, so the clap is still refined (it was timed by the burst alone, 7 ms off)."""
    from gazepipe.stages.sync import video

    s = np.array([24.69, 24.66, 24.67, 23.41, 19.18, 11.81, 1.84, 0.0, 0.0])
    monkeypatch.setattr(video, "_displacement", lambda frames, shut, thr: s)
    ts = np.arange(100) / 60.0

    def read(a: int, b: int):
        return ts[a:b], np.zeros((b - a, 8, 8), np.uint8)

    t, sd = video._refine_by_displacement(ts, read, ts[50], None)
    y = s[4:7]
    root = [r.real for r in np.roots(np.polyfit([-2.0, -1.0, 0.0], y, 2)) if 0 <= r.real <= 1.5][0]
    straddle = video.STRADDLE_FRAMES if root < 0.5 else 0.0    # the last moving frame may take in the contact
    assert t == pytest.approx((50 + root - straddle) / 60.0)
    assert sd == video.TIMING_FRAMES["displacement"]


def test_motion_energy_is_the_mean_absolute_step_across_chunks():
    from gazepipe.stages.sync.video import motion_energy

    rng = np.random.default_rng(2)
    frames = rng.integers(0, 256, size=(10, 6, 8), dtype=np.uint8)
    frames[4] = 0
    frames[5] = 255                                   # a full-range step: no wrap-around in uint8

    def read_window(a, b):
        return np.arange(a, b) / 30.0, frames[a:b]

    energy, n = motion_energy(read_window, 0, 10, chunk=3)            # chunk edges inside the steps
    expect = np.abs(np.diff(frames.astype(np.int64), axis=0)).mean(axis=(1, 2))
    assert n == 10
    np.testing.assert_array_equal(energy, expect)
    assert energy[4] == 255.0
    roi, _ = motion_energy(read_window, 2, 8, roi=(1, 4, 2, 6), chunk=4)
    np.testing.assert_array_equal(roi, np.abs(np.diff(frames[2:8, 1:4, 2:6].astype(np.int64), axis=0)).mean(axis=(1, 2)))
