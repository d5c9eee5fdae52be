"""The generator's clapper looks and mocap rates (``SynthConfig.clapper_look``, ``rate_hz``; ``python -m
gazepipe.synth --clapper-look NAME --mocap-rate-hz HZ``): claps the head camera sees less well score low on
the video while their timing stays right, and the sync keeps them (SPEC §3.4: never set aside for a low score)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from gazepipe.io.capture import read_markers
from gazepipe.io.video import FrameReader, probe_video, read_frames
from gazepipe.report.checks import Thresholds, sync_checks
from gazepipe.stages.sync.qc import SyncQC
from gazepipe.stages.sync.stage import sync_take
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.__main__ import _config
from gazepipe.synth.skeleton import CLAPPER_MARKERS
from gazepipe.synth.video import LOOKS, SAMPLE_LOOK


def test_the_command_line_sets_the_look_and_the_rate():
    a = argparse.Namespace(skeleton="ten", no_eyes=False, label_swaps=0, occlusion_bursts=0, clap_hazards=0.0,
                           mocap_rate_hz=120.0, clapper_look="dim", unlisted_markers=None, unlisted_motion=1.0)
    cfg = _config(a)
    assert cfg.rate_hz == 120.0 and cfg.clapper_look == LOOKS["dim"]
    plain = _config(argparse.Namespace(**{**vars(a), "mocap_rate_hz": None, "clapper_look": "sample"}))
    assert plain.clapper_look is SAMPLE_LOOK and plain.rate_hz == pytest.approx(30000 / 1001)


@pytest.fixture(scope="module")
def dim_take(tmp_path_factory):
    # the neutral take first, so the follow take's camera is a 59.94 Hz one labelled 60 (ratio 1.001)
    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=12.0, shift_targets=(), face_takes=(),
                      neutral_s=1.0, rate_hz=120.0, clapper_look=LOOKS["dim"], session_id="dim")
    folder = generate_session(tmp_path_factory.mktemp("dim"), seed=2, config=cfg)
    return folder, json.loads((folder / "truth" / "truth.json").read_text())["takes"]["follow_standing_01"]


def test_a_dim_clapper_is_written_as_asked(dim_take):
    """The truth says which look; the clapper's arm differs from the background by about an eighth of the
    sample's contrast, under 3 grey levels of noise."""
    folder, t = dim_take
    assert t["video"]["clapper_look"]["contrast"] == LOOKS["dim"].contrast and t["rate_hz"] == 120.0
    k = int(round(t["video"]["clap_times_video_s"][0] * 60.0))
    _, frames = read_frames(folder / t["video"]["path"], k - 20, k + 11, gray=True)
    shut, opened = frames[-1].astype(float), frames[0].astype(float)
    diff = np.abs(opened - shut)
    assert 5.0 < np.percentile(diff, 99.5) < 40.0          # the sample's white arm differs by over 60


def test_a_low_scoring_clap_keeps_the_clock_within_5_ms(dim_take):
    """A plain take whose dim clapper scores under 0.5 on the video (0.16: the sync would have set it aside for
    that once): both claps set the map, the clock_map check
    passes over the crop, and the map is within 5 ms of the truth there (one clap and the nominal rate would be
    over 5 ms off at the crop's far end: the camera runs 1,000 ppm fast)."""
    folder, t = dim_take
    raw = read_markers(folder / t["mocap"])
    a, b = (raw.labels.index(m) for m in CLAPPER_MARKERS)
    video = folder / t["video"]["path"]
    ts = probe_video(video).timestamps_s
    with FrameReader(video, gray=True, scale=0.5, timestamps_s=ts) as rw:
        res = sync_take(raw.xyz[:, a], raw.xyz[:, b], raw.valid[:, a], raw.valid[:, b], raw.rate_hz, ts, rw)
    qc = SyncQC.from_record(res.qc)
    assert min(c.video_confidence for c in qc.claps) < 0.5
    assert qc.claps_used == (1, 2) and not qc.warnings
    rate = raw.rate_hz
    crop_s = (t["crop"][0] / rate, (t["crop"][1] - 1) / rate)
    check = next(c for c in sync_checks(qc, True, t["n_frames"], rate, Thresholds(), crop_s) if c.id == "clock_map")
    assert check.severity == "pass" and check.value <= 5.0
    tr = np.load(folder / "truth" / "follow_standing_01.npz")
    inside = (tr["video_mocap_time_s"] >= crop_s[0]) & (tr["video_mocap_time_s"] <= crop_s[1])
    err = np.abs(res.clock.to_mocap(tr["video_time_s"][inside]) - tr["video_mocap_time_s"][inside]) * 1000.0
    assert err.max() <= 5.0 and err.max() <= check.value
    alone = (float(t["video"]["ratio"]) - 1.0) * (crop_s[1] - crop_s[0]) * 1000.0
    assert alone > 5.0
