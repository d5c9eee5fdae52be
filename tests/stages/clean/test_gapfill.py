"""Gap filling, spike removal and rigid-cluster finding (SPEC §3.2 steps 1–2)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gazepipe.model import FILL_CODES
from gazepipe.stages.clean.gapfill import fill_gaps, find_gaps, find_rigid_clusters
from gazepipe.stages.clean.spikes import remove_spikes
from gazepipe.stages.geometry import frame_from_points
from tests.helpers import TESTS
from tests.helpers.captures import NOISE, RATE, body, hide

CORPUS = TESTS / "data" / "corpus" / "c3d"


def gap_error(res, truth: np.ndarray, m: int, s: int, e: int) -> float:
    return float(np.linalg.norm(res.xyz[s:e, m] - truth[s:e, m], axis=1).mean())


# ------------------------------------------------------------------------------------------- methods
@pytest.mark.parametrize(("method", "length", "tol_mm"), [
    # rigid: 3 donors with 0.5 mm noise give about noise-level error whatever the gap length
    ("rigid", 40, 2.0),
    # PCA of the intercorrelated body: a linear model of rotations of up to ±0.6 rad, corrected at both edges
    ("pca", 20, 5.0),
    # interpolation of smooth motion over a short gap: error dominated by the noise of the anchor samples
    ("pchip", 4, 2.0),
    ("linear", 2, 2.0),
])
def test_each_method_recovers_hidden_samples(method, length, tol_mm):
    truth, measured, clusters = body()
    gaps = [(5, 200, 200 + length), (9, 400, 400 + length)]
    x, valid = hide(measured, gaps)
    res = fill_gaps(x, valid, RATE, clusters=clusters, methods=(method,))
    for m, s, e in gaps:
        assert (res.fill_code[s:e, m] == FILL_CODES[method]).all()
        assert gap_error(res, truth, m, s, e) < tol_mm


def test_choice_follows_the_segment_for_long_gap_and_beats_interpolation():
    truth, measured, clusters = body()
    m, s, e = 5, 250, 300  # 0.83 s of a swinging segment: interpolation cannot know the swing
    x, valid = hide(measured, [(m, s, e)])
    res = fill_gaps(x, valid, RATE, clusters=clusters)
    rec = next(g for g in res.gaps if g.marker == m)
    # the segment's mates carry the marker: rigid fill, and PCA in the moving frame of its nearest markers (the
    # same mates), validate alike and fill it; interpolation gets no weight
    assert set(rec.weights) <= {"rigid", "pca"} and abs(rec.errors["rigid"] - rec.errors["pca"]) < 0.2
    assert rec.errors["rigid"] < rec.errors["pchip"] / 10
    pchip = fill_gaps(x, valid, RATE, clusters=clusters, methods=("pchip",))
    assert gap_error(res, truth, m, s, e) < 2.0 < gap_error(pchip, truth, m, s, e)


def test_choice_without_clusters_uses_other_methods():
    truth, measured, _ = body()
    x, valid = hide(measured, [(2, 100, 103), (7, 300, 330)])
    res = fill_gaps(x, valid, RATE, steady_mates=False)
    assert {g.method for g in res.gaps} <= {"pca", "pchip", "linear"}
    # a 3-frame gap in smooth motion: whatever is chosen is close to the truth
    assert gap_error(res, truth, 2, 100, 103) < 2.0


def test_without_clusters_rigid_fill_finds_the_steady_mates():
    from gazepipe.stages.clean.fill_methods import find_steady_mates  # noqa: PLC0415

    truth, measured, clusters = body()
    m, s, e = 7, 280, 330  # a swinging segment: its own mates are the only markers at a steady distance
    x, valid = hide(measured, [(m, s, e)])
    assert sorted(find_steady_mates(x, valid, m, s, e, 120)) == clusters[1]
    res = fill_gaps(x, valid, RATE)
    rec = res.gaps[0]
    assert "rigid" in rec.weights and np.isfinite(rec.errors["rigid"])
    assert gap_error(res, truth, m, s, e) < 2.0
    # with its segment hidden with it, the mates are markers measured through the gap, none of the hidden ones
    x2, valid2 = hide(measured, [(j, s, e) for j in clusters[1]])
    mates = find_steady_mates(x2, valid2, m, s, e, 120)
    assert mates is None or (mates[0] == m and not set(mates[1:]) & set(clusters[1]) and valid2[s:e, mates[1:]].all())


def test_long_gaps_stay_unfilled():
    truth, measured, clusters = body()
    n = int(RATE * 1.0) + 1  # one sample more than max_gap_s allows
    x, valid = hide(measured, [(1, 100, 100 + n), (5, 300, 300 + n - 1)])
    res = fill_gaps(x, valid, RATE, clusters=clusters, max_gap_s=1.0)
    assert (res.fill_code[100:100 + n, 1] == FILL_CODES["unfilled"]).all()
    assert np.isnan(res.xyz[100:100 + n, 1]).all()
    assert (res.fill_code[300:300 + n - 1, 5] != FILL_CODES["unfilled"]).all()  # exactly max_gap_s: filled
    assert res.qc[1].unfilled == n and res.qc[1].longest_gap_frames == n
    assert res.qc[1].longest_gap_s == pytest.approx(n / RATE)


def test_validation_stretches_hide_enough_samples_next_to_short_gaps():
    from gazepipe.stages.clean.gapfill import _validation_windows  # noqa: PLC0415

    valid = np.ones(400, bool)
    for length, per_side in ((1, 16), (3, 6), (5, 4), (8, 2), (40, 2)):
        s = 200
        valid_m = valid.copy()
        valid_m[s:s + length] = False
        wins = _validation_windows(valid_m, s, s + length)
        before = [w for w in wins if w[1] <= s]
        after = [w for w in wins if w[0] >= s + length]
        assert len(before) == len(after) == per_side, length
        # each as long as the gap, two measured frames apart, nearest first, none touching the gap
        for side in (before, after):
            assert all(b - a == length for a, b in side)
            gaps = [min(abs(a1 - b0), abs(a0 - b1)) for (a0, b0), (a1, b1) in zip(side[:-1], side[1:], strict=True)]
            assert gaps == [2] * (per_side - 1), (length, side)
        assert before[0][1] == s - 2 and after[0][0] == s + length + 2
    # no room: the stretches stop at the neighbouring gap and keep one measured frame before it
    valid_m = valid.copy()
    valid_m[190] = valid_m[200] = False
    before = [w for w in _validation_windows(valid_m, 200, 201) if w[1] <= 200]
    assert before == [(197, 198), (194, 195)]  # (191, 192) would leave no measured frame after 190


def test_edge_gaps_never_interpolated_in_time():
    truth, measured, clusters = body()
    x, valid = hide(measured, [(1, 0, 10), (5, 590, 600)])
    only_interp = fill_gaps(x, valid, RATE, clusters=clusters, methods=("pchip", "linear"))
    assert (only_interp.fill_code[:10, 1] == FILL_CODES["unfilled"]).all()
    assert (only_interp.fill_code[590:, 5] == FILL_CODES["unfilled"]).all()
    res = fill_gaps(x, valid, RATE, clusters=clusters)
    for m, sl in ((1, slice(0, 10)), (5, slice(590, 600))):
        codes = set(res.fill_code[sl, m].tolist())
        assert codes <= {FILL_CODES["rigid"], FILL_CODES["pca"]}
        assert np.linalg.norm(res.xyz[sl, m] - truth[sl, m], axis=1).mean() < 3.0


def test_measured_samples_bit_exact_and_codes_consistent():
    truth, measured, clusters = body()
    rng = np.random.default_rng(3)
    gaps = []
    for m in range(12):
        s = int(rng.integers(5, 500))
        gaps.append((m, s, s + int(rng.integers(1, 40))))
    x, valid = hide(measured, gaps)
    res = fill_gaps(x, valid, RATE, clusters=clusters)
    assert np.array_equal(res.xyz[valid], x[valid])  # bit for bit
    assert (res.fill_code[valid] == FILL_CODES["measured"]).all()
    assert (res.fill_code[~valid] != FILL_CODES["measured"]).all()
    for g in res.gaps:
        assert (res.fill_code[g.start:g.stop, g.marker] == FILL_CODES[g.method]).all()
    for m, q in enumerate(res.qc):
        assert q.n_gaps == len(find_gaps(valid[:, m]))
        assert sum(q.filled.values()) + q.unfilled == int((~valid[:, m]).sum())
    again = fill_gaps(x, valid, RATE, clusters=clusters)
    assert again.xyz.tobytes() == res.xyz.tobytes() and again.fill_code.tobytes() == res.fill_code.tobytes()
    assert np.isfinite(res.xyz).all()


def test_input_not_modified():
    _, measured, clusters = body(n_t=200)
    x, valid = hide(measured, [(0, 50, 60)])
    x0, v0 = x.copy(), valid.copy()
    fill_gaps(x, valid, RATE, clusters=clusters)
    assert np.array_equal(x, x0, equal_nan=True) and np.array_equal(valid, v0)


# ------------------------------------------------------------------------------------------- spikes
def test_spikes_and_flips_removed_clean_motion_kept():
    truth, measured, _ = body(n_t=300)
    valid = np.ones(measured.shape[:2], bool)
    v_clean, n_clean = remove_spikes(measured, valid, RATE)
    assert n_clean.sum() == 0 and v_clean.all()
    bad = measured.copy()
    bad[150, 3, 0] += 1200.0  # one-sample spike
    bad[-10:, 7, 2] *= -1.0  # sign flip of z in the last 10 frames (z about +1 m)
    v_new, n = remove_spikes(bad, valid, RATE)
    assert not v_new[150, 3] and v_new[149, 3] and v_new[151, 3]
    assert not v_new[-10:, 7].any() and v_new[:-10, 7].all()
    assert n[3] == 1 and n[7] == 10 and n.sum() == 11


def test_spikes_real_files():
    import ezc3d  # noqa: PLC0415

    for name, expect in (("ART-Human_2persons_integer", {"Human1:HEADZ": 10}), ("Walking_Hybrid_2", None)):
        path = CORPUS / f"{name}.c3d"
        c = ezc3d.c3d(str(path))
        xyz = c["data"]["points"][:3].transpose(2, 1, 0).astype(np.float64)
        labels = c["parameters"]["POINT"]["LABELS"]["value"]
        valid = ~np.all(xyz == 0, axis=2)
        v_new, n = remove_spikes(xyz, valid, float(c["parameters"]["POINT"]["RATE"]["value"][0]))
        removed = {labels[m]: int(n[m]) for m in np.flatnonzero(n)}
        if expect is not None:
            assert removed == expect
            assert not v_new[-10:, labels.index("Human1:HEADZ")].any()
        else:
            # Walking_Hybrid_2: only the three copies of L_THIGH_3, which jumps 163 mm between two frames
            # (distance to its segment mates 110 -> 255 mm) and stays there until its trajectory ends
            assert set(removed) == {"L_THIGH_3"}


# ------------------------------------------------------------------------------------------- clusters
def test_rigid_clusters_found():
    _, measured, clusters = body()
    valid = np.ones(measured.shape[:2], bool)
    valid[100:150, 2] = False
    assert find_rigid_clusters(measured, valid) == clusters


# ------------------------------------------------------------------------------------------- real data
def test_accuracy_on_real_walking_slice():
    """Walking_Hybrid_2 (240 Hz, QTM): gaps hidden in its gap-free stretch; de-duplicated trajectories."""
    import ezc3d  # noqa: PLC0415

    path = CORPUS / "Walking_Hybrid_2.c3d"
    c = ezc3d.c3d(str(path))
    xyz = c["data"]["points"][:3].transpose(2, 1, 0).astype(np.float64)[30:430]
    keep = []
    for m in range(xyz.shape[1]):
        if np.all(xyz[:, m] != 0) and not any(np.array_equal(xyz[:, m], xyz[:, k]) for k in keep):
            keep.append(m)
    truth = xyz[:, keep]
    clusters = find_rigid_clusters(truth, np.ones(truth.shape[:2], bool), max_rel_std=0.03)
    gaps = [(0, 50, 74), (3, 120, 150), (7, 200, 212), (11, 260, 300), (15, 300, 305), (19, 90, 150)]
    gaps = [(m, s, e) for m, s, e in gaps if m < truth.shape[1]]
    x, valid = hide(truth, gaps)
    res = fill_gaps(x, valid, 240.0, clusters=clusters)
    err = np.linalg.norm(res.xyz - truth, axis=2)[~valid].mean()
    single = {}
    for meth in ("pca", "pchip", "linear"):
        r = fill_gaps(x, valid, 240.0, clusters=clusters, methods=(meth,))
        single[meth] = np.linalg.norm(r.xyz - truth, axis=2)[~valid].mean()
    # skin markers at 240 Hz with gaps of 0.02-0.25 s: the bench measures 1-8 mm for such gaps
    assert err < 8.0
    # the per-gap choice is close to the best single method and far better than the seed's linear fill
    assert err < 1.25 * min(single.values())
    assert err < 0.5 * single["linear"]


# ------------------------------------------------------------------------------------------- blending
def test_blend_weights_inverse_square_and_cutoffs():
    from gazepipe.stages.clean.gapfill import METHODS, blend_weights  # noqa: PLC0415

    w = blend_weights({"rigid": 1.0, "pca": 2.0, "pchip": 2.5, "linear": 10.0}, METHODS)
    # linear is more than 3x worse than the best and is left out; the rest by 1/err²
    inv = np.array([1.0, 1 / 4.0, 1 / 6.25])
    assert list(w) == ["rigid", "pca", "pchip"]
    assert np.allclose(list(w.values()), inv / inv.sum()) and sum(w.values()) == pytest.approx(1.0)
    assert blend_weights({"rigid": np.nan, "pca": np.nan}, METHODS) == {"rigid": 1.0}  # nothing validated
    assert blend_weights({"pchip": np.nan, "linear": 0.5}, METHODS) == {"linear": 1.0}
    assert blend_weights({}, METHODS) == {}


def test_blend_kept_only_when_it_validates_no_worse_than_its_best_member():
    from gazepipe.stages.clean.gapfill import check_blend  # noqa: PLC0415

    truth = np.zeros((4, 3))
    # two methods erring alike (+1 and +1.2 mm in x): their blend is worse than the better one alone
    alike = {"linear": np.tile([1.0, 0, 0], (4, 1)), "pchip": np.tile([1.2, 0, 0], (4, 1))}
    assert check_blend({"linear": 0.6, "pchip": 0.4}, truth, alike) == {"linear": 1.0}
    # opposite errors cancel: the blend stays
    opposite = {"linear": np.tile([1.0, 0, 0], (4, 1)), "rigid": np.tile([-1.2, 0, 0], (4, 1))}
    assert check_blend({"linear": 0.6, "rigid": 0.4}, truth, opposite) == {"linear": 0.6, "rigid": 0.4}
    # frames a member could not predict do not count
    opposite["rigid"][0] = np.nan
    assert check_blend({"linear": 0.6, "rigid": 0.4}, truth, opposite) == {"linear": 0.6, "rigid": 0.4}


def test_blended_gap_is_the_weighted_sum_of_the_methods():
    truth, measured, clusters = body()
    gaps = [(5, 250, 280), (2, 100, 110), (9, 400, 406)]
    x, valid = hide(measured, gaps)
    res = fill_gaps(x, valid, RATE, clusters=clusters, framewise=False)   # the per-gap blend (test_framewise)
    single = {m: fill_gaps(x, valid, RATE, clusters=clusters, methods=(m,)) for m in ("rigid", "pca", "pchip",
                                                                                     "linear")}
    n_blended = 0
    for g in res.gaps:
        assert sum(g.weights.values()) == pytest.approx(1.0)
        assert g.method == max(g.weights, key=g.weights.get)
        assert (res.fill_code[g.start:g.stop, g.marker] == FILL_CODES[g.method]).all()
        expect = sum(w * single[k].xyz[g.start:g.stop, g.marker] for k, w in g.weights.items())
        assert np.allclose(res.xyz[g.start:g.stop, g.marker], expect, atol=1e-9)
        n_blended += len(g.weights) > 1
    assert n_blended >= 1
    # a blend is no worse than the best single method over these gaps (each has a near-noise-level method)
    err = np.mean([gap_error(res, truth, *gap) for gap in gaps])
    best_single = min(np.mean([gap_error(r, truth, *gap) for gap in gaps]) for r in single.values())
    assert err <= 1.1 * best_single


def test_movement_during_gap_between_still_phases_not_interpolated():
    """Still, then a quick movement, then still: the hidden stretches beside the gap show no motion, so
    interpolation validates perfectly there; the markers measured through the gap show the movement."""
    truth0, _, clusters = body(noise=0.0)
    # frame i of the take shows body frame idx[i]: still at 100, 300 frames of motion in 30, still at 400
    idx = np.concatenate([np.full(280, 100), np.linspace(100, 400, 30).round().astype(int), np.full(290, 400)])
    truth = truth0[idx]
    rng = np.random.default_rng(5)
    measured = truth + rng.normal(0, NOISE, truth.shape)
    m, s, e = 5, 275, 315
    x, valid = hide(measured, [(m, s, e)])
    res = fill_gaps(x, valid, RATE, clusters=clusters)
    rec = res.gaps[[g.marker for g in res.gaps].index(m)]
    linear = fill_gaps(x, valid, RATE, clusters=clusters, methods=("linear",))
    assert gap_error(linear, truth, m, s, e) > 20.0  # the movement is not a straight line at constant speed
    assert rec.errors["linear"] > 10.0 and rec.errors["pchip"] > 10.0  # seen on the donors, not beside the gap
    assert set(rec.weights) <= {"rigid", "pca"}
    assert gap_error(res, truth, m, s, e) < 3.0




def test_interpolation_donors_must_move_with_the_marker():
    """A foot stands still through its gap while the other foot, 300 mm away, swings: the swinging foot is not
    a donor for the standing one's interpolation check (its error would say the gap is full of motion); a marker
    on the standing foot is."""
    from gazepipe.stages.clean.fill_methods import donor_interp_errors

    f = np.arange(300.0)
    t = f / RATE
    stand = np.zeros((300, 3))
    # moving up to frame 135, still from 135 to 165 (through the gap [140, 160)), moving again after
    stand[:, 0] = 0.005 * (np.minimum(f - 135, 0) ** 3 + np.maximum(f - 165, 0) ** 3)
    swing = np.stack([300 + 250 * np.sin(2 * np.pi * 1.7 * t), 100 * np.cos(2 * np.pi * 1.7 * t),
                      np.zeros(300)], axis=1)
    xyz = np.stack([stand, stand + [0.0, 60.0, 0.0], swing], axis=1)
    valid = np.ones((300, 3), bool)
    valid[140:160, 0] = False
    m, s, e = 0, 140, 160
    with_mate = donor_interp_errors(xyz, valid, m, s, e, ["linear"], window=120)
    assert with_mate["linear"] < 1.0  # the mate on the same foot stands still too
    valid[:, 1] = False  # only the swinging foot is left
    assert donor_interp_errors(xyz, valid, m, s, e, ["linear"])["linear"] > 20.0  # it would mislead
    assert np.isnan(donor_interp_errors(xyz, valid, m, s, e, ["linear"], window=120)["linear"])


def test_pca_predictors_are_measured_at_the_gap_edges_too():
    """The PCA fill is corrected to meet the marker at the frames just before and after the gap, so those frames
    must be predicted from the same markers as the gap: a marker missing at an edge frame is no predictor (on
    the ART file, one body missing in the frame before a 2-frame gap put 13 mm into it)."""
    from gazepipe.stages.clean.fill_methods import fit_pca_models

    _, measured, _ = body()
    m, s, e = 5, 300, 302
    x, valid = hide(measured, [(m, s, e), (9, s - 1, s), (2, e, e + 1), (7, s, e)])
    models = fit_pca_models(x, valid, m, valid[:, m], s, e, (None,))
    preds = set(models[0].predictors.tolist())
    assert preds == set(range(12)) - {m, 9, 2, 7}


def test_marker_standing_through_its_gap_is_interpolated(monkeypatch):
    """A foot stands still through its gap while the stretches beside the gap hold its steps, and the other
    markers (another body) swing: the stretches make interpolation look poor, but the foot's speed at the gap's
    edges shows it stood, and interpolation fills the gap."""
    from gazepipe.stages.clean import gapfill

    f = np.arange(400.0)
    t = f / RATE
    foot = np.zeros((400, 3))
    # stepping before frame 185 and after 215, standing in between (gap [190, 210))
    foot[:, 0] = 0.005 * (np.minimum(f - 185, 0) ** 3 + np.maximum(f - 215, 0) ** 3)
    foot[:, 2] = 30 * np.sin(2 * np.pi * 0.9 * t) * ((f < 185) | (f > 215))
    rot = Rotation.from_euler("z", 0.8 * np.sin(2 * np.pi * 0.6 * t)[:, None])
    other = np.stack([rot.apply(p) for p in np.array([[400.0, 0, 0], [450, 60, 0], [420, -50, 40]])], axis=1)
    truth = np.concatenate([foot[:, None], other + [0.0, 0.0, 900.0]], axis=1)
    measured = truth + np.random.default_rng(2).normal(0, NOISE, truth.shape)
    m, s, e = 0, 190, 210
    x, valid = hide(measured, [(m, s, e)])
    res = fill_gaps(x, valid, RATE)
    rec = res.gaps[0]
    assert rec.method in ("linear", "pchip")
    assert gap_error(res, truth, m, s, e) < 2.0
    # judged on the stretches alone, interpolation's error would be over 4x higher (13.6 and 26.7 mm for PCHIP
    # and linear, which fill the gap within 0.5 mm)
    monkeypatch.setattr(gapfill, "_STILL_EDGE_RATIO", 0.0)
    beside = fill_gaps(x, valid, RATE).gaps[0].errors
    for meth in ("linear", "pchip"):
        assert beside[meth] > 4.0 * rec.errors[meth]

def test_pca_novelty_flags_poses_the_model_never_saw():
    """The PCA model's fit residual on its predictors is about as large in a gap as in the stretches beside it
    when the gap shows the same kind of motion, and far larger when the gap holds a movement that training never
    saw (the take is still before and after it)."""
    from gazepipe.stages.clean.fill_methods import fit_pca_models, pca_novelty
    from gazepipe.stages.clean.gapfill import _PCA_NOVELTY_MIN

    m, s, e = 5, 275, 315
    wins = [(230, 270), (320, 360)]

    def ratio(measured: np.ndarray) -> float:
        valid = np.ones(measured.shape[:2], bool)
        known = valid[:, m].copy()
        for a, b in [(s, e), *wins]:
            known[a:b] = False
        model = fit_pca_models(measured, valid, m, known, s, e, (None,))[0]
        return pca_novelty(model, measured, valid, valid, wins, s, e)

    truth, measured, _ = body()
    assert 0.5 < ratio(measured) < _PCA_NOVELTY_MIN / 1.5
    truth0, _, _ = body(noise=0.0)
    idx = np.concatenate([np.full(280, 100), np.linspace(100, 400, 30).round().astype(int), np.full(290, 400)])
    still = truth0[idx] + np.random.default_rng(5).normal(0, NOISE, (600, truth0.shape[1], 3))
    assert ratio(still) > 1.5 * _PCA_NOVELTY_MIN

def test_pca_body_frame_with_some_predictors_hidden():
    """In the body frame (predictors' mean trajectory subtracted) the centroid of the predictors measured in a
    frame is shifted by their mean offset from all predictors' centroid: a translating shape is predicted
    exactly from any subset of its markers."""
    from gazepipe.stages.clean.fill_methods import PcaModel

    rng = np.random.default_rng(3)
    n_t = 300
    t = np.arange(n_t) / RATE
    shape = rng.normal(0, 150, (6, 3))
    root = np.stack([800 * np.sin(0.7 * t), 300 * np.cos(1.3 * t), 50 * t ** 2], axis=1)
    xyz = shape[None] + root[:, None, :]
    valid = np.ones((n_t, 6), bool)
    model = PcaModel(xyz, valid, 5, np.arange(5), np.arange(0, 200))
    vis = valid.copy()
    vis[200:, :3] = False  # only predictors 3 and 4 measured in the frames predicted
    pred = model.predict(xyz, vis, np.arange(200, n_t))[0]
    assert np.abs(pred - xyz[200:, 5]).max() < 1e-6
    # the offset matters: the visible predictors' centroid is tens of mm away from all predictors' centroid
    assert np.linalg.norm(shape[3:5].mean(axis=0) - shape[:5].mean(axis=0)) > 20.0


def test_pchip_eval_is_scipys_pchip_bit_for_bit():
    """The PCHIP evaluated on the few knots around a gap is scipy's interpolant exactly (flat stretches, sign
    changes of the slope, uneven knot spacing, two knots)."""
    from scipy.interpolate import PchipInterpolator

    from gazepipe.stages.clean.fill_methods import pchip_eval

    rng = np.random.default_rng(5)
    for trial in range(300):
        n = int(rng.integers(2, 12))
        x = np.sort(rng.choice(100, n, replace=False)).astype(np.float64)
        y = rng.normal(0, 50, (n, 3)).cumsum(axis=0)
        if trial % 3 == 0:
            y[int(rng.integers(n))] = y[0]  # repeated values: zero slopes
        if trial % 4 == 0:
            y = np.round(y)  # integer data (ART files): many equal neighbours
        t = np.setdiff1d(np.arange(x[0], x[-1]), x)
        if t.size:
            assert np.array_equal(pchip_eval(x, y, t), PchipInterpolator(x, y, axis=0)(t))


def _carried(ref: np.ndarray, cur: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The rigid fill's carry of point ``p`` fixed to mates ``ref`` (K, 3) onto each frame's mates ``cur``
    (n, K, 3), through the compiled kernel: (n, 3)."""
    from gazepipe.stages.clean.model_kernels import _carry

    n, k = cur.shape[:2]
    xyz = np.full((n + 1, k + 1, 3), np.nan)
    xyz[0, :k], xyz[0, k] = ref, p                      # the reference frame, the point measured there
    xyz[1:, :k] = cur
    out = np.empty((n, 3))
    for f in range(n):
        _carry(xyz, 0, f + 1, k, np.arange(k), k, out[f])
    return out


def test_two_mate_rotation_moves_a_rigid_point():
    """With two mates the fill rotates the reference the least way onto each frame's axis: a point on a body
    turning about an axis perpendicular to the mates' axis, through their midpoint, is recovered exactly."""
    ref = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]])
    p = np.array([50.0, 0.0, 80.0])  # above the midpoint, in the plane the rotation keeps
    ang = np.linspace(-2.5, 2.5, 41)
    rot = Rotation.from_euler("y", ang[:, None])
    shift = np.array([10.0, -20.0, 30.0])
    cur = np.stack([rot.apply(r - ref.mean(axis=0)) for r in ref], axis=1) + ref.mean(axis=0) + shift
    want = rot.apply(p - ref.mean(axis=0)) + ref.mean(axis=0) + shift
    assert np.abs(_carried(ref, cur, p) - want).max() < 1e-9


def test_three_mates_carry_a_rigid_point_through_any_rotation():
    """With three or more mates the carry is the least-squares rigid motion of the mates (det +1, never a
    reflection): a point of a rigid body turned through random rotations, near half turns included, lands where
    the body took it; with noisy mates it lands where the rigid fit of those mates (scipy's) takes it."""
    rng = np.random.default_rng(3)
    ref = rng.uniform(-80.0, 80.0, (4, 3))
    p = np.array([20.0, -30.0, 110.0])
    rot = Rotation.random(200, random_state=4) * Rotation.from_rotvec([[0.0, 0.0, 0.0]] * 100
                                                                       + [[0.0, 0.0, np.pi - 1e-6]] * 100)
    shift = rng.normal(0.0, 500.0, (200, 3))
    cur = np.stack([rot.apply(r) for r in ref], axis=1) + shift[:, None]
    assert np.abs(_carried(ref, cur, p) - (rot.apply(p) + shift)).max() < 1e-9
    noisy = cur + rng.normal(0.0, 2.0, cur.shape)
    fits = [Rotation.align_vectors(c - c.mean(axis=0), ref - ref.mean(axis=0))[0] for c in noisy]
    want = np.array([r.apply(p - ref.mean(axis=0)) for r in fits]) + noisy.mean(axis=1)
    assert np.abs(_carried(ref, noisy, p) - want).max() < 1e-9


def test_pca_local_frame_follows_a_turning_body_part():
    """A body part turning through large angles: in the lab frame (even with its translation removed) its
    markers are far from linear in the pose, so a few components cannot reconstruct one of them; in the moving
    frame of three steady markers its shape is constant and any other marker on it is reconstructed exactly."""
    from gazepipe.stages.clean.fill_methods import PcaModel

    rng = np.random.default_rng(4)
    n_t = 400
    t = np.arange(n_t) / RATE
    shape = rng.normal(0, 80, (6, 3))
    rot = Rotation.from_euler("zyx", np.stack([2.5 * np.sin(2 * np.pi * 0.2 * t), 1.0 * np.sin(2 * np.pi * 0.35 * t),
                                              0.7 * np.cos(2 * np.pi * 0.25 * t)], axis=1))
    xyz = np.stack([rot.apply(p) for p in shape], axis=1) + np.array([300.0, -200.0, 900.0])
    valid = np.ones((n_t, 6), bool)
    train, test = np.arange(0, 300), np.arange(300, n_t)
    local = PcaModel(xyz, valid, 5, np.arange(5), train, local_frame="steady")
    lab = PcaModel(xyz, valid, 5, np.arange(5), train)
    assert local.frame is not None and lab.frame is None
    err_local = np.linalg.norm(local.predict(xyz, valid, test, local.ks)[0] - xyz[test, 5], axis=-1)
    err_lab = np.linalg.norm(lab.predict(xyz, valid, test, lab.ks[:1])[0] - xyz[test, 5], axis=-1)
    assert err_local.max() < 1e-6  # the fewest components already: the shape does not change
    assert err_lab.mean() > 5.0


def test_pca_local_frame_needs_three_spread_markers():
    """Three steadiest predictors on a line cannot fix a rotation: the model keeps the lab frame."""
    from gazepipe.stages.clean.fill_methods import PcaModel

    n_t = 200
    t = np.arange(n_t) / RATE
    line = np.array([[0.0, 0, 0], [50.0, 0, 0], [100.0, 0, 0]])
    rot = Rotation.from_euler("z", np.sin(t)[:, None])
    xyz = np.concatenate([np.stack([rot.apply(p) for p in line], axis=1),
                          np.stack([100 * np.sin(3 * t), 50 * np.cos(2 * t), t], axis=1)[:, None, :],
                          np.stack([rot.apply(np.array([30.0, 40.0, 0.0]))], axis=1)], axis=1)
    valid = np.ones((n_t, 5), bool)
    model = PcaModel(xyz, valid, 4, np.arange(4), np.arange(n_t), local_frame="steady")
    assert model.frame is None


def _edge_correct_one(pred: np.ndarray, xyz_m: np.ndarray, known_m: np.ndarray, a: int, b: int,
                  lo: int, hi: int, partial: bool = False) -> np.ndarray | None:
    """Reference: one interval at a time. Blend the mismatch at the known frames ``a - 1`` and ``b`` linearly across ``[a, b)``.

    ``pred`` covers frames ``[lo, hi)`` with ``lo <= a - 1`` where possible and ``hi >= b + 1`` where possible;
    NaN rows are frames the method could not predict. Returns the ``[a, b)`` part, or ``None`` when any frame
    of it is NaN (unless ``partial``: then NaN rows stay NaN and ``None`` means no frame at all).
    """
    core = pred[a - lo:b - lo]
    bad = np.isnan(core).any(axis=1)
    if bad.all() or (bad.any() and not partial):
        return None
    res_l = res_r = None
    if a - 1 >= lo and known_m[a - 1] and not np.isnan(pred[a - 1 - lo]).any():
        res_l = xyz_m[a - 1] - pred[a - 1 - lo]
    if b < hi and known_m[b] and not np.isnan(pred[b - lo]).any():
        res_r = xyz_m[b] - pred[b - lo]
    if res_l is None and res_r is None:
        return core
    if res_l is None:
        return core + res_r
    if res_r is None:
        return core + res_l
    w = ((np.arange(a, b) - (a - 1)) / (b - (a - 1)))[:, None]
    return core + (1.0 - w) * res_l + w * res_r


def test_packed_edge_correction_equals_the_per_interval_one() -> None:
    """The one-pass edge correction of many predictions and intervals gives, bit for bit, what correcting each
    interval on its own gives: both edges known, one, none (take boundaries, unknown or unpredicted edge
    frames), partly predicted intervals with and without ``partial``."""
    from gazepipe.stages.clean.fill_methods import _edge_correct_packed

    rng = np.random.default_rng(7)
    n_t = 60
    xyz_m = rng.normal(size=(n_t, 3)) * 100.0
    known = rng.random(n_t) > 0.2
    intervals = [(0, 4), (5, 9), (12, 13), (20, 27), (30, 31), (40, 48), (55, 60)]
    spans = [(max(a - 1, 0), min(b + 1, n_t)) for a, b in intervals]
    jobs = [(a, b, known, bool(i % 2)) for i, (a, b) in enumerate(intervals)]
    preds = rng.normal(size=(4, sum(hi - lo for lo, hi in spans), 3)) * 100.0
    preds[1, 3] = np.nan                              # an unpredicted edge frame
    preds[2, 10:12] = np.nan                          # unpredicted frames inside intervals
    preds[3, :] = np.nan                              # a prediction with nothing
    filled, none = _edge_correct_packed(preds, xyz_m, spans, jobs)
    off = o_in = 0
    for j, ((lo, hi), (a, b, km, partial)) in enumerate(zip(spans, jobs, strict=True)):
        for k in range(preds.shape[0]):
            ref = _edge_correct_one(preds[k, off:off + hi - lo], xyz_m, km, a, b, lo, hi, partial)
            got = filled[k, o_in:o_in + b - a]
            assert none[k, j] == (ref is None), (k, j)
            if ref is None:
                assert np.isnan(got).all()
            else:
                assert np.array_equal(got, ref, equal_nan=True), (k, j)
        off += hi - lo
        o_in += b - a
    assert none[3].all() and not none[0].any()


@pytest.mark.parametrize("local_frame", [None, "steady"])
def test_stacked_prediction_is_each_frames_least_squares_on_its_measured_predictors(local_frame):
    """:func:`predict_stack` against the definition, frame by frame: the first k components fitted (least squares)
    to the weighted coordinates of the predictors measured in that frame only, the unmeasured ones NaN in the
    positions (they must not leak into any frame's fit), for every candidate k."""
    from gazepipe.stages.clean.fill_methods import PcaModel, predict_stack

    truth, measured, _ = body(400, seed=6)
    valid = np.ones(measured.shape[:2], bool)
    preds = np.arange(1, 12)
    model = PcaModel(measured, valid, 0, preds, np.arange(0, 300), local_frame=local_frame)
    frames = np.arange(300, 400)
    vis = valid[frames].copy()
    rng = np.random.default_rng(2)
    vis[:, 1:] &= rng.random((100, 11)) > 0.25          # a different set of predictors hidden in most frames
    if model.frame is not None:
        vis[:, preds[model.frame]] = True               # the moving frame's own markers stay measured
    xyz = measured.copy()
    xyz[frames] = np.where(vis[..., None], xyz[frames], np.nan)
    got = predict_stack([model], xyz, frames, vis)
    n_p = preds.size
    compared = 0
    for row, f in enumerate(frames):
        seen = vis[row, preds]
        pts = measured[f, preds]
        rot = origin = None
        if model.frame is not None:
            fp = pts[model.frame]
            rot, origin = frame_from_points(fp[None, 0], fp[None, 1], fp[None, 2]), fp.mean(axis=0)[None]
            pts = (pts - origin) @ rot[0]
        ctr = np.zeros(3)
        if model.body_frame:
            ctr = pts[seen].mean(axis=0) - model.mean[:3 * n_p].reshape(n_p, 3)[seen].mean(axis=0)
        cols = np.flatnonzero(np.repeat(seen, 3))
        z = ((pts - ctr).reshape(-1)[cols] - model.mean[cols]) * model.w[cols]
        # the components usable here: those whose R diagonal (QR of the measured rows) is not negligible
        diag = np.abs(np.diag(np.linalg.qr(model.v_all[cols, :min(max(model.ks), cols.size)])[1]))
        good = diag > 1e-8 * diag.max()
        usable = int(np.argmin(good)) if not good.all() else diag.size
        for i, k in enumerate(model.ks):
            if k > usable:                              # more components than the measured rows determine
                assert np.isnan(got[i, row]).all()
                continue
            scores = np.linalg.lstsq(model.v_all[cols, :k], z, rcond=None)[0]
            want = model.v_all[3 * n_p:, :k] @ scores / model.w[3 * n_p:] + model.mean[3 * n_p:] + ctr
            if rot is not None:
                want = rot[0] @ want + origin[0]
            assert np.allclose(got[i, row], want, atol=1e-6), (f, k)
            compared += 1
    # most (frame, k) pairs were predicted and compared, not left NaN on both sides
    assert compared >= 0.5 * frames.size * len(model.ks)


def _reach_between_rests(n: int = 400, move: tuple[int, int] = (190, 205), travel_mm: float = 200.0,
                         seed: int = 0) -> np.ndarray:
    """(n, 6, 3) mm: six markers of one body part, still, then all moving ``travel_mm`` along x over the frames
    ``move`` (a gaze shift's head), then still again; 0.3 mm noise."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(-80.0, 80.0, (6, 3))
    u = np.clip((np.arange(n) - move[0]) / (move[1] - move[0]), 0.0, 1.0)
    shift = (u * u * (3.0 - 2.0 * u))[:, None] * np.array([travel_mm, 0.0, 0.0])
    return base[None] + shift[:, None, :] + rng.normal(0.0, 0.3, (n, 6, 3))


def test_a_gap_over_a_move_between_still_stretches_is_held_to_the_move():
    """Every marker but one hidden for 40 frames around a 200 mm move, still before and after: the stretches
    beside the gap are still and every method looks right there (about 0.5 mm), while interpolating across the
    move is tens of mm off mid-gap. The estimate grows with how much further the gap travels, so the gap stays
    open under a 5 mm limit instead of being filled as 'within 1 mm'."""
    truth = _reach_between_rests()
    gaps = [(m, 180, 220) for m in range(5)]
    x, valid = hide(truth, gaps)
    res = fill_gaps(x, valid, 120.0, max_error_mm=5.0)
    for g in res.gaps:
        if g.start == 180:
            assert g.method == "unfilled" and g.error_mm > 5.0
    # without a limit the fill is made, and its estimate says it is far off
    free = fill_gaps(x, valid, 120.0)
    real = np.linalg.norm(free.xyz[180:220, 0] - truth[180:220, 0], axis=1).mean()
    est = next(g.error_mm for g in free.gaps if g.marker == 0 and g.start == 180)
    assert real > 5.0 and est >= 0.5 * real


def test_a_gap_in_a_steady_move_keeps_its_estimate():
    """A steady drift through the gap and beside it: the stretches travel as far as the gap, nothing is
    scaled, and the gap is filled within its limit."""
    rng = np.random.default_rng(1)
    n = 400
    base = rng.uniform(-80.0, 80.0, (6, 3))
    drift = np.arange(n)[:, None] * np.array([0.5, 0.2, 0.0])
    truth = base[None] + drift[:, None, :] + rng.normal(0.0, 0.3, (n, 6, 3))
    x, valid = hide(truth, [(0, 180, 220)])
    res = fill_gaps(x, valid, 120.0, max_error_mm=5.0)
    g = next(g for g in res.gaps if g.marker == 0)
    assert g.method != "unfilled" and g.error_mm < 2.0
    assert np.linalg.norm(res.xyz[180:220, 0] - truth[180:220, 0], axis=1).mean() < 2.0


# ------------------------------------------------------------------------------------------- groups
def test_a_prop_that_moves_on_its_own_is_no_evidence_for_the_subject() -> None:
    """A clapper held beside a segment follows it for seconds, then claps inside a gap that hides the whole
    segment. Filled from the subject's markers only (``groups``), each fill's estimated error is honest (the mean
    real error within twice the estimate plus 1 mm, the bench's honesty criterion); with the prop in the same
    group, the fills follow its clap while the stretches beside the gap, where it was still, vouch for them."""
    truth, measured, clusters = body()
    s, e = 300, 340
    clap = np.zeros(len(truth))
    clap[s + 5:e - 5] = 40.0 * np.sin(np.linspace(0.0, np.pi, e - s - 10))     # mm, inside the gap only
    prop = truth[:, [4, 5]] + np.array([30.0, 0.0, 0.0]) + clap[:, None, None] * np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(1)
    truth = np.concatenate([truth, prop], axis=1)
    measured = np.concatenate([measured, prop + rng.normal(0, NOISE, prop.shape)], axis=1)
    x, valid = hide(measured, [(m, s, e) for m in (4, 5, 6, 7)])

    def dishonest(res) -> list[int]:
        return [g.marker for g in res.gaps
                if gap_error(res, truth, g.marker, s, e) > 2.0 * g.error_mm + 1.0]

    assert dishonest(fill_gaps(x, valid, RATE, clusters=clusters, groups=[list(range(12)), [12, 13]])) == []
    assert len(dishonest(fill_gaps(x, valid, RATE, clusters=clusters))) == 4


def test_a_fill_that_breaks_its_segments_shape_where_the_shape_is_seen_is_held_to_it() -> None:
    """``distance_miss`` is a lower bound on a fill's error from the gap's own frames: about the noise for the
    true positions, at most the error (plus noise) for a wrong fill, and large for a fill 20 mm off while two of
    its mates are measured in half the gap."""
    from gazepipe.stages.clean.gapfill import distance_miss

    truth, measured, clusters = body()
    s, e = 300, 360
    x, valid = hide(measured, [(0, s, e), (1, s + 30, e), (2, s + 30, e), (3, s, e)])
    exact = distance_miss(x, valid, 0, s, e, clusters[0], truth[s:e, 0], 120)
    assert exact < 2 * NOISE
    rng = np.random.default_rng(3)
    for off_mm in (2.0, 5.0, 20.0):
        way = rng.normal(size=(e - s, 3))
        wrong = truth[s:e, 0] + off_mm * way / np.linalg.norm(way, axis=1, keepdims=True)
        miss = distance_miss(x, valid, 0, s, e, clusters[0], wrong, 120)
        assert miss <= off_mm + 2 * NOISE
    assert distance_miss(x, valid, 0, s, e, clusters[0], truth[s:e, 0] + np.array([20.0, 0.0, 0.0]), 120) > 5.0
    # no mate measured anywhere in the gap: the shape is not seen, nothing to say
    assert distance_miss(x, valid, 3, s + 30, e, [0, 3], truth[s + 30:e, 3] + 50.0, 120) == 0.0


def test_neighbours_from_another_segment_are_only_as_rigid_as_they_stay() -> None:
    """``mates_misfit``: the marker carried rigidly with its own segment's mates stays within the noise; with
    the trunk's markers, from which its segment swings, it is tens of millimetres off around the gap."""
    from gazepipe.stages.clean.gapfill import mates_misfit

    truth, measured, clusters = body()
    s, e = 300, 330
    x, valid = hide(measured, [(4, s, e)])
    assert mates_misfit(x, valid, 4, s, e, clusters[1], 120) < 5 * NOISE      # the reference frame's noise, carried
    assert mates_misfit(x, valid, 4, s, e, [4, *clusters[0][:3]], 120) > 20.0


# ------------------------------------------------------------------------- fills that can show their error

def test_a_gap_whose_fill_cannot_be_estimated_stays_a_gap_unless_validation_is_off():
    """A marker alone, seen every fourth frame: nothing beside its gaps can be hidden, nothing is measured
    through them: no fill can show its error, so none is written (with or without an error limit), and each
    gap says why. With validation off (the caller's explicit choice) the first method fills them."""
    from gazepipe.stages.clean.gapfill import REASON_NO_ESTIMATE

    truth, measured, _ = body(300, seed=2)
    valid = np.ones((300, 1), bool)
    valid[100:200] = (np.arange(100, 200) % 4 == 0)[:, None]
    x = np.where(valid[..., None], measured[:, :1], np.nan)
    for limit in (None, 5.0):
        res = fill_gaps(x, valid, RATE, max_error_mm=limit)
        inner = [g for g in res.gaps if 101 < g.start and g.stop < 199]
        assert inner and all(g.method == "unfilled" and g.reason == REASON_NO_ESTIMATE for g in inner)
        assert all(np.isfinite(g.error_mm) for g in res.gaps if g.method != "unfilled")
    blind = fill_gaps(x, valid, RATE, validation=False)
    assert all(g.method != "unfilled" for g in blind.gaps)


def test_a_blend_nothing_could_be_hidden_for_is_estimated_by_its_members_errors():
    """Gaps of one frame between single measured samples (a marker seen every other frame): no stretch beside
    them can be hidden, but the markers moving with it, measured through them, give interpolation's error on
    the gap's own frames. A blend of such members is estimated by its weighted errors, which bound its own
    (triangle inequality), so the gaps are filled, with estimates no smaller than their real errors."""
    from gazepipe.stages.clean.gapfill import fill_error

    assert fill_error({"pchip": 0.5, "linear": 0.5}, {"pchip": 1.0, "linear": 3.0}, None) == 2.0
    assert np.isnan(fill_error({"pchip": 0.5, "linear": 0.5}, {"pchip": 1.0, "linear": np.nan}, None))
    truth, measured, clusters = body(300, seed=3)
    valid = np.ones(measured.shape[:2], bool)
    valid[100:160:2, 1] = False
    x = np.where(valid[..., None], measured, np.nan)
    res = fill_gaps(x, valid, RATE, clusters=clusters, max_error_mm=5.0, methods=("pchip", "linear"))
    inner = [g for g in res.gaps if 101 < g.start < 158]
    assert inner and all(g.method != "unfilled" and np.isfinite(g.error_mm) for g in inner)
    real = np.array([np.linalg.norm(res.xyz[g.start, 1] - truth[g.start, 1]) for g in inner])
    est = np.array([g.error_mm for g in inner])
    assert real.mean() <= est.mean()


def test_unlabeled_trajectories_are_named_as_labellers_name_them():
    from gazepipe.stages.clean.gapfill import unlabeled_markers

    names = ["*155", "Subject:*3", "Unlabeled 3", "Unlabeled:1001", "unlabelled_7", "Unidentified 12", "_unnamed",
             "_unnamed~2", "Unnamed4", "SACR", "M1", "Star", "*", "LASI*", "C7", "Unlabeled_marker_cap"]
    assert [names[i] for i in unlabeled_markers(names)] == names[:9]


def test_an_unlabeled_trajectory_is_left_alone():
    """``leave``: the gaps of the markers it names stay, and say why; the others' are filled."""
    from gazepipe.stages.clean.gapfill import REASON_UNLABELED

    truth, measured, clusters = body(300, seed=4)
    x, valid = hide(measured, [(1, 100, 130), (5, 150, 170)])
    res = fill_gaps(x, valid, RATE, clusters=clusters, leave=[1])
    g1 = next(g for g in res.gaps if g.marker == 1)
    assert g1.method == "unfilled" and g1.reason == REASON_UNLABELED
    assert (res.fill_code[100:130, 1] == FILL_CODES["unfilled"]).all()
    assert (res.fill_code[150:170, 5] != FILL_CODES["unfilled"]).all()


# ------------------------------------------------------------------------------------------- compiled kernels
def test_interpolation_kernel_is_the_interpolant_through_every_known_sample() -> None:
    """interp_fill (compiled, a few anchors each side) gives the bits of scipy's PCHIP through every known sample
    and of the straight line between the nearest known samples; None exactly where an interval has no known
    sample on one side or one inside it."""
    from scipy.interpolate import PchipInterpolator

    from gazepipe.stages.clean.fill_methods import interp_fill

    rng = np.random.default_rng(11)
    for trial in range(200):
        n_t = int(rng.integers(6, 90))
        xyz = rng.normal(0, 40, (n_t, 3)).cumsum(axis=0)
        if trial % 3 == 0:
            xyz = np.round(xyz)                          # equal neighbours: zero slopes
        known = rng.random(n_t) > rng.uniform(0.1, 0.6)
        starts = rng.integers(0, n_t - 1, 4)
        intervals = [(int(a), int(min(n_t, a + rng.integers(1, 9)))) for a in starts]
        idx = np.flatnonzero(known)
        for kind in ("pchip", "linear"):
            got = interp_fill(xyz, known, intervals, kind)
            for (a, b), g in zip(intervals, got, strict=True):
                ok = idx.size > 0 and idx[0] < a and idx[-1] >= b and not known[a:b].any()
                assert (g is not None) == ok, (trial, kind, a, b)
                if not ok:
                    continue
                t = np.arange(a, b, dtype=np.float64)
                if kind == "pchip":
                    ref = PchipInterpolator(idx.astype(np.float64), xyz[idx], axis=0)(t)
                else:
                    t0, t1 = idx[idx < a][-1], idx[idx >= b][0]
                    w = ((t - t0) / (t1 - t0))[:, None]
                    ref = (1.0 - w) * xyz[t0] + w * xyz[t1]
                assert np.array_equal(g, ref), (trial, kind, a, b)


def test_nearest_complete_frames_are_found_outward_from_each_interval() -> None:
    """The compiled search for a rigid fill's reference frames finds the nearest frame before each interval and
    the nearest at or after its end where the marker is known and every mate measured (-1: none), as a search
    over every frame does."""
    from gazepipe.stages.clean import kernels

    rng = np.random.default_rng(3)
    for _ in range(100):
        n_t, n_m = int(rng.integers(5, 60)), 6
        valid = rng.random((n_t, n_m)) > 0.3
        known = rng.random(n_t) > 0.3
        cols = np.sort(rng.choice(n_m, int(rng.integers(1, 4)), replace=False)).astype(np.int64)
        starts = rng.integers(0, n_t, 3).astype(np.int64)
        stops = np.minimum(starts + rng.integers(1, 6, 3), n_t).astype(np.int64)
        before, after = kernels.nearest_complete(known, valid, cols, starts, stops)
        complete = np.flatnonzero(known & valid[:, cols].all(axis=1))
        for i in range(3):
            b_ref = complete[complete < starts[i]]
            a_ref = complete[complete >= stops[i]]
            assert before[i] == (b_ref[-1] if b_ref.size else -1)
            assert after[i] == (a_ref[0] if a_ref.size else -1)


def test_kernels_compile_where_no_cache_can_be_written(monkeypatch) -> None:
    """Where numba finds no writable cache directory (a read-only install, no writable home) it refuses
    ``cache=True`` when the function is decorated; the kernels are then compiled once per process instead."""
    import numba

    from gazepipe.stages import jit

    real = numba.njit

    def refusing(*args, cache=False, **kwargs):
        if cache:
            raise RuntimeError("cannot cache function 'f': no locator available for file 'kernels.py'")
        return real(*args, cache=cache, **kwargs)

    monkeypatch.setattr(numba, "njit", refusing)

    def twice(x: float) -> float:
        return 2.0 * x

    assert jit.kernel(twice)(1.5) == 3.0
