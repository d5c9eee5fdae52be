"""Head-camera video, OpenFace CSVs and Live Link Face takes of the synthetic session, read back through the
project's readers and checked against the truth written beside them."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from gazepipe.arkit import ARKIT_NAMES
from gazepipe.io.livelinkface import read_livelinkface
from gazepipe.io.openface import read_openface
from gazepipe.io.video import probe_video, read_frames
from gazepipe.synth import SynthConfig, generate_session, load_truth
from tests.helpers import CORPUS, SAMPLE

FPS = 60.0
# neutral first, so the three follow takes have indices 1, 2, 3: every camera clock variant occurs
AV = SynthConfig(follow_poses=("standing", "standing", "sitting"), follow_duration_s=13.0, shift_targets=(),
                 neutral_s=1.0, face_takes=((60.0, 8.0), (30.0, 10.0)))


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_session(tmp_path_factory.mktemp("av") / "s", seed=11, config=AV)


@pytest.fixture(scope="module")
def takes(session: Path) -> list[dict]:
    return tomllib.loads((session / "session.toml").read_text())["takes"]


def _follow(takes: list[dict]) -> list[dict]:
    return [t for t in takes if t["kind"] == "gaze_follow"]


def _cam_rot(tr: dict) -> Rotation:
    return Rotation.from_quat(np.asarray(tr["session"]["camera_to_head_quat"])[[1, 2, 3, 0]])


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0)))


# ------------------------------------------------------------------------------------------------ video
def test_videos_probe_with_the_truth_frames_and_clocks(session: Path, takes: list[dict]) -> None:
    ratios, offsets = [], []
    for t in _follow(takes):
        tr = load_truth(session, t["id"])
        v = tr["scalars"]["video"]
        probe = probe_video(session / t["video"])
        assert probe.nominal_fps == FPS and (probe.width, probe.height) == (v["width"], v["height"])
        assert probe.n_frames == v["n_frames"] == tr["video_time_s"].size
        # frame k is stamped k / 60 on the video clock
        assert np.allclose(probe.timestamps_s, np.arange(probe.n_frames) / FPS, atol=1e-6)
        assert np.allclose(tr["video_mocap_time_s"], v["offset_s"] + v["ratio"] * probe.timestamps_s, atol=1e-9)
        mocap_t = tr["time_s"]
        assert tr["video_mocap_time_s"][-1] > mocap_t[-1] + 0.9          # the video runs past the mocap's end
        without = ~tr["mocap_has_video"]
        assert without.sum() == v["mocap_frames_without_video"]
        if v["offset_s"] > 0:     # the camera started late: the first mocap frames have no picture
            assert without[0] and without.sum() == pytest.approx(v["offset_s"] * 30000 / 1001, abs=1)
        else:
            assert not without.any()
        ratios.append(v["ratio"])
        offsets.append(v["offset_s"])
    assert 1.001 in ratios                                                # a 59.94 camera labelled 60
    drift = [abs(r - 1.0) for r in ratios if r != 1.001]
    assert drift and all(2e-4 <= d <= 8e-4 for d in drift)
    assert any(o > 0 for o in offsets) and any(-4.0 <= o <= -1.5 for o in offsets)


def test_video_clap_is_where_the_mocap_clap_maps(session: Path, takes: list[dict]) -> None:
    """The motion-energy burst of the closing clapper ends at the truth clap on the video clock, and the truth
    clap on the mocap clock is where the (noise-free) clapper markers come shut."""
    for t in _follow(takes):
        tr = load_truth(session, t["id"])
        v = tr["scalars"]["video"]
        x = tr["markers_true"]
        d = np.linalg.norm(x[:, tr["labels"].index("CLAP1")] - x[:, tr["labels"].index("CLAP2")], axis=1)
        shut = d.min()
        for tc_m, tc_v in zip(tr["clap_times_s"], tr["video_clap_times_s"], strict=True):
            assert tc_v == pytest.approx((tc_m - v["offset_s"]) / v["ratio"], abs=1e-9)
            i = int(np.ceil(tc_m * 30000 / 1001))
            assert d[i] == pytest.approx(shut, abs=0.5) and d[i - 2] > shut + 5.0
            k = int(round(tc_v * FPS))
            ts, frames = read_frames(session / t["video"], k - 45, k + 30)
            e = np.abs(np.diff(frames.astype(np.float64), axis=0)).mean(axis=(1, 2))
            te = 0.5 * (ts[1:] + ts[:-1])
            still = np.median(e)
            peak = int(np.argmax(e))
            # the fastest closing is in the last frame pair before contact: the peak sits within a frame of it
            assert tc_v - 1.5 / FPS <= te[peak] <= tc_v + 0.5 / FPS
            assert e[peak] > 20 * still
            # after contact the clapper stays shut: energy back to the noise floor two frames on
            after = te > tc_v + 2.0 / FPS
            assert e[after].max() < 0.1 * e[peak]
            # the last sample above half the peak is the end of the burst: within a frame of the clap
            end = te[np.flatnonzero(e > 0.5 * e[peak])[-1]]
            assert abs(end - tc_v) <= 1.0 / FPS


# --------------------------------------------------------------------------------------------- OpenFace
def test_openface_eyes_map_to_the_true_directions(session: Path, takes: list[dict]) -> None:
    layouts = set()
    for t in _follow(takes):
        tr = load_truth(session, t["id"])
        et = read_openface(session / t["eyes"])
        layouts.add(et.layout)
        n = tr["video_time_s"].size
        assert et.time_s.size == n and np.allclose(et.time_s, tr["video_time_s"], atol=5e-4)
        assert np.array_equal(et.frame, np.arange(1, n + 1))
        r = _cam_rot(tr)
        ok = tr["eyes_valid"]
        right = r.apply(np.nan_to_num(et.gaze_right))      # camera axes -> head axes: v_head = R · v_cam
        left = r.apply(np.nan_to_num(et.gaze_left))
        for got, want in ((right, tr["eyes_right_head"]), (left, tr["eyes_left_head"])):
            err = _angle_deg(got[ok], want[ok].astype(np.float64))
            assert 1.0 < np.median(err) < 2.5 and np.percentile(err, 95) < 5.0   # ~2° RMS per eye
        # the eyes converge on the target: the subject's right eye (at -X) points further to +X than the left
        # eye, by ~2° here. A swapped mapping would flip the sign of this mean difference.
        want_dx = float(np.mean(tr["eyes_right_head"][ok, 0] - tr["eyes_left_head"][ok, 0]))
        got_dx = float(np.mean(right[ok, 0] - left[ok, 0]))
        assert want_dx > 0.01 and abs(got_dx - want_dx) < 0.35 * want_dx
        cyc = right[ok] + left[ok]
        cyc /= np.linalg.norm(cyc, axis=1, keepdims=True)
        assert np.median(_angle_deg(cyc, tr["eyes_dir_head"][ok].astype(np.float64))) < 1.5
        # the camera-axes truth is the head-axes truth turned by Rᵀ
        assert np.allclose(r.inv().apply(tr["eyes_dir_head"].astype(np.float64)), tr["eyes_dir_cam"], atol=1e-5)


def test_openface_gating_masks_match_the_truth(session: Path, takes: list[dict]) -> None:
    for t in _follow(takes):
        tr = load_truth(session, t["id"])
        et = read_openface(session / t["eyes"])
        raw = pd.read_csv(session / t["eyes"], skipinitialspace=True)
        assert np.array_equal(et.success, tr["eyes_success"])
        assert np.array_equal(et.blink, tr["eyes_blink"])
        gate = et.success & (et.confidence >= 0.8) & ~et.blink
        assert np.array_equal(gate, tr["eyes_valid"])
        assert np.array_equal(et.success & (et.confidence < 0.8), tr["eyes_low_conf"])
        good = et.success & ~tr["eyes_low_conf"]
        assert et.confidence[good].min() >= 0.86 and et.confidence[good].max() <= 0.98
        fail = ~et.success
        assert 0 < fail.sum() < 0.02 * fail.size
        assert np.all(raw.loc[fail, ["gaze_0_x", "gaze_0_z", "gaze_1_y", "AU45_r"]].to_numpy() == 0)
        # blinks: AU45_r >= 1 inside, below 1 outside; 100-300 ms each, a few seconds apart
        assert np.all(raw["AU45_r"].to_numpy()[tr["eyes_blink"]] >= 1.0)
        assert np.all(raw["AU45_r"].to_numpy()[~tr["eyes_blink"]] < 1.0)
        edges = np.diff(np.concatenate([[0], tr["eyes_blink"].astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        assert len(starts) >= 1                      # short takes: the claps' quiet time leaves room for few
        dur = (stops - starts) / FPS
        assert dur.min() >= 0.09 and dur.max() <= 0.31
        assert np.all(np.diff(starts) / FPS > 1.5)
        # confidence dips are runs of 1-20 frames
        edges = np.diff(np.concatenate([[0], tr["eyes_low_conf"].astype(np.int8), [0]]))
        runs = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
        assert len(runs) >= 2 and runs.max() <= 20


def test_one_eyes_file_uses_the_older_comma_space_layout(session: Path, takes: list[dict]) -> None:
    styles = {}
    for t in _follow(takes):
        header = (session / t["eyes"]).read_text().split("\n", 1)[0]
        et = read_openface(session / t["eyes"])
        styles[t["id"]] = (", " in header, et.layout)
        assert load_truth(session, t["id"])["scalars"]["eyes"]["layout"] == et.layout
    assert sorted(styles.values()) == [(False, "openface2"), (False, "openface2"), (True, "openface_legacy")]


# ------------------------------------------------------------------------------------------ Live Link Face
def test_livelinkface_header_is_the_real_apps(session: Path, takes: list[dict]) -> None:
    corpus = CORPUS / "livelinkface" / "alex_rom_3_first300.csv"
    want = corpus.read_text().split("\n", 1)[0].strip().split(",")
    for t in (t for t in takes if t["kind"] == "face"):
        for key in ("tracked", "clean"):
            assert (session / t[key]).read_text().split("\n", 1)[0].split(",") == want


def test_livelinkface_pairs_read_back_with_their_dropped_frames(session: Path, takes: list[dict]) -> None:
    face = [t for t in takes if t["kind"] == "face"]
    assert sorted(set(t["rate_hz"] for t in face)) == [30, 60] and all(t["timecode_fps"] == 60 for t in face)
    for t in face:
        tr = load_truth(session, t["id"])
        assert tr["face_names"] == list(ARKIT_NAMES)
        n = tr["face_time_s"].size
        assert n == pytest.approx(t["rate_hz"] * tr["scalars"]["duration_s"], abs=1)
        kept = {}
        for key in ("clean", "tracked"):
            ft = read_livelinkface(session / t[key], rate_hz=t["rate_hz"], timecode_fps=t["timecode_fps"])
            drop = tr[f"face_{key}_dropped"]
            kept[key] = np.flatnonzero(~drop)
            assert drop.any() and ft.dropped_frames == drop.sum()
            assert np.array_equal(ft.frame_index, kept[key])
            step = 60 // t["rate_hz"]
            assert set(np.diff(ft.tc_frame)) <= {step, 2 * step, 3 * step}
            assert np.allclose(ft.values, tr[f"face_{key}"][kept[key]], atol=1e-6)
            assert np.allclose(ft.time_s, tr["face_time_s"][kept[key]] - tr["face_time_s"][0], atol=2e-5)
            if t["rate_hz"] == 60:
                assert np.allclose(ft.head, tr[f"face_{key}_angles"][kept[key], :3], atol=1e-6)
            else:
                assert np.isnan(ft.head).all()           # head tracking off, as in the real take
        # dropped at different places: aligning the pair on timecode leaves frames of each without the other
        assert set(kept["clean"]) != set(kept["tracked"])


def test_livelinkface_tracked_is_a_learnable_corruption_of_clean(session: Path, takes: list[dict]) -> None:
    for t in (t for t in takes if t["kind"] == "face"):
        tr = load_truth(session, t["id"])
        c = tr["face_clean"].astype(np.float64)
        k = tr["face_tracked"].astype(np.float64)
        assert c.min() >= 0 and c.max() <= 1 and k.min() >= 0 and k.max() <= 1
        names = tr["face_names"]
        busy = [j for j in range(c.shape[1]) if c[:, j].std() > 0.05]
        assert len(busy) >= 20                                # most channels move
        # clean is smooth (the eye channels aside: blinks and saccades are fast); tracked adds noise and jitter
        busy = [j for j in busy if not names[j].startswith("eye")]
        rough_c = np.sqrt(np.mean(np.diff(c[:, busy], 2, axis=0) ** 2))
        rough_k = np.sqrt(np.mean(np.diff(k[:, busy], 2, axis=0) ** 2))
        assert rough_k > 2 * rough_c
        # a systematic bias: blinks are under-reported (gain from a least-squares fit well below 1)
        for side in ("Left", "Right"):
            j = names.index(f"eyeBlink{side}")
            a, b = np.polyfit(c[:, j], k[:, j], 1)
            assert a < 0.9
        # outlier spikes exist and stand out from the tracking noise
        sp = tr["face_spikes"]
        assert sp.any() and np.median((k - c)[sp]) > 0.2
        # left/right mostly symmetric but not identical
        jl, jr = names.index("mouthSmileLeft"), names.index("mouthSmileRight")
        if c[:, jl].std() > 0.02:
            assert np.corrcoef(c[:, jl], c[:, jr])[0, 1] > 0.9 and not np.allclose(c[:, jl], c[:, jr])


# ------------------------------------------------------------------------------------------- determinism
def test_same_seed_gives_identical_video_and_csv_bytes(session: Path, tmp_path: Path) -> None:
    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=10.0, shift_targets=(), neutral_s=1.0,
                      face_takes=((30.0, 4.0),))
    a = generate_session(tmp_path / "a", seed=11, config=cfg)
    b = generate_session(tmp_path / "b", seed=11, config=cfg)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert [str(p) for p in files if p.suffix in (".mp4", ".csv")]
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert [p for p in files if (a / p).read_bytes() != (b / p).read_bytes()] == []
    c = generate_session(tmp_path / "c", seed=12, config=cfg)
    assert (c / "video/follow_standing_01.mp4").read_bytes() != (a / "video/follow_standing_01.mp4").read_bytes()


# ------------------------------------------------------------------------------------------- sample data
def test_sample_session_has_every_modality_within_the_size_budget() -> None:
    total = sum(p.stat().st_size for p in SAMPLE.parent.rglob("*") if p.is_file())
    assert total < 21 * 2**20          # five gaze_follow takes with video and eyes, nine shifts, five face takes
    takes = tomllib.loads((SAMPLE / "session.toml").read_text())["takes"]
    follow = _follow(takes)
    assert follow and all((SAMPLE / t["video"]).is_file() and (SAMPLE / t["eyes"]).is_file() for t in follow)
    face = [t for t in takes if t["kind"] == "face"]
    assert sorted(set(t["rate_hz"] for t in face)) == [30, 60]
    assert all((SAMPLE / t["tracked"]).is_file() and (SAMPLE / t["clean"]).is_file() for t in face)
    for t in follow:
        assert probe_video(SAMPLE / t["video"]).n_frames == load_truth(SAMPLE, t["id"])["scalars"]["video"]["n_frames"]
