"""The synthetic session generator: files per SPEC §1, determinism, and self-consistent ground truth."""

from __future__ import annotations

import json
import struct
import tomllib
from pathlib import Path

import c3d
import ezc3d
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gazepipe.synth import SynthConfig, generate_session, load_truth
from tests.helpers import REPO

RATE = 30000.0 / 1001.0
SMALL = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=16.0,
                    shift_targets=((36.0, 12.0), (-72.0, 0.0), (72.0, -12.0)), neutral_s=2.0)


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_session(tmp_path_factory.mktemp("synth") / "s", seed=7, config=SMALL)


@pytest.fixture(scope="module")
def all_takes(session: Path) -> list[dict]:
    return tomllib.loads((session / "session.toml").read_text())["takes"]


@pytest.fixture(scope="module")
def takes(all_takes: list[dict]) -> list[dict]:
    """The takes with motion capture (not the ``face`` takes)."""
    return [t for t in all_takes if "mocap" in t]


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _rot(q_wxyz: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.asarray(q_wxyz, dtype=float)[..., [1, 2, 3, 0]])


def _char_frame(x: np.ndarray, labels: list[str]) -> Rotation:
    """SPEC §2 character frame written out independently: columns left, up, forward in the Z-up lab."""
    left = x[:, labels.index("PEL_L")] - x[:, labels.index("PEL_R")]
    left = left.astype(float)
    left[:, 2] = 0.0
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    up = np.zeros_like(left)
    up[:, 2] = 1.0
    return Rotation.from_matrix(np.stack([left, up, np.cross(left, up)], axis=2))


def _tri_frame(p: np.ndarray) -> Rotation:
    """Gram–Schmidt frame of a marker triangle (T, 3, 3) (SPEC §3.3, three markers)."""
    e1 = p[:, 1] - p[:, 0]
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    nrm = np.cross(e1, p[:, 2] - p[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return Rotation.from_matrix(np.stack([e1, np.cross(nrm, e1), nrm], axis=2))


def test_same_seed_gives_identical_bytes(session: Path, tmp_path: Path) -> None:
    again = generate_session(tmp_path / "again", seed=7, config=SMALL)
    a, b = _files(session), _files(again)
    assert sorted(a) == sorted(b)
    assert [k for k in a if a[k] != b[k]] == []
    other = _files(generate_session(tmp_path / "other", seed=8, config=SMALL))
    assert other["mocap/follow_standing_01.c3d"] != a["mocap/follow_standing_01.c3d"]


def test_tomls_parse_and_reference_existing_files(session: Path, takes: list[dict], all_takes: list[dict]) -> None:
    doc = tomllib.loads((session / "session.toml").read_text())
    assert doc["schema"] == 1
    ms = tomllib.loads((session / doc["session"]["markerset"]).read_text())
    assert ms["up_axis"] == "z" and ms["root"] == "SACR" and ms["target"] == "POLE"
    assert ms["clapper"] == ["CLAP1", "CLAP2"] and ms["head_centre"] == "HEADC"
    names = list(ms["segments"])
    assert names[0] == "pelvis" and names[-1] == "head" and len(names) == 10
    assert "parent" not in ms["segments"]["pelvis"]
    assert [ms["segments"][n]["parent"] for n in names[1:]] == names[:-1]
    assert ms["segments"]["pelvis"]["markers"][:2] == ["PEL_L", "PEL_R"]
    assert set(ms["lod"]["segments"]) <= set(names)
    assert "camera" not in ms
    kinds = [t["kind"] for t in all_takes]
    assert kinds.count("gaze_follow") == 2 and kinds.count("gaze_shift") == 3 and kinds.count("neutral") == 1
    assert kinds.count("face") == 2 and len(takes) == len(all_takes) - 2
    assert len({t["id"] for t in all_takes}) == len(all_takes)
    for t in all_takes:
        for key in ("mocap", "video", "eyes", "tracked", "clean"):
            if key in t:
                assert (session / t[key]).is_file()
        assert ("video" in t) == ("eyes" in t) == (t["kind"] == "gaze_follow")
        assert ("tracked" in t) == ("clean" in t) == ("timecode_fps" in t) == (t["kind"] == "face")
    for t in takes:
        assert (session / t["mocap"]).is_file()
        assert (session / "truth" / f"{t['id']}.npz").is_file()
        if t["kind"] == "gaze_shift":
            assert set(t["target"]) == {"yaw_deg", "pitch_deg"}
    seg_markers = {m for s in ms["segments"].values() for m in s["markers"]}
    labels = load_truth(session, "follow_standing_01")["labels"]
    assert seg_markers | {"SACR", "HEADC", "POLE", "CLAP1", "CLAP2"} == set(labels)


def test_c3d_reads_back_as_noisy_truth_with_gaps(session: Path, takes: list[dict]) -> None:
    for t in takes:
        path = session / t["mocap"]
        truth = load_truth(session, t["id"])
        c = ezc3d.c3d(str(path))
        assert abs(c["parameters"]["POINT"]["RATE"]["value"][0] - RATE) < 1e-3
        assert c["parameters"]["POINT"]["UNITS"]["value"] == ["mm"]
        assert c["parameters"]["POINT"]["SCALE"]["value"][0] < 0          # float storage
        assert list(c["parameters"]["POINT"]["LABELS"]["value"]) == truth["labels"]
        assert struct.unpack("<H", path.read_bytes()[6:8])[0] == 1          # header: first frame 1
        xyz = np.transpose(c["data"]["points"][:3], (2, 1, 0))
        gap = truth["gap_mask"]
        assert xyz.shape == truth["markers_true"].shape
        assert np.array_equal(np.isnan(xyz).any(axis=2), gap)       # ezc3d turns residual −1 into NaN
        with open(path, "rb") as fh:                                   # raw samples: 0, 0, 0 and residual −1
            raw = np.stack([p for _, p, _ in c3d.Reader(fh).read_frames()])
        assert np.array_equal(raw[:, :, 3] < 0, gap)
        assert np.all(raw[:, :, :3][gap] == 0.0)
        err = (xyz - truth["markers_true"])[~gap]
        assert np.all(np.abs(err) < 3.5)
        assert 0.4 < err.std() < 0.6
        # the gap list is the run-length form of the mask
        rebuilt = np.zeros_like(gap)
        for m, a, b in truth["gaps"]:
            rebuilt[a:b, m] = True
        assert np.array_equal(rebuilt, gap)


def test_gaps_obey_the_rules(session: Path, takes: list[dict]) -> None:
    lengths = []
    for t in takes:
        tr = load_truth(session, t["id"])
        labels, gaps = tr["labels"], tr["gaps"]
        n = tr["gap_mask"].shape[0]
        for m, a, b in gaps:
            if labels[m] in ("SACR", "PEL_L", "PEL_R", "PEL_B"):
                assert b - a <= 3
            if labels[m].startswith("CLAP"):
                for tc in tr["clap_times_s"]:
                    assert b / RATE < tc - 1.0 or a / RATE > tc + 0.5
        if t["kind"] == "gaze_follow":
            lengths.extend((gaps[:, 2] - gaps[:, 1]).tolist())
            assert (gaps[:, 1] == 0).any() and (gaps[:, 2] == n).any()
    lengths = np.array(lengths)
    for lo, hi in ((1, 5), (6, 15), (16, 30), (31, 90)):
        assert ((lengths >= lo) & (lengths <= hi)).any()
    assert (lengths > RATE).any()


def test_clusters_are_rigid_and_not_mirrored(session: Path) -> None:
    ms = tomllib.loads((session / "markerset.toml").read_text())
    tr = load_truth(session, "follow_standing_01")
    x, labels = tr["markers_true"].astype(float), tr["labels"]
    for name, seg in ms["segments"].items():
        cols = [labels.index(m) for m in seg["markers"]]
        p = x[:, cols]
        d = np.linalg.norm(p[:, :, None] - p[:, None, :], axis=3)
        assert np.abs(d - d[0]).max() < 2e-3
        if len(cols) == 3 and name != "pelvis":      # spine and neck triangles: 60–120 mm sides
            sides = d[0][np.triu_indices(3, 1)]
            assert sides.min() >= 59.0 and sides.max() <= 121.0
    c = _char_frame(x, labels)
    assert np.allclose(np.linalg.det(c.as_matrix()), 1.0)
    # neutral heading: forward is the lab +Y turned 35° about +Z, so the lab frame is not the character frame
    fwd = c[0].apply([0.0, 0.0, 1.0])
    assert np.allclose(fwd, [-np.sin(np.deg2rad(35)), np.cos(np.deg2rad(35)), 0.0], atol=1e-5)
    # the subject's left markers are on +X of the character frame, the head above the pelvis
    rel = c[0].inv().apply(x[0] - x[0, labels.index("SACR")])
    assert rel[labels.index("HFL"), 0] > 0 > rel[labels.index("HFR"), 0]
    assert rel[labels.index("HEADC"), 1] > 500.0 and rel[labels.index("HEADC"), 2] > 100.0


def test_segment_rotations_match_the_markers(session: Path, takes: list[dict]) -> None:
    ms = tomllib.loads((session / "markerset.toml").read_text())
    for t in takes:
        tr = load_truth(session, t["id"])
        x, labels = tr["markers_true"].astype(float), tr["labels"]
        c = _char_frame(x, labels)
        q = tr["seg_quat_char"]
        r0 = tr["rest_periods"][0]
        assert r0[0] == 0
        still = min(r0[1], int(tr["scalars"]["design"].get("rest1_s", 1e9) * RATE))
        for k, name in enumerate(tr["segments"]):
            rot = _rot(q[:, k])
            assert rot[:still].magnitude().max() < 1e-6          # identity in the neutral pose, first rest
            assert rot[:r0[1]].magnitude().max() < np.deg2rad(0.5)   # the rest's tail: barely moving
            cols = [labels.index(m) for m in ms["segments"][name]["markers"][:3]]
            m = _tri_frame(x[:, cols])
            calib = c.inv() * m * m[0].inv() * c[0]
            assert (calib * rot.inv()).magnitude().max() < 1e-4
            parent = ms["segments"][name].get("parent")
            if parent:
                loc = _rot(q[:, tr["segments"].index(parent)]).inv() * rot
                assert (loc * _rot(tr["seg_quat_local"][:, k]).inv()).magnitude().max() < 1e-5
        hc = c.inv().apply(x[:, labels.index("HEADC")] - x[:, labels.index("SACR")])
        assert np.abs(hc - tr["head_centre_char"]).max() < 1e-2
        head = _rot(q[:, tr["segments"].index("head")])
        assert np.abs(head.apply(tr["eye_dir_head"]) - tr["eye_dir_char"]).max() < 1e-5


def test_follow_targets_and_eyes(session: Path, takes: list[dict]) -> None:
    for t in (t for t in takes if t["kind"] == "gaze_follow"):
        tr = load_truth(session, t["id"])
        x, labels = tr["markers_true"].astype(float), tr["labels"]
        c = _char_frame(x, labels)
        v = c.inv().apply(x[:, labels.index("POLE")] - x[:, labels.index("HEADC")])
        assert np.abs(v / np.linalg.norm(v, axis=1, keepdims=True) - tr["target_dir_char"]).max() < 1e-5
        assert np.min(np.linalg.norm(v, axis=1)) > 790.0
        # still at the end, fixating the pole: eye and target directions agree
        last = tr["rest_periods"][-1]
        cos = np.sum(tr["eye_dir_char"][last[0]:] * tr["target_dir_char"][last[0]:], axis=1)
        assert np.rad2deg(np.arccos(np.clip(cos.min(), -1, 1))) < 0.5
        # while moving, the eyes lag the target by a human reaction time: some error, but bounded on average
        a, b = tr["crop"]
        ang = np.rad2deg(np.arccos(np.clip(np.sum(tr["eye_dir_char"][a:b] * tr["target_dir_char"][a:b], 1), -1, 1)))
        assert 0.5 < np.median(ang) < 20.0
        assert len(tr["clap_times_s"]) == 2


def test_claps_close_fast_and_stay_shut(session: Path, takes: list[dict]) -> None:
    for t in (t for t in takes if t["kind"] == "gaze_follow"):
        tr = load_truth(session, t["id"])
        x, labels = tr["markers_true"].astype(float), tr["labels"]
        d = np.linalg.norm(x[:, labels.index("CLAP1")] - x[:, labels.index("CLAP2")], axis=1)
        rests = tr["rest_periods"]
        tc1, tc2 = tr["clap_times_s"]
        assert rests[0, 0] / RATE < tc1 < rests[0, 1] / RATE - 0.5
        assert rests[-1, 0] / RATE < tc2 < rests[-1, 1] / RATE - 0.5
        for tc in (tc1, tc2):
            after = int(np.ceil(tc * RATE))
            shut = d[after:after + int(0.5 * RATE)]
            assert np.allclose(shut, shut[0], atol=1e-3) and 20.0 < shut[0] < 30.0
            assert d[after - 1] > shut[0]                   # the frame before contact is still open
            assert d[int(np.floor((tc - 0.1) * RATE))] > 60.0    # 100 ms before, it is well open
            assert 120.0 < d[int((tc - 0.4) * RATE)] < 180.0     # opened wide before closing


def test_shift_eyes_reach_the_requested_direction(session: Path, takes: list[dict]) -> None:
    for t in (t for t in takes if t["kind"] == "gaze_shift"):
        tr = load_truth(session, t["id"])
        yaw, pitch = np.deg2rad(t["target"]["yaw_deg"]), np.deg2rad(t["target"]["pitch_deg"])
        c = _char_frame(tr["markers_true"].astype(float), tr["labels"])
        c0, c1 = tr["crop"]
        assert c1 == len(c) and 0 < c0 < c1
        want = Rotation.from_euler("YX", [yaw, -pitch]).apply([0.0, 0.0, 1.0])
        got = (c[c0].inv() * c[c1 - 1]).apply(tr["eye_dir_char"][c1 - 1])
        assert np.abs(got - want).max() < 1e-5
        assert np.sign(got[0]) == np.sign(yaw)        # positive yaw is toward the character's left (+X)
        s = tr["scalars"]
        assert 0.3 < s["l_s"] < 2.0 and 0.0 < s["t_beta_frac"] < 1.0 and 0.0 < s["beta"] < 0.4
        # P+ of the eyes composed with the head's displacement gives the requested change
        head = tr["segments"].index("head")
        q = _rot(tr["seg_quat_char"][:, head])
        fix = c[c0].inv() * c                       # per-frame character frame -> frame fixed at c0
        d_head = (fix[c1 - 1] * q[c1 - 1]) * (fix[c0] * q[c0]).inv()
        eyes = _rot(s["p_plus"]["eyes"])
        assert np.abs((d_head * eyes).apply([0, 0, 1.0]) - want).max() < 1e-5
        assert s["design"]["onset_s"] == sorted(s["design"]["onset_s"], reverse=True)


def test_neutral_take_is_still(session: Path) -> None:
    tr = load_truth(session, "neutral")
    assert tr["rest_periods"].tolist() == [[0, tr["gap_mask"].shape[0]]]
    assert _rot(tr["seg_quat_char"].reshape(-1, 4)).magnitude().max() < 1e-5
    assert np.ptp(tr["markers_true"], axis=0).max() < 1e-3


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.rad2deg(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def test_follow_eyes_lead_the_head(session: Path, takes: list[dict]) -> None:
    for t in (t for t in takes if t["kind"] == "gaze_follow"):
        tr = load_truth(session, t["id"])
        a, b = tr["crop"]
        head_fwd = _rot(tr["seg_quat_char"][a:b, tr["segments"].index("head")]).apply([0.0, 0.0, 1.0])
        eye_err = _angle_deg(tr["eye_dir_char"][a:b], tr["target_dir_char"][a:b])
        head_err = _angle_deg(head_fwd, tr["target_dir_char"][a:b])
        assert np.median(eye_err) < 0.5 * np.median(head_err)
        # eyes stay inside their 45° range in the head
        assert _angle_deg(tr["eye_dir_head"], np.array([0.0, 0.0, 1.0])).max() < 45.0 + 1e-3
        # per-eye directions converge on the fixation point: the left eye (+X) looks a little to the right
        head = _rot(tr["seg_quat_char"][:, tr["segments"].index("head")]).inv()
        left_x = head.apply(tr["eye_left_dir_char"])[:, 0]
        right_x = head.apply(tr["eye_right_dir_char"])[:, 0]
        assert np.median(left_x - tr["eye_dir_head"][:, 0]) < 0 < np.median(right_x - tr["eye_dir_head"][:, 0])
        assert np.all(_angle_deg(tr["eye_left_dir_char"], tr["eye_dir_char"]) < 5.0)


def test_rests_follow_the_spec_rule(session: Path, takes: list[dict]) -> None:
    """Rests recomputed here with a plain loop over frames (SPEC §3.2 on noise-free positions)."""
    for t in takes[:3]:
        tr = load_truth(session, t["id"])
        subj = [i for i, lab in enumerate(tr["labels"]) if lab != "POLE" and not lab.startswith("CLAP")]
        x = tr["markers_true"][:, subj].astype(float)
        v = np.gradient(x, axis=0) * RATE
        still = np.linalg.norm(v, axis=2).mean(axis=1) < 6.0
        runs: list[list[int]] = []
        for i, s in enumerate(still):
            if s and runs and runs[-1][1] == i:
                runs[-1][1] = i + 1
            elif s:
                runs.append([i, i + 1])
        merged: list[list[int]] = []
        for r in runs:
            if merged and (r[0] - merged[-1][1]) < RATE / 6.0:
                merged[-1][1] = r[1]
            else:
                merged.append(r)
        expect = [r for r in merged if r[1] - r[0] >= 0.25 * RATE]
        assert tr["rest_periods"].tolist() == expect
        if t["kind"] == "gaze_follow":
            assert tr["crop"].tolist() == [expect[0][1], expect[-1][0]]


def test_shift_overshoot_rule_recovers_the_design(session: Path, takes: list[dict]) -> None:
    for t in (t for t in takes if t["kind"] == "gaze_shift"):
        s = load_truth(session, t["id"])["scalars"]
        d, loc = s["design"], s["overshoot_head_local"]
        c0 = s["crop"][0]
        # the crop starts after the head began to move: the displacement counts from there
        u = (c0 / RATE - d["onset_s"][-1]) / d["duration_s"] / d["u_beta"]
        u = min(max(u, 0.0), 1.0)
        p0 = (1.0 + d["beta"]) * u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)
        assert 0.0 <= p0 < 0.3
        assert loc["beta"] == pytest.approx(d["beta"] / (1.0 - p0), abs=0.01)
        assert loc["t_beta_frac"] * s["l_s"] + c0 / RATE == pytest.approx(d["t_beta_s"], abs=1.0 / RATE)
        assert 0.0 <= s["beta"] <= d["beta"] + 0.01      # the head's global overshoot is damped by the chain


def test_shift_cascade_is_measurable(session: Path, takes: list[dict]) -> None:
    for t in (t for t in takes if t["kind"] == "gaze_shift" and abs(t["target"]["yaw_deg"]) > 60):
        s = load_truth(session, t["id"])["scalars"]
        sf, onset = s["start_frac"], s["design"]["onset_s"]
        assert 0.0 < sf["chest"] < sf["pelvis"] < 1.0
        for name in ("chest", "pelvis"):      # the 18°/s rule fires after the segment's designed onset
            start = s["crop"][0] / RATE + sf[name] * s["l_s"]
            k = load_truth(session, t["id"])["segments"].index(name)
            assert onset[k] < start < onset[k] + 0.5


def test_modality_writers_plug_in(tmp_path: Path) -> None:
    seen = []

    def eyes_writer(session_dir: Path, take) -> dict:
        if take.kind != "gaze_follow":
            return {}
        rel = f"eyes/{take.id}.csv"
        (session_dir / "eyes").mkdir(exist_ok=True)
        (session_dir / rel).write_text("frame\n")
        seen.append((take.id, take.truth_arrays["eye_dir_head"].shape, take.camera_to_head.as_quat().shape))
        take.truth_scalars["eyes_rows"] = 1
        return {"eyes": rel}

    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=12.0, shift_targets=(), neutral_s=0.0,
                      head_camera=False, face_takes=())
    out = generate_session(tmp_path / "w", seed=1, config=cfg, writers=[eyes_writer])
    (take,) = tomllib.loads((out / "session.toml").read_text())["takes"]
    assert take["eyes"] == "eyes/follow_standing_01.csv" and (out / take["eyes"]).is_file()
    assert load_truth(out, take["id"])["scalars"]["eyes_rows"] == 1
    assert seen[0][2] == (4,)


def decoded_video(path: Path) -> tuple[int, str]:
    """A video as its reader sees it: (frames, SHA-256 of every decoded frame's pixels and timestamp)."""
    import hashlib

    import cv2

    cap = cv2.VideoCapture(str(path))
    digest, n = hashlib.sha256(), 0
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            digest.update(np.float64(cap.get(cv2.CAP_PROP_POS_MSEC)).tobytes())
            digest.update(np.ascontiguousarray(frame).tobytes())
            n += 1
    finally:
        cap.release()
    return n, digest.hexdigest()


def decoded_c3d(path: Path) -> tuple[str, str]:
    """A C3D as a reader sees it, less the writer's version stamp (group EZC3D): (its header and parameters,
    SHA-256 of its point and analog data)."""
    import hashlib

    import ezc3d

    c3d = ezc3d.c3d(str(path))
    params = {(group, name): repr(entry["value"]) for group, entries in c3d["parameters"].items()
              if group != "EZC3D" and isinstance(entries, dict)
              for name, entry in entries.items() if isinstance(entry, dict) and "value" in entry}
    digest = hashlib.sha256()
    for key in ("points", "analogs"):
        digest.update(np.ascontiguousarray(c3d["data"][key]).tobytes())
    digest.update(np.ascontiguousarray(c3d["data"]["meta_points"]["residuals"]).tobytes())
    assert params, path
    return repr((sorted(c3d["header"]["points"].items()), sorted(params.items()))), digest.hexdigest()


def assert_close_json(ours: object, theirs: object, where: str) -> None:
    """Equal JSON documents, but for floats within round-off of each other."""
    if isinstance(ours, dict) and isinstance(theirs, dict):
        assert ours.keys() == theirs.keys(), where
        for key in ours:
            assert_close_json(ours[key], theirs[key], f"{where}:{key}")
    elif isinstance(ours, list) and isinstance(theirs, list):
        assert len(ours) == len(theirs), where
        for i, (a, b) in enumerate(zip(ours, theirs, strict=True)):
            assert_close_json(a, b, f"{where}[{i}]")
    elif isinstance(ours, float) and isinstance(theirs, float):
        np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-9, err_msg=where)
    else:
        assert ours == theirs, where


def test_module_entry_writes_the_bundled_sample(tmp_path: Path) -> None:
    """``python -m gazepipe.synth OUT`` writes the bundled sample byte for byte (so it can be regenerated), with
    five gaze_follow and five face takes (every split of every dataset gets one)."""
    import filecmp

    from gazepipe.synth.__main__ import main

    assert main([str(tmp_path / "s")]) == 0
    doc = tomllib.loads((tmp_path / "s" / "session.toml").read_text())
    kinds = [t["kind"] for t in doc["takes"]]
    assert kinds.count("gaze_follow") == 5 and kinds.count("gaze_shift") >= 8 and "neutral" in kinds
    assert kinds.count("face") == 5
    assert all("video" in t and "eyes" in t for t in doc["takes"] if t["kind"] == "gaze_follow")
    assert sum(t["target"]["yaw_deg"] < 0 for t in doc["takes"] if "target" in t) >= 3
    sample = REPO / "sample_data" / "session01"
    ours = sorted(p.relative_to(tmp_path / "s") for p in (tmp_path / "s").rglob("*") if p.is_file())
    theirs = sorted(p.relative_to(sample) for p in sample.rglob("*") if p.is_file())
    assert ours == theirs
    _, mismatch, errors = filecmp.cmpfiles(tmp_path / "s", sample, [str(p) for p in ours], shallow=False)
    assert not errors
    # videos are compared as what a reader decodes (every frame's pixels and timestamp): the container's bytes
    # depend on the FFmpeg that OpenCV ships (OpenCV 5.1 writes another mux tag), not on the generator
    for name in (m for m in mismatch if m.endswith(".mp4")):
        ours_video = decoded_video(tmp_path / "s" / name)
        assert ours_video[0] > 100 and ours_video == decoded_video(sample / name), name
    # C3D files likewise as what a reader decodes: ezc3d stamps its own version into the files it writes
    for name in (m for m in mismatch if m.endswith(".c3d")):
        assert decoded_c3d(tmp_path / "s" / name) == decoded_c3d(sample / name), name
    # the ground truth is float64 arithmetic whose last bits may differ between numpy and scipy releases (seen:
    # 2e-13 mm), so its numbers are compared to round-off
    for name in (m for m in mismatch if m.endswith(".json")):
        assert_close_json(json.loads((tmp_path / "s" / name).read_text()), json.loads((sample / name).read_text()),
                          name)
    assert not [m for m in mismatch if not m.endswith((".npz", ".mp4", ".c3d", ".json"))], mismatch[:5]
    for name in (m for m in mismatch if m.endswith(".npz")):
        with np.load(tmp_path / "s" / name) as ours_npz, np.load(sample / name) as theirs_npz:
            assert ours_npz.files == theirs_npz.files
            for key in ours_npz.files:
                a, b = ours_npz[key], theirs_npz[key]
                assert a.dtype == b.dtype and a.shape == b.shape, (name, key)
                if a.dtype.kind == "f":
                    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9, err_msg=f"{name}:{key}")
                else:
                    assert np.array_equal(a, b), (name, key)


def test_a_four_segment_layout_in_a_y_up_lab(tmp_path):
    """Markers on four of the chain's segments, written in y-up lab axes: the markerset lists those segments
    (each the parent of the next) with its [lod]; the C3D holds the truth's lab positions plus noise, the body
    standing along +Y; the captures of the z-up, ten-segment default are not touched by the option."""
    import dataclasses
    import tomllib

    from gazepipe.io.capture import read_markers
    from gazepipe.synth.skeleton import FOUR_SEGMENTS

    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=6.0, shift_targets=(), neutral_s=2.0,
                      head_camera=False, face_takes=(), gaps=False)
    out = generate_session(tmp_path / "y", seed=3, config=dataclasses.replace(cfg, segments=FOUR_SEGMENTS,
                                                                               up_axis="y"))
    ms = tomllib.loads((out / "markerset.toml").read_text())
    assert ms["up_axis"] == "y" and list(ms["segments"]) == list(FOUR_SEGMENTS)
    assert [ms["segments"][s].get("parent") for s in FOUR_SEGMENTS] == [None, "pelvis", "chest", "neck2"]
    assert ms["lod"]["segments"] == ["pelvis", "chest", "head"]
    mk = read_markers(out / "mocap" / "follow_standing_01.c3d")
    truth = load_truth(out, "follow_standing_01")
    arrays = truth
    assert list(arrays["labels"]) == mk.labels and "SP1A" not in mk.labels and "NK2A" in mk.labels
    err = np.linalg.norm(mk.xyz - arrays["markers_true"], axis=2)
    assert np.median(err) < 1.5 and err.max() < 5.0                        # 0.5 mm noise per axis
    pel = mk.xyz[:, mk.labels.index("PEL_L")]
    assert 900 < np.median(pel[:, 1]) < 1200                                 # the pelvis stands along +Y
    assert truth["session"]["marker_segments"] == list(FOUR_SEGMENTS) and truth["session"]["up_axis"] == "y"
    z_up = generate_session(tmp_path / "z", seed=3, config=cfg)
    assert (z_up / "mocap" / "follow_standing_01.c3d").read_bytes() != (out / "mocap" / "follow_standing_01.c3d").read_bytes()
    assert "up_axis" not in load_truth(z_up, "follow_standing_01")["session"]


def test_gaze_shift_capture_hazards(tmp_path):
    """body_steps, root_rest_gaps and clap_rebounds (SynthConfig): the whole body steps in the room as the gaze
    change ends (and the truth's second rest starts after it), a pelvis marker is lost inside a rest, and the
    clapper stick bounces open right after contact; the defaults stay without them."""
    from gazepipe.synth import load_truth
    from gazepipe.synth.motion import CLAP_SHUT_MM
    from gazepipe.synth.skeleton import SEGMENT_MARKERS

    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=8.0, head_camera=False, face_takes=(),
                      shift_targets=((36.0, 12.0), (-72.0, 0.0)), neutral_s=0.0, body_steps=1.0,
                      root_rest_gaps=True, clap_rebounds=1.0)
    folder = generate_session(tmp_path / "s", seed=1, config=cfg)
    meta = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    for take, t in meta.items():
        tr = load_truth(folder, take)
        labels = list(tr["labels"])
        x = tr["markers_true"].astype(np.float64)
        rate = float(t["rate_hz"])
        pelvis = [labels.index(n) for n in SEGMENT_MARKERS["pelvis"] if n in labels]
        rests = np.asarray(t["rest_periods"])
        lost = tr["gap_mask"][:, pelvis]
        assert any(lost[a:b].any(axis=0).max() and lost[a:b].sum() >= 0.5 * rate - 1 for a, b in rests), take
        if t["kind"] == "gaze_shift":
            step = t["design"]["step"]
            root = x[:, labels.index("SACR")]
            moved = np.linalg.norm(root[-1] - root[0])
            # (the sacrum also swings with the pelvis' own turn in the shift: up to ~15 mm)
            assert moved == pytest.approx(np.linalg.norm(step["lab_mm"]), abs=20.0)
            assert rests[1][0] / rate >= step["start_s"] + 0.8 * step["duration_s"], (rests, step)
        else:
            bounce = np.asarray(t["design"]["clap_rebound"])
            d = np.linalg.norm(x[:, labels.index("CLAP2")] - x[:, labels.index("CLAP1")], axis=1)
            for tc, (mm, dur) in zip(t["clap_times_s"], bounce, strict=True):
                after = d[int(np.ceil(tc * rate)):int(np.ceil((tc + dur) * rate))]
                assert 3.0 <= mm <= 6.0 and CLAP_SHUT_MM + 1e-3 < after.max() <= CLAP_SHUT_MM + mm   # noise-free


def test_occlusion_bursts_hide_one_side_of_the_body_at_once() -> None:
    from numpy.linalg import lstsq

    from gazepipe.stages.clean.filters import true_runs
    from gazepipe.synth.markers import BURST_S, make_occlusion_bursts
    from gazepipe.synth.skeleton import subject_marker_layout

    labels, _, offsets = subject_marker_layout()
    rng = np.random.default_rng(1)
    n, rate = 3000, 120.0
    xyz = np.broadcast_to(offsets[None] + [0.0, 0.0, 1000.0], (n, len(labels), 3)).copy()
    mask = make_occlusion_bursts(rng, labels, xyz, rate, 4)
    share = mask.mean(axis=1)
    assert share.max() >= 0.3 and share.max() <= 0.8 + 1e-9
    runs = true_runs(share > 0)
    assert 1 <= len(runs) <= 4 and mask[0].sum() == 0
    for a, b in runs:
        assert b - a <= int(BURST_S[1] * rate) * 2            # two bursts may touch
        hidden = mask[a]
        # one side: a plane separates the hidden markers from the seen ones
        side = lstsq(np.c_[offsets, np.ones(len(labels))], np.where(hidden, 1.0, -1.0), rcond=None)[0]
        assert ((np.c_[offsets, np.ones(len(labels))] @ side > 0) == hidden).mean() > 0.9


def test_module_entry_options_make_a_harder_session(tmp_path: Path) -> None:
    """``--skeleton four --label-swaps 1 --no-eyes`` writes the four-segment markerset in y-up axes, swaps in the
    truth and no eye tracking; a share outside 0-1 is refused by the command line."""
    from gazepipe.synth.__main__ import main

    assert main([str(tmp_path / "s"), "--seed", "2", "--skeleton", "four", "--label-swaps", "1", "--no-eyes"]) == 0
    ms = tomllib.loads((tmp_path / "s" / "markerset.toml").read_text())
    assert ms["up_axis"] == "y" and list(ms["segments"]) == ["pelvis", "chest", "neck2", "head"]
    doc = tomllib.loads((tmp_path / "s" / "session.toml").read_text())
    assert not any("eyes" in t or "video" in t for t in doc["takes"])
    truth = json.loads((tmp_path / "s" / "truth" / "truth.json").read_text())
    assert any(t.get("swap_samples") for t in truth["takes"].values())
    with pytest.raises(SystemExit) as exc:
        main([str(tmp_path / "t"), "--clap-hazards", "1.5"])
    assert exc.value.code == 2
