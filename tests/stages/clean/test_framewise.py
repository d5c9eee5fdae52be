"""Frame-by-frame model averaging of a gap's candidate fills (gazepipe.stages.clean.framewise)."""

from __future__ import annotations

import numpy as np

from gazepipe.io.capture import read_markers
from gazepipe.io.session_toml import load_markerset
from gazepipe.stages.clean import framewise
from gazepipe.stages.clean.gapfill import NOTE_FRAMEWISE, fill_gaps
from gazepipe.stages.clean.spikes import find_spikes
from gazepipe.synth import SynthConfig, generate_session


def _rigid_scene(n: int = 200, seed: int = 0):
    """A marker m = 0 rigidly linked to three others, the whole body turning and moving; 0.3 mm noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 30.0
    body = np.array([[0.0, 0.0, 0.0], [120.0, 0.0, 0.0], [0.0, 90.0, 0.0], [0.0, 0.0, 150.0]])
    ang = 0.8 * np.sin(0.7 * t)
    c, s = np.cos(ang), np.sin(ang)
    rot = np.stack([np.stack([c, -s, 0 * c], 1), np.stack([s, c, 0 * c], 1), np.tile([0.0, 0, 1], (n, 1))], 1)
    xyz = np.einsum("tij,mj->tmi", rot, body) + np.stack([300 * t, 50 * np.sin(t), 0 * t], 1)[:, None]
    return xyz + rng.normal(0, 0.3, xyz.shape), xyz


def test_each_frame_follows_the_candidate_that_keeps_the_distances():
    noisy, truth = _rigid_scene()
    valid = np.ones(noisy.shape[:2], dtype=bool)
    s, e = 80, 120
    valid[s:e, 0] = False
    links = framewise.linked_neighbours(noisy, valid, valid[:, 0], 0, s, e, 60)
    assert sorted(links[0].tolist()) == [1, 2, 3]
    off = np.zeros((e - s, 3))
    off[: (e - s) // 2, 0] = 30.0            # "a" is 30 mm off in the first half, right in the second
    good_a, good_b = truth[s:e, 0] + off, truth[s:e, 0] + off[::-1]
    avg = framewise.average({"a": good_a, "b": good_b}, {"a": 0.5, "b": 0.5}, np.arange(s, e), noisy, valid,
                            links)
    err = np.linalg.norm(avg - truth[s:e, 0], axis=1)
    # each half follows the candidate that is right there (away from the switch, which the smoothing spreads)
    inner = np.r_[0:15, 25:40]
    assert err[inner].max() < 3.0, err
    assert np.linalg.norm(0.5 * (good_a + good_b) - truth[s:e, 0], axis=1)[inner].min() > 14.0   # the flat mean


def test_where_the_average_is_kept_it_is_closer_to_the_truth(tmp_path):
    """On a hostile generated take (long trunk occlusions, spikes, dense gaps): the gaps filled by the
    frame-by-frame average are, taken together, closer to the truth than the per-gap blend would have filled
    them, and the average is kept on some of the long gaps."""
    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=30.0, head_camera=False, face_takes=(),
                      shift_targets=(), spikes_per_marker_min=1.0, long_gaps=4, gaps_per_marker_min=3.0)
    folder = generate_session(tmp_path / "s", seed=5, config=cfg)
    ms = load_markerset(folder / "markerset.toml")
    c3d = next((folder / "mocap").glob("follow_*.c3d"))
    mk = read_markers(c3d)
    pos = {lab: i for i, lab in enumerate(mk.labels)}
    clusters = [[pos[n] for n in seg.markers if n in pos] for seg in ms.segments]
    valid = mk.valid & ~find_spikes(mk.xyz, mk.valid, mk.rate_hz, clusters)
    xyz = np.where(valid[..., None], mk.xyz, np.nan)
    truth = np.load(folder / "truth" / f"{c3d.stem}.npz")["markers_true"].astype(np.float64)
    both = fill_gaps(xyz, valid, mk.rate_hz, clusters=clusters, max_gap_s=3.0)
    alone = fill_gaps(xyz, valid, mk.rate_hz, clusters=clusters, max_gap_s=3.0, framewise=False)
    used = [g for g in both.gaps if g.reason == NOTE_FRAMEWISE]
    long = [g for g in both.gaps if g.length >= 16 and g.method != "unfilled"]
    assert len(used) >= 3, (len(used), len(long))
    err = [np.linalg.norm(r.xyz[g.start:g.stop, g.marker] - truth[g.start:g.stop, g.marker], axis=1).mean()
           for g in used for r in (both, alone)]
    assert np.mean(err[0::2]) < np.mean(err[1::2]), (np.mean(err[0::2]), np.mean(err[1::2]))
