"""Tests of the frames stage and the rotation helpers on synthetic rigid clusters with known rotations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gazepipe.errors import StageError
from gazepipe.model import Markers, MarkerSet, Segment
from gazepipe.stages.frames.stage import FramesParams, character_frame, compute_frames
from gazepipe.stages.geometry import (
    from_wxyz,
    kabsch,
    matrix_from_six,
    rotation_from_six,
    six_from_rotation,
    to_wxyz,
)

RATE = 120.0
# body geometry in the character frame of the neutral pose (mm; +X left, +Y up, +Z forward)
CENTRES = {"pelvis": [0, 100, 0], "spine": [0, 350, -20], "head": [0, 750, 0]}
OFFSETS = {
    "pelvis": [[120, 0, -40], [-120, 0, -40], [0, 30, -110]],          # left, right, back
    "spine": [[60, 0, -90], [-60, 0, -90], [0, 110, -100]],
    "head": [[70, 60, 60], [-70, 60, 60], [70, 60, -80], [-70, 60, -80], [0, 130, 0]],  # Pejsa's hat
}
NAMES = {"pelvis": ["PEL1", "PEL2", "PEL3"], "spine": ["SPN1", "SPN2", "SPN3"],
         "head": ["HFL", "HFR", "HBL", "HBR", "HTOP"]}
HEADC_OFF = np.array([0.0, -40.0, 95.0])
#: what the markers alone give, without filling segment rotations across their gaps
NO_ROT_FILL = FramesParams(max_fill_error_deg=0.0)      # eyes' centre relative to the head segment's centre
TARGET_CHAR = np.array([600.0, 900.0, 1800.0])


def markerset(up: str = "z", headc: bool = True, eye_offset=None) -> MarkerSet:
    segs = (Segment("pelvis", tuple(NAMES["pelvis"])), Segment("spine", tuple(NAMES["spine"]), "pelvis"),
            Segment("head", tuple(NAMES["head"]), "spine"))
    return MarkerSet(path="markerset.toml", up_axis=up, units="mm", root="SACR", target="POLE", clapper=(),
                     segments=segs, head_centre="HEADC" if headc else None, eye_offset_mm=eye_offset)


def lab_from_char0(up: str) -> np.ndarray:
    """Columns = character axes in lab at heading 0: z-up: left = +y, up = +z, forward = +x."""
    if up == "z":
        return np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], dtype=float)
    return np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)  # y-up: left +x, up +y, forward +z


def build(n: int, rots: dict[str, Rotation], heading: np.ndarray, origin: np.ndarray, up: str = "z",
          noise: float = 0.0, seed: int = 0) -> tuple[Markers, dict]:
    """Markers of the rigid model with segment rotations ``rots`` (character frame), heading angle (rad, about
    the vertical) and lab origin per frame. Returns the markers and truth (character-frame quantities)."""
    rng = np.random.default_rng(seed)
    c0 = lab_from_char0(up)
    upv = c0[:, 1]
    cmat = Rotation.from_rotvec(heading[:, None] * upv[None, :]).as_matrix() @ c0   # (n, 3, 3)
    labels, char_pts = ["SACR"], [np.zeros((n, 3))]
    for seg in ("pelvis", "spine", "head"):
        r = rots[seg].as_matrix()
        for name, off in zip(NAMES[seg], OFFSETS[seg], strict=True):
            labels.append(name)
            char_pts.append(np.asarray(CENTRES[seg]) + r @ np.asarray(off, dtype=float))
    rh = rots["head"].as_matrix()
    headc = np.asarray(CENTRES["head"]) + rh @ HEADC_OFF
    labels += ["HEADC", "POLE"]
    char_pts += [headc, np.broadcast_to(TARGET_CHAR, (n, 3))]
    char = np.stack(char_pts, axis=1)                                   # (n, M, 3)
    lab = origin[:, None, :] + np.einsum("tij,tmj->tmi", cmat, char)
    lab = lab + rng.normal(0.0, noise, lab.shape)
    mk = Markers(labels=labels, xyz=lab, valid=np.ones(lab.shape[:2], bool), rate_hz=RATE)
    d = TARGET_CHAR - headc
    truth = {"headc": headc, "target_dir": d / np.linalg.norm(d, axis=1, keepdims=True), "cmat": cmat}
    return mk, truth


def random_rots(n: int, seed: int) -> dict[str, Rotation]:
    """Smooth, large rotations per segment; the root only pitches and rolls (its heading is the frame's)."""
    t = np.arange(n) / RATE
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0, 2 * np.pi, 9)
    pel = Rotation.from_euler("ZX", np.stack([0.15 * np.sin(1.1 * t + ph[0]), 0.25 * np.sin(0.7 * t + ph[1])], 1))
    spine = Rotation.from_rotvec(np.stack([0.4 * np.sin(0.9 * t + ph[2]), 0.6 * np.sin(0.5 * t + ph[3]),
                                           0.3 * np.sin(1.3 * t + ph[4])], 1))
    head = Rotation.from_rotvec(np.stack([0.5 * np.sin(1.7 * t + ph[5]), 1.2 * np.sin(0.8 * t + ph[6]),
                                          0.3 * np.sin(1.9 * t + ph[7])], 1))
    return {"pelvis": pel, "spine": spine, "head": head}


def ident(n: int) -> dict[str, Rotation]:
    return {k: Rotation.identity(n) for k in ("pelvis", "spine", "head")}


def angles_deg(q_wxyz: np.ndarray, truth: Rotation) -> np.ndarray:
    return np.degrees((from_wxyz(q_wxyz) * truth.inv()).magnitude())


@pytest.fixture(scope="module")
def take():
    n = 600
    t = np.arange(n) / RATE
    rots = random_rots(n, 1)
    heading = 0.8 * np.sin(0.3 * t) + 0.5
    origin = np.stack([200 * np.sin(0.2 * t), 100 * t, 5 * np.cos(t)], 1) + [1000, -500, 950]
    mk, truth = build(n, rots, heading, origin, noise=0.5, seed=2)
    nn = 60
    neutral, _ = build(nn, ident(nn), np.full(nn, -1.1), np.tile([300.0, 200, 940], (nn, 1)), noise=0.5, seed=3)
    return mk, neutral, rots, truth


@pytest.mark.parametrize("triangle", ["rigid_fit", "gram_schmidt"])
def test_orientations_recovered(take, triangle):
    mk, neutral, rots, _ = take
    j = compute_frames(mk, markerset(), neutral, FramesParams(triangle=triangle))
    assert j.valid.all()
    for s, name in enumerate(j.segments):
        err = angles_deg(j.quat[:, s], rots[name])
        # 0.5 mm noise on clusters of ~120–240 mm: a few tenths of a degree expected
        assert np.median(err) < 1.0, name
        assert np.percentile(err, 99) < 3.0, name


def test_identity_in_neutral(take):
    _, neutral, _, _ = take
    j = compute_frames(neutral, markerset(), neutral)
    for s in range(len(j.segments)):
        r = from_wxyz(j.quat[:, s])
        assert r.mean().magnitude() < 1e-9               # calibration maps the neutral mean exactly to identity
        assert np.median(r.magnitude()) < np.radians(1.0)


def test_neutral_heading_and_position_do_not_matter(take):
    mk, neutral, rots, _ = take
    nn = 60
    other, _ = build(nn, ident(nn), np.full(nn, 2.0), np.tile([-800.0, 40, 900], (nn, 1)), noise=0.5, seed=4)
    a = compute_frames(mk, markerset(), neutral)
    b = compute_frames(mk, markerset(), other)
    diff = np.degrees((from_wxyz(a.quat.reshape(-1, 4)) * from_wxyz(b.quat.reshape(-1, 4)).inv()).magnitude())
    assert np.median(diff) < 0.5


def test_six_number_form(take):
    mk, neutral, _, _ = take
    j = compute_frames(mk, markerset(), neutral)
    r = from_wxyz(j.quat.reshape(-1, 4))
    six = j.six.reshape(-1, 6)
    np.testing.assert_allclose(six[:, :3], r.apply([0.0, 0.0, 1.0]), atol=1e-12)   # forward first
    np.testing.assert_allclose(six[:, 3:], r.apply([0.0, 1.0, 0.0]), atol=1e-12)   # then up
    back = rotation_from_six(six)
    assert np.max((back * r.inv()).magnitude()) < 1e-9


def test_six_helpers_known_rotation():
    r = Rotation.from_euler("y", 90, degrees=True)   # yaw 90° toward +X (left): forward ẑ → x̂
    np.testing.assert_allclose(six_from_rotation(r), [1, 0, 0, 0, 1, 0], atol=1e-12)
    # non-orthogonal input is orthonormalised, forward kept
    m = matrix_from_six(np.array([0.0, 0.0, 2.0, 0.3, 1.0, 0.5]))
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(m[:, 2], [0, 0, 1], atol=1e-12)
    assert np.linalg.det(m) == pytest.approx(1.0)


def test_quaternion_order_and_sign():
    r = Rotation.from_rotvec([0.0, 0.0, np.pi / 2])
    q = to_wxyz(r)
    np.testing.assert_allclose(q, [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], atol=1e-12)
    assert to_wxyz(Rotation.from_quat([0, 0, 0, -1]))[0] == 1.0   # canonical w ≥ 0


def test_local_is_parent_inverse_times_global(take):
    mk, neutral, rots, _ = take
    j = compute_frames(mk, markerset(), neutral)
    for s, p in enumerate(j.parents):
        g = from_wxyz(j.quat[:, s])
        loc = from_wxyz(j.quat_local[:, s])
        expect = g if p < 0 else from_wxyz(j.quat[:, p]).inv() * g
        assert np.max((loc * expect.inv()).magnitude()) < 1e-9
    # and against the truth
    truth = rots["spine"].inv() * rots["head"]
    assert np.median(angles_deg(j.quat_local[:, 2], truth)) < 1.0


@pytest.mark.parametrize("up", ["z", "y"])
def test_character_axes(up):
    """Subject facing lab +x (z-up) or +z (y-up): a marker on the subject's left gets +X, above +Y, ahead +Z."""
    n = 4
    mk, truth = build(n, ident(n), np.zeros(n), np.tile([10.0, 20, 30], (n, 1)), up=up)
    origin, c = character_frame(mk, markerset(up))
    np.testing.assert_allclose(origin, mk.xyz[:, 0])
    c0 = lab_from_char0(up)
    np.testing.assert_allclose(c, np.broadcast_to(c0, c.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(c), 1.0)
    left_lab, up_lab, fwd_lab = ([0, 1, 0], [0, 0, 1], [1, 0, 0]) if up == "z" else ([1, 0, 0], [0, 1, 0], [0, 0, 1])
    for lab_dir, axis in ((left_lab, 0), (up_lab, 1), (fwd_lab, 2)):
        p = origin + 100.0 * np.asarray(lab_dir, float)
        local = np.einsum("tji,tj->ti", c, p - origin)
        assert np.all(local[:, axis] > 99.9)
    # PEL1 is the subject's left marker by construction: +X
    pel1 = np.einsum("tji,tj->ti", c, mk.xyz[:, mk.index("PEL1")] - origin)
    assert np.all(pel1[:, 0] > 0)


def test_target_direction_and_head_centre(take):
    mk, neutral, _, truth = take
    j = compute_frames(mk, markerset(), neutral)
    np.testing.assert_allclose(np.linalg.norm(j.target_dir, axis=1), 1.0)
    err = np.degrees(np.arccos(np.clip(np.sum(j.target_dir * truth["target_dir"], 1), -1, 1)))
    assert np.median(err) < 1.0
    assert np.median(np.linalg.norm(j.head_centre - truth["headc"], axis=1)) < 2.0


def test_head_centre_from_eye_offset(take):
    """Without HEADC: head markers' centroid + eye_offset in head axes."""
    mk, neutral, _, truth = take
    off = HEADC_OFF - np.mean(OFFSETS["head"], axis=0)        # relative to the head markers' centroid
    j = compute_frames(mk, markerset(headc=False, eye_offset=tuple(off)), neutral)
    assert np.median(np.linalg.norm(j.head_centre - truth["headc"], axis=1)) < 2.0


def test_target_unfilled_is_nan_and_char_missing_invalid(take):
    mk, neutral, _, _ = take
    xyz = mk.xyz.copy()
    xyz[10:20, mk.index("POLE")] = np.nan
    xyz[30:35, mk.index("SACR")] = np.nan
    xyz[50, mk.index("SPN2")] = np.nan
    m2 = Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(2), rate_hz=RATE)
    j = compute_frames(m2, markerset(), neutral, NO_ROT_FILL)
    assert np.isnan(j.target_dir[10:20]).all() and np.isfinite(j.target_dir[20:30]).all()
    assert not j.valid[30:35].any() and not j.valid[50]
    assert j.valid.sum() == len(j.valid) - 6
    assert np.isnan(j.quat[30:35]).all() and np.isnan(j.char_rot[30:35]).all()
    assert np.isnan(j.quat[50, 1]).all() and np.isfinite(j.quat[50, [0, 2]]).all()
    assert np.isnan(j.quat_local[50, 2]).all()      # head local needs the spine


def test_char_rot_maps_character_to_lab(take):
    mk, neutral, _, truth = take
    j = compute_frames(mk, markerset(), neutral)
    np.testing.assert_allclose(from_wxyz(j.char_rot).as_matrix(), truth["cmat"], atol=0.02)


def test_kabsch_recovers_rotation():
    rng = np.random.default_rng(7)
    ref = rng.normal(0, 80, (6, 3))
    r = Rotation.random(50, random_state=8)
    pts = np.einsum("nij,kj->nki", r.as_matrix(), ref) + rng.normal(0, 500, (50, 1, 3))
    got = Rotation.from_matrix(kabsch(ref, pts))
    assert np.max((got * r.inv()).magnitude()) < 1e-9
    # a reflected cluster still gives a proper rotation
    assert np.allclose(np.linalg.det(kabsch(ref, -pts)), 1.0)


def test_no_neutral_fails(take):
    mk, _, _, _ = take
    with pytest.raises(StageError, match="neutral"):
        compute_frames(mk, markerset(), None, take="t1")
    short = Markers(labels=mk.labels, xyz=mk.xyz[:2], valid=mk.valid[:2], rate_hz=RATE)
    with pytest.raises(StageError, match="neutral frame"):
        compute_frames(mk, markerset(), short, FramesParams(min_neutral_frames=3))


def test_deterministic(take):
    mk, neutral, _, _ = take
    a = compute_frames(mk, markerset(), neutral)
    b = compute_frames(mk, markerset(), neutral)
    assert a.quat.tobytes() == b.quat.tobytes() and a.six.tobytes() == b.six.tobytes()


# ------------------------------------------------------------------------------------------------ sample session

from tests.helpers import SAMPLE  # noqa: E402


@pytest.fixture(scope="module")
def sample_joints(tmp_path_factory):
    """Joints of the sample session's gaze takes with their truth: every take cleaned with the optional 10 Hz
    low-pass; the gaze_shift takes also with the defaults."""
    from gazepipe.io.capture import read_markers
    from gazepipe.io.session_toml import load_session
    from gazepipe.stages.clean.stage import CleanParams, clean_markers
    from gazepipe.synth.truth import load_truth

    root = SAMPLE
    ses = load_session(root / "session.toml")
    ms = ses.markerset
    out = {}
    for lp in (None, 10.0):
        params = CleanParams(lowpass_hz=lp)
        neutral_take = next(t for t in ses.takes if t.kind == "neutral")
        neutral = clean_markers(read_markers(neutral_take.mocap), ms, "neutral", params).markers
        rows = []
        kinds = ("gaze_follow", "gaze_shift") if lp else ("gaze_shift",)   # keeps the suite fast
        for t in ses.takes:
            if t.kind not in kinds:
                continue
            res = clean_markers(read_markers(t.mocap), ms, t.kind, params, take=t.id)
            tr = load_truth(root, t.id)
            tr["segment_markers"] = [ms.segment(name).markers for name in tr["segments"]]
            rows.append((t.id, compute_frames(res.markers, ms, neutral, take=t.id), res, tr))
        out[lp] = rows
    return out


def _seg_errors(j, res, tr):
    """Angle errors (N_valid, S) in degrees against the truth, and whether every marker of the segment was
    measured in that frame (gap-filled samples carry the filler's error, tested with the filler)."""
    q = tr["seg_quat_char"][res.frames].astype(np.float64)
    ok = j.valid
    err = np.stack([angles_deg(j.quat[ok, s], from_wxyz(q[ok, s])) for s in range(len(j.segments))], axis=1)
    measured = np.stack([(res.fill_code[ok][:, [res.markers.index(m) for m in seg]] == 0).all(axis=1)
                         for seg in tr["segment_markers"]], axis=1)
    return err, measured


def test_sample_orientations_with_lowpass(sample_joints):
    """With the optional 10 Hz low-pass: median ≤ 1°, p99 ≤ 3° per segment and take (measured markers)."""
    for tid, j, res, tr in sample_joints[10.0]:
        assert j.segments == list(tr["segments"])
        err, measured = _seg_errors(j, res, tr)
        for s, name in enumerate(j.segments):
            e = err[measured[:, s], s]
            assert np.median(e) <= 1.0, (tid, name, np.median(e))
            assert np.percentile(e, 99) <= 3.0, (tid, name, np.percentile(e, 99))


def test_sample_orientations_defaults(sample_joints):
    """Without low-pass the 62 mm neck triangles with 0.5 mm noise sit at a ~0.9–1.05° median (noise floor);
    every frame, gap-filled ones included, stays within a p99 of 3° on most segments."""
    worst = []
    for tid, j, res, tr in sample_joints[None]:
        err, measured = _seg_errors(j, res, tr)
        for s in range(len(j.segments)):
            e = err[measured[:, s], s]
            worst.append(np.median(e))
            assert np.median(e) <= 1.1, (tid, j.segments[s])
            assert np.percentile(e, 99) <= 3.0, (tid, j.segments[s])
    assert np.median(worst) <= 0.8


def test_sample_target_direction(sample_joints):
    for lp in (None, 10.0):
        for tid, j, res, tr in sample_joints[lp]:
            td = tr["target_dir_char"][res.frames].astype(np.float64)
            ok = j.valid & np.isfinite(j.target_dir).all(axis=1) & np.isfinite(td).all(axis=1)
            if not ok.any():
                continue
            cos = np.clip(np.sum(j.target_dir[ok] * td[ok], axis=1), -1.0, 1.0)
            assert np.median(np.degrees(np.arccos(cos))) <= 1.0, tid
            hc = tr["head_centre_char"][res.frames].astype(np.float64)
            assert np.median(np.linalg.norm(j.head_centre[ok] - hc[ok], axis=1)) < 2.0, tid


def test_partial_clusters_fitted_to_markers_present(take):
    """A five-marker head with one or two markers missing is fitted to those present (its accuracy stays that of
    a full cluster, its centroid is carried by the fit); a three-marker segment missing one stays undefined, and
    so does a head left with a collinear or too small subset."""
    mk, neutral, rots, truth = take
    xyz = mk.xyz.copy()
    h = [mk.index(n) for n in NAMES["head"]]
    xyz[100:200, h[4]] = np.nan                   # HTOP: four coplanar markers left
    xyz[250:300, [h[0], h[3]]] = np.nan           # HFL + HBR: three left
    xyz[350:360, [h[0], h[1], h[2]]] = np.nan     # two left: undefined
    xyz[400:410, mk.index("SPN2")] = np.nan       # a triangle loses a marker: undefined
    m2 = Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(2), rate_hz=RATE)
    ms = markerset(headc=False, eye_offset=tuple(HEADC_OFF - np.mean(OFFSETS["head"], axis=0)))
    j = compute_frames(m2, ms, neutral, NO_ROT_FILL)
    full = compute_frames(mk, ms, neutral, NO_ROT_FILL)
    part = np.r_[100:200, 250:300]
    assert j.valid[part].all()
    assert not j.valid[350:360].any() and np.isnan(j.quat[350:360, 2]).all()
    assert not j.valid[400:410].any() and np.isfinite(j.quat[400:410, 2]).all()
    err = angles_deg(j.quat[part, 2], rots["head"][part])
    err_full = angles_deg(full.quat[:, 2], rots["head"])
    assert np.median(err) < 2.0 * np.median(err_full) and err.max() < 2.0   # 0.5 mm noise on a 140 mm cluster
    assert np.median(np.linalg.norm(j.head_centre[part] - truth["headc"][part], axis=1)) < 2.0
    others = np.setdiff1d(np.arange(mk.n_frames), np.r_[part, 350:360, 400:410])
    np.testing.assert_array_equal(j.quat[others], full.quat[others])


def test_partial_cluster_collinear_subset_undefined(take):
    """Three markers left on one line of the reference carry no rotation about it: the segment stays undefined."""
    mk, neutral, _, _ = take
    xyz, nxyz = mk.xyz.copy(), neutral.xyz.copy()
    h = [mk.index(n) for n in NAMES["head"]]
    # move HTOP onto the line HFL–HBR in every frame (neutral included): HFL, HBR, HTOP are collinear
    for arr in (xyz, nxyz):
        arr[:, h[4]] = 0.5 * (arr[:, h[0]] + arr[:, h[3]])
    xyz[20:30, [h[1], h[2]]] = np.nan
    m2 = Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(2), rate_hz=RATE)
    n2 = Markers(labels=neutral.labels, xyz=nxyz, valid=neutral.valid, rate_hz=RATE)
    j = compute_frames(m2, markerset(), n2, NO_ROT_FILL)
    assert not j.valid[20:30].any() and j.valid[30:40].all()


# ------------------------------------------------------------------------------ missing root and neutral markers

@pytest.mark.parametrize("up", ["z", "y"])
@pytest.mark.parametrize("missing", ["PEL1", "PEL2"])
def test_heading_from_the_root_segments_fit_when_one_of_its_markers_is_missing(up, missing):
    """One of the two markers the heading is taken from is gone for 200 frames: the character frame there comes
    from a rigid fit of the others and the root marker to their neutral geometry, within a degree of the truth,
    and every segment keeps its orientation."""
    n = 600
    t = np.arange(n) / RATE
    rots = random_rots(n, 5)
    rots["pelvis"] = Rotation.identity(n)      # the test body's root marker is rigid with its pelvis only so
    mk, truth = build(n, rots, 0.8 * np.sin(0.3 * t), np.tile([1000.0, -500, 950], (n, 1)), up=up, noise=0.5,
                      seed=6)
    neutral, _ = build(60, ident(60), np.full(60, 0.4), np.tile([300.0, 200, 940], (60, 1)), up=up, noise=0.5,
                       seed=7)
    xyz = mk.xyz.copy()
    xyz[200:400, mk.index(missing)] = np.nan
    gapped = Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(2), rate_hz=RATE)
    j = compute_frames(gapped, markerset(up), neutral)
    assert j.qc["heading_fitted_frames"] == 200 and j.valid.all()
    # against the heading SPEC §2 defines, from the complete markers
    full = compute_frames(mk, markerset(up), neutral)
    err = np.degrees((from_wxyz(j.char_rot[200:400]) * from_wxyz(full.char_rot[200:400]).inv()).magnitude())
    assert np.median(err) < 0.5 and err.max() < 1.5
    for s, name in enumerate(j.segments):
        assert np.percentile(angles_deg(j.quat[200:400, s], rots[name][200:400]), 99) < 3.0, name
    # with the root marker gone as well only two markers are left: no fit, no character frame
    xyz[250:260, mk.index("SACR")] = np.nan
    j2 = compute_frames(Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(2), rate_hz=RATE),
                        markerset(up), neutral)
    assert not j2.valid[250:260].any() and j2.valid[200:250].all()


def test_a_marker_missing_from_the_neutral_pose_falls_back_to_the_next_source(take):
    """The first neutral source lacks a spine marker throughout: the spine is calibrated on the second source
    (QC says which), the other segments on the first, and the take does not fail."""
    mk, neutral, rots, _ = take
    xyz = neutral.xyz.copy()
    xyz[:, neutral.index("SPN3")] = np.nan
    holed = Markers(labels=neutral.labels, xyz=xyz, valid=np.isfinite(xyz).all(2), rate_hz=RATE)
    j = compute_frames(mk, markerset(), [("neutral take", holed), ("first rest period", neutral)])
    assert j.qc["neutral_sources"] == {"pelvis": "neutral take", "spine": "first rest period", "head": "neutral take"}
    assert j.valid.all()
    assert np.median(angles_deg(j.quat[:, 1], rots["spine"])) < 1.0
    # no source for the spine at all: it has no orientation, the others do, and QC says why
    j1 = compute_frames(mk, markerset(), [("neutral take", holed)])
    assert np.isnan(j1.quat[:, 1]).all() and np.isfinite(j1.quat[:, [0, 2]]).all()
    assert j1.qc["neutral_sources"]["spine"] is None and any("'spine'" in w for w in j1.qc["warnings"])


def test_segment_rotations_are_filled_across_open_gaps_when_the_hold_out_allows(take):
    """The spine loses a marker for 12 frames and the head for 30: their parent-relative rotations are filled
    across (flagged in rot_filled) within the hold-out's estimate of the truth. At the take's start and end,
    with nothing to meet on one side, the rotations stay missing."""
    mk, neutral, rots, _ = take
    xyz = mk.xyz.copy()
    xyz[300:312, mk.index("SPN2")] = np.nan
    h = [mk.index(n) for n in NAMES["head"]]
    xyz[400:430, h[:3]] = np.nan                     # two head markers left: the head has no rotation there
    xyz[0:5, mk.index("SPN1")] = np.nan
    xyz[595:, h[:3]] = np.nan
    m2 = Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(2), rate_hz=RATE)
    j = compute_frames(m2, markerset(), neutral)
    assert j.rot_filled[300:312, 1].all() and j.rot_filled[400:430, 2].all()
    assert j.rot_filled.sum() == 12 + 30 and j.valid[5:595].all() and not j.valid[595:].any()
    assert not j.valid[:5].any()
    gaps = {(g["segment"], g["start"]): g for g in j.qc["rotation_gaps"]}
    assert gaps[(1, 300)]["filled"] and gaps[(2, 400)]["filled"]
    assert not gaps[(2, 595)]["filled"] and not gaps[(1, 0)]["filled"]
    # the head has no child to span it; its two markers left turn the slerp to meet them
    assert gaps[(2, 400)]["method"] == "slerp+markers"
    for seg, rows in ((1, np.r_[300:312]), (2, np.r_[400:430])):
        err = angles_deg(j.quat[rows, seg], rots[j.segments[seg]][rows])
        assert err.mean() <= gaps[(seg, rows[0])]["error_deg"] + 1.0 and err.max() < 3.0
    strict = compute_frames(m2, markerset(), neutral, FramesParams(max_fill_error_deg=1e-3))
    assert not strict.rot_filled.any() and not strict.valid[300:312].any()
    # the joints table says which rotations were filled
    from gazepipe.schemas.joints import joints_arrays, joints_to_table

    back = joints_arrays(joints_to_table(j, np.arange(mk.n_frames)))
    np.testing.assert_array_equal(back["rot_filled"], j.rot_filled)


def test_the_rest_before_the_take_gives_a_gap_at_its_start_its_other_side(take):
    """A spine marker is hidden from 10 frames before the take's first frame to 10 after: with the rest before
    the take given, the spine's rotation is filled over the take's first 10 frames, close to the truth; without
    it, those frames have nothing on one side and stay missing. Only the take's own frames come out."""
    mk, neutral, rots, _ = take
    xyz = mk.xyz.copy()
    xyz[90:110, mk.index("SPN2")] = np.nan
    def part(a, b):
        return Markers(labels=mk.labels, xyz=xyz[a:b], valid=np.isfinite(xyz[a:b]).all(2), rate_hz=RATE,
                       first_frame=a)
    rest, own = part(0, 100), part(100, 600)
    alone = compute_frames(own, markerset(), neutral)
    assert not alone.valid[:10].any() and not alone.rot_filled.any()
    j = compute_frames(own, markerset(), neutral, before=rest)
    assert j.quat.shape[0] == 500 and j.first_frame == 100
    assert j.rot_filled[:10, 1].all() and j.valid.all() and j.rot_filled.sum() == 10
    assert angles_deg(j.quat[:10, 1], rots["spine"][100:110]).max() < 3.0
    np.testing.assert_array_equal(j.quat[20:], alone.quat[20:])
    assert [(g["start"], g["stop"]) for g in j.qc["rotation_gaps"]] == [(-10, 10)]


def test_the_rest_pose_before_the_take_is_the_mean_of_measured_rotations_only():
    """rest_pose averages a segment's measured rotations in the last frames of the rest; rotations filled (across
    a gap of its markers, or from gap-filled markers) never enter (a fill 20° off changes nothing); it falls back
    to the measured frames of the whole rest, and a segment with no measured frame in the rest has no pose
    (None), not the fill's."""
    from gazepipe.stages.frames.stage import rest_pose
    from gazepipe.stages.geometry import to_wxyz

    truth = Rotation.from_rotvec([0.0, 0.3, 0.0])
    still = to_wxyz(truth)
    off = to_wxyz(Rotation.from_rotvec([0.0, 0.3 + np.radians(20.0), 0.0]))
    n = 40
    quat = np.tile(still, (n, 3, 1))
    filled = np.zeros((n, 3), bool)
    quat[-5:, 0], filled[-5:, 0] = off, True       # segment 0: the last 5 frames filled, 20° off
    quat[:, 1], filled[:, 1] = off, True           # segment 1: filled over the whole rest
    quat[-10:, 2], filled[-10:, 2] = off, True     # segment 2: the last n_last frames all filled
    char = np.tile(still, (n, 1))
    got = rest_pose(quat, char, 10, ~filled)
    assert got["quat"][1] is None
    for j in (0, 2):
        assert angles_deg(np.array(got["quat"][j]), truth) < 1e-6, j
    ignored = rest_pose(quat, char, 10)             # without the flags the fills count: 20° in segment 1
    assert angles_deg(np.array(ignored["quat"][1]), truth) > 19.0


def test_rotations_from_gap_filled_markers_are_not_measured(take):
    """``rot_measured`` marks the rotations whose segment markers were all measured: a spine marker gap-filled
    (valid, but not measured) makes the spine's rotation unmeasured there and nothing else. In the rest before
    the take the still pose averages the measured frames only: a fill 40 mm off in its last frames leaves it as
    it is, and a spine never measured there has no pose."""
    mk, neutral, _, _ = take
    measured = np.ones(mk.valid.shape, bool)
    measured[200:230, mk.index("SPN3")] = False
    j = compute_frames(mk, markerset(), neutral, measured=measured)
    spine = j.segments.index("spine")
    assert not j.rot_filled.any() and j.valid.all()
    assert not j.rot_measured[200:230, spine].any() and j.rot_measured.sum() == j.rot_measured.size - 30
    same = compute_frames(mk, markerset(), neutral)
    np.testing.assert_array_equal(j.quat, same.quat)
    assert same.rot_measured.all()
    # a still rest before the take (the pose of its first frame): SPN3 filled 40 mm off over its last 40 frames
    nr = 100
    still = {name: Rotation.from_quat(np.tile(r[0].as_quat(), (nr, 1))) for name, r in take[2].items()}
    rest, _ = build(nr, still, np.full(nr, 0.5), np.tile([1000.0, -500, 955], (nr, 1)), noise=0.5, seed=5)
    xyz = rest.xyz.copy()
    xyz[60:, mk.index("SPN3")] += [0.0, 0.0, 40.0]
    filled = Markers(labels=mk.labels, xyz=xyz, valid=rest.valid, rate_hz=RATE)
    rest_meas = np.ones(rest.valid.shape, bool)
    rest_meas[60:, mk.index("SPN3")] = False
    # the offset fill jumps away and back at the take's first frame: the continuity check alone would make it a
    # gap (test_a_flip_of_a_segment_becomes_a_gap_not_a_row); here the measured flags are what is tested
    smooth = FramesParams(jump_factor=0.0)
    honest = compute_frames(mk, markerset(), neutral, smooth, before=filled, before_measured=rest_meas)
    fooled = compute_frames(mk, markerset(), neutral, smooth, before=filled)
    k = j.segments.index("spine")
    truth = still["spine"][0]
    assert angles_deg(np.array(fooled.rest_before["quat"][k]), truth) > 2.0
    assert angles_deg(np.array(honest.rest_before["quat"][k]), truth) < 0.3
    np.testing.assert_array_equal(honest.quat, fooled.quat)     # the rotations themselves are the same
    never = np.ones(rest.valid.shape, bool)
    never[:, mk.index("SPN3")] = False
    assert compute_frames(mk, markerset(), neutral, smooth, before=filled,
                          before_measured=never).rest_before["quat"][k] is None


def test_a_missing_head_centre_marker_is_carried_by_the_heads_fit(take):
    """Where the head-centre marker is unfilled but the head is solved, the head centre (and so the target
    direction) comes from the head's rigid fit, within the accuracy of the measured marker."""
    mk, neutral, _, truth = take
    xyz = mk.xyz.copy()
    xyz[100:250, mk.index("HEADC")] = np.nan
    m2 = Markers(labels=mk.labels, xyz=xyz, valid=np.isfinite(xyz).all(2), rate_hz=RATE)
    j = compute_frames(m2, markerset(), neutral)
    assert j.qc["head_centre_carried_frames"] == 150
    gap = slice(100, 250)
    assert np.isfinite(j.head_centre[gap]).all() and np.isfinite(j.target_dir[gap]).all()
    assert np.linalg.norm(j.head_centre[gap] - truth["headc"][gap], axis=1).max() < 3.0
    err = np.degrees(np.arccos(np.clip(np.sum(j.target_dir[gap] * truth["target_dir"][gap], 1), -1, 1)))
    assert err.max() < 1.0


def test_fit_uncertainty_matches_the_spread_of_rigid_fits():
    """The first-order propagation of marker errors through the rigid fit gives the RMS turn of fits to noisy
    clusters (three chest markers of the four-segment layout, filled 2.3–4.5 mm off: 4°)."""
    from gazepipe.stages.frames.stage import fit_uncertainty_deg

    ref = np.array([(55.0, 0.0, -135.0), (-55.0, 0.0, -135.0), (20.0, -45.0, -132.0)])
    err = np.array([2.3, 3.3, 4.5])
    rng = np.random.default_rng(0)
    pts = ref[None] + rng.standard_normal((4000, 3, 3)) * (err / np.sqrt(3.0))[None, :, None]
    spread = np.sqrt(np.mean(np.degrees(Rotation.from_matrix(kabsch(ref, pts)).magnitude()) ** 2))
    got = fit_uncertainty_deg(ref, err[None])[0]
    assert got == pytest.approx(spread, rel=0.05)
    assert fit_uncertainty_deg(ref, np.zeros((2, 3))).tolist() == [0.0, 0.0]


def test_a_segment_on_uncertain_fills_is_unsure(take):
    """A segment whose markers are gap-filled with estimated errors that may turn it by more than
    max_fit_uncertainty_deg has no rotation from its markers there (nor is the take's validity kept on it); small
    fill errors change nothing, and without the estimates nothing is judged."""
    mk, neutral, rots, truth = take
    ms = markerset()
    sp = [mk.index(n) for n in NAMES["spine"]]
    measured = np.ones(mk.valid.shape, bool)
    measured[300:340, sp] = False                           # the spine's three markers filled for 40 frames
    small = np.full(mk.valid.shape, np.nan)
    small[300:340, sp] = 0.5
    large = small.copy()
    large[300:340, sp] = 6.0
    params = FramesParams(max_fit_uncertainty_deg=3.0)
    base = compute_frames(mk, ms, neutral, params, measured=measured)
    same = compute_frames(mk, ms, neutral, params, measured=measured, fill_error_mm=small)
    np.testing.assert_array_equal(base.quat, same.quat)
    assert same.qc["fill_uncertain_frames"]["spine"] == 0
    off_judging = compute_frames(mk, ms, neutral, FramesParams(max_fit_uncertainty_deg=0.0), measured=measured,
                                 fill_error_mm=large)
    assert not off_judging.qc["fill_uncertain_frames"]          # max_fit_uncertainty_deg = 0: not judged
    j = compute_frames(mk, ms, neutral, params, measured=measured, fill_error_mm=large)
    assert j.qc["fill_uncertain_frames"]["spine"] == 40
    unsure = ~np.isfinite(j.quat[300:340, 1]).all(axis=1) | j.rot_filled[300:340, 1]
    assert unsure.all()                                     # unknown, or filled across by a checked estimate
    assert not j.rot_measured[300:340, 1].any()
    off = np.r_[0:300, 340:mk.n_frames]
    np.testing.assert_array_equal(j.quat[off, 0], compute_frames(mk, ms, neutral, params).quat[off, 0])


# ------------------------------------------------------------------------------------------------ continuity


def _rows_of(j, lod: bool = True):
    """gaze_rnn_lod-style rows (no eyes) of a Joints, through the joints table as the build reads it."""
    from gazepipe.schemas.joints import joints_arrays, joints_to_table
    from gazepipe.stages.build.gaze import rnn_rows

    arrays = joints_arrays(joints_to_table(j, np.arange(j.n_frames)))
    return rnn_rows(arrays, list(range(len(j.segments))), None)


def test_a_flip_of_a_segment_becomes_a_gap_not_a_row(take):
    """One frame's spine markers turned 150° about the spine's centre (a fit gone wrong for a frame: a marker
    swapped, a ghost kept), and a 50 mm ghost on one of the five head markers for two frames: without the
    continuity check they give rows 150° and ~8° off; with it those rotations are gaps of the segment's markers (QC
    ``flip_frames``), filled across by the rotation fill within its estimate, and no row is more than a few
    degrees off. A clean take has no flip."""
    mk, neutral, rots, _ = take
    xyz = mk.xyz.copy()
    sp = [mk.index(n) for n in NAMES["spine"]]
    c = xyz[250, sp].mean(axis=0)
    turn = Rotation.from_rotvec([0.0, 0.0, np.radians(150.0)])
    xyz[250, sp] = c + turn.apply(xyz[250, sp] - c)
    xyz[400:402, mk.index("HFL")] += [0.0, 50.0, 0.0]
    bad = Markers(labels=mk.labels, xyz=xyz, valid=mk.valid, rate_hz=RATE)
    off = compute_frames(bad, markerset(), neutral, FramesParams(jump_factor=0.0))
    assert angles_deg(off.quat[250, 1], rots["spine"][250]) > 100.0
    assert angles_deg(off.quat[400:402, 2], rots["head"][400:402]).min() > 7.0
    j = compute_frames(bad, markerset(), neutral)
    assert j.qc["flip_frames"] == {"pelvis": 0, "spine": 1, "head": 2} and j.qc["heading_flip_frames"] == 0
    assert j.rot_filled[250, 1] and j.rot_filled[400:402, 2].all() and j.rot_filled.sum() == 3
    assert not j.rot_measured[250, 1] and not j.rot_measured[400:402, 2].any()
    rows = _rows_of(j)
    six = rows.features["y"].reshape(rows.n_rows, 3, 6).astype(np.float64)
    from gazepipe.stages.geometry import rotation_from_six
    for s, name in enumerate(("pelvis", "spine", "head")):
        got = rotation_from_six(six[:, s])
        err = np.degrees((got * rots[name][rows.frame].inv()).magnitude())
        assert err.max() < 4.0, name
    clean = compute_frames(mk, markerset(), neutral)
    assert sum(clean.qc["flip_frames"].values()) == 0 and clean.qc["heading_flip_frames"] == 0


def test_a_flip_of_the_heading_leaves_the_frame_without_a_character_frame(take):
    """The root segment's first two markers exchange names for one frame: the character frame's heading flips by
    180° there (and the pelvis with it). That frame has no character frame (QC ``heading_flip_frames``), so it
    gives no row and ends a run of rows; the frames beside it keep theirs."""
    mk, neutral, _, truth = take
    xyz = mk.xyz.copy()
    a, b = mk.index("PEL1"), mk.index("PEL2")
    xyz[300, [a, b]] = xyz[300, [b, a]]
    bad = Markers(labels=mk.labels, xyz=xyz, valid=mk.valid, rate_hz=RATE)
    off = compute_frames(bad, markerset(), neutral, FramesParams(jump_factor=0.0))
    turned = Rotation.from_matrix(truth["cmat"][300]).inv() * from_wxyz(off.char_rot[300])
    assert np.degrees(turned.magnitude()) > 170.0
    j = compute_frames(bad, markerset(), neutral)
    assert j.qc["heading_flip_frames"] == 1
    assert not j.valid[300] and np.isnan(j.char_rot[300]).all() and j.valid[299] and j.valid[301]
    rows = _rows_of(j)
    assert 300 not in rows.frame and 301 not in rows.frame and {299, 302} <= set(rows.frame.tolist())
    assert rows.qc["dropped"]["no_character_frame"] == 1


def _noisy_turn(n: int, seed: int, noise_deg: float = 0.3) -> np.ndarray:
    """(n, 3, 3) rotations of a segment turning slowly (10°/s at 120 Hz about a tilted axis) with isotropic
    noise of ``noise_deg`` RMS per axis."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 120.0
    slow = Rotation.from_rotvec(np.radians(10.0) * t[:, None] * np.array([0.3, 0.2, 0.93]))
    noise = Rotation.from_rotvec(np.radians(noise_deg) * rng.standard_normal((n, 3)))
    return (slow * noise).as_matrix()


def test_a_long_flip_is_a_gap_and_two_unrelated_noise_steps_are_not():
    """:func:`~gazepipe.stages.frames.continuity.flips` at 120 Hz (the stage's rule there: 0.1 s short flips,
    2 s at most). A 0.5 s run of a segment turned 25° off (a fit gone wrong the same way throughout) is a flip;
    two steps past the threshold 1.5 s apart whose offsets do not match (3.8° each about axes 40° apart: 2.6°
    between them, within the jump threshold, but most of the offset) leave the rotations between them alone
    (they were a flip before :data:`~gazepipe.stages.frames.continuity._SAME`); nothing is found on the clean
    rotations."""
    from gazepipe.stages.frames.continuity import flips
    from gazepipe.stages.frames.stage import _jump_rule

    rule = _jump_rule(FramesParams(), 120.0)
    assert rule is not None and rule.short_frames == 12 and rule.max_frames == 240
    clean = _noisy_turn(900, 3)
    assert not flips(clean, rule).any()
    bad = clean.copy()
    off = Rotation.from_rotvec(np.radians(25.0) * np.array([1.0, 0.0, 0.0]))
    bad[300:360] = (Rotation.from_matrix(bad[300:360]) * off).as_matrix()
    found = flips(bad, rule)
    assert found[300:360].all() and found.sum() == 60
    two = _noisy_turn(900, 0)
    assert not flips(two, rule).any()
    axis = np.array([np.cos(np.radians(40.0)), np.sin(np.radians(40.0)), 0.0])
    two[400:] = (Rotation.from_matrix(two[400:]) * Rotation.from_rotvec(np.radians([3.8, 0.0, 0.0]))).as_matrix()
    two[580:] = (Rotation.from_matrix(two[580:]) * Rotation.from_rotvec(np.radians(3.8) * axis).inv()).as_matrix()
    assert not flips(two, rule).any()


def test_a_fit_to_fills_the_fill_across_it_contradicts_becomes_a_gap(take):
    """A spine marker gap-filled up to 14 mm off over 40 frames (meeting the marker at both ends) while its fill
    claims 3.5 mm: the fit to it is turned up to ~7° while its own estimate says ~1.3°, and it has no jump for
    the continuity check. The fill across those frames, from the rotations around them, says otherwise (QC
    ``fit_refuted_frames``): they become a gap of the spine's markers, filled across within a couple of
    degrees. Where the marker is where it should be (the fill honest) the fit is kept, weighed with the fill."""
    mk, neutral, rots, _ = take
    sp3 = mk.index("SPN3")
    xyz = mk.xyz.copy()
    drift = 14.0 * np.sin(np.pi * (np.arange(300, 340) - 299) / 41.0)     # a fill meets its ends, off between
    xyz[300:340, sp3] += drift[:, None] * [0.0, 1.0, 0.0]
    measured = np.ones(mk.valid.shape, bool)
    measured[300:340, sp3] = False
    claims = np.full(mk.valid.shape, np.nan)
    claims[300:340, sp3] = 3.5
    bad = Markers(labels=mk.labels, xyz=xyz, valid=mk.valid, rate_hz=RATE)
    raw = compute_frames(bad, markerset(), neutral, FramesParams(max_fill_error_deg=0.0), measured=measured,
                         fill_error_mm=claims)
    assert angles_deg(raw.quat[300:340, 1], rots["spine"][300:340]).max() > 5.0
    assert raw.qc["flip_frames"]["spine"] == 0                 # no jump: the continuity check sees nothing
    j = compute_frames(bad, markerset(), neutral, measured=measured, fill_error_mm=claims)
    assert j.qc["fit_refuted_frames"]["spine"] == 40 and j.rot_filled[300:340, 1].all()
    assert angles_deg(j.quat[300:340, 1], rots["spine"][300:340]).max() < 2.5
    honest = compute_frames(mk, markerset(), neutral, measured=measured, fill_error_mm=claims)
    assert honest.qc["fit_refuted_frames"]["spine"] == 0 and not honest.rot_filled[300:340, 1].any()
    assert angles_deg(honest.quat[300:340, 1], rots["spine"][300:340]).max() < 3.0
