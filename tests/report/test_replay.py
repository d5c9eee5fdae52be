"""The 3D replay of a take (gazepipe.report.replay, replay_page, `gazepipe view`): its data (sample colours from
the markers table, the raw capture in the cleaned axes, the worst moments, decimation that keeps them, the size
bound, byte-identical pages, z-up and y-up skeletons), the page in headless Chromium, and the command."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.model import FILL_CODES, Markers, MarkerSet, Segment
from gazepipe.report.collect import load_sessions, open_output, take_entries
from gazepipe.report.replay import (
    CATEGORIES,
    ReplayInputs,
    choose_frames,
    load_replay_inputs,
    raw_in_clean_axes,
    sample_categories,
    stick_pairs,
    window_half,
    worst_moments,
)
from gazepipe.report.replay_page import (
    CLEANED_TRACES,
    LEGEND,
    PLOTLY_JS,
    RAW_TRACES,
    RELATIVE_PLOTLY,
    REPLAY_MAX_BYTES,
    build_replay,
    plotly_js,
    replay_html,
)
from tests.helpers import HOSTILE_LABELS, check_page_escapes

CHROMIUM = Path("/usr/bin/chromium")
TAKE = "session01/follow_standing_03"     # the sample take with a stretch that gives no dataset row


# ----------------------------------------------------------------------------------- a synthetic take

TEN = [("pelvis", 3), ("spine1", 3), ("spine2", 3), ("spine3", 3), ("spine4", 3), ("chest", 4), ("neck1", 3),
       ("neck2", 3), ("neck3", 3), ("head", 5)]
FOUR = [("pelvis", 3), ("chest", 4), ("neck2", 3), ("head", 5)]


def _markerset(skeleton: list[tuple[str, int]], up: str) -> MarkerSet:
    segs, parent = [], None
    for name, n in skeleton:
        segs.append(Segment(name, tuple(f"{name.upper()}{i}" for i in range(n)), parent))
        parent = name
    return MarkerSet(path="markerset.toml", up_axis=up, units="mm", root="ROOT", target="POLE", clapper=(),
                     segments=tuple(segs), head_centre=None)


def synthetic_take(skeleton=TEN, up: str = "z", T: int = 900, rate: float = 100.0, seed: int = 0,
                   heading: bool = False) -> ReplayInputs:
    """A take made by hand, with everything the replay shows and a known answer: a body walking along x, its
    cleaned markers stabilised (root at the origin, and turned when ``heading``), a gap filled by PCA with a
    known error, an unfilled stretch that leaves a segment without rotation, a removed spike, a repaired
    label swap, a filled rotation; the crop cuts 50 frames at each end."""
    rng = np.random.default_rng(seed)
    ms = _markerset(skeleton, up)
    labels = ["ROOT"] + [m for s in ms.segments for m in s.markers] + ["POLE"]
    M = len(labels)
    upv = np.zeros(3)
    upv["xyz".index(up)] = 1.0
    fwd = np.array([1.0, 0, 0])
    side = np.cross(upv, fwd)
    t = np.arange(T) / rate
    body = np.zeros((M, 3))
    k = 1
    for i, s in enumerate(ms.segments):       # segments stacked up the body, markers on a small circle
        for j in range(len(s.markers)):
            a = 2 * np.pi * j / len(s.markers) + 0.3 * i
            body[k] = 80 * np.cos(a) * fwd + 80 * np.sin(a) * side + (150 + 80 * i) * upv
            k += 1
    body[-1] = 1500 * fwd + 300 * upv                                        # the target
    root_path = (400 * t)[:, None] * fwd + 900 * upv + 30 * np.sin(t)[:, None] * side
    xyz = root_path[:, None, :] + body[None] + rng.normal(0, 0.5, (T, M, 3))
    xyz[:, -1] = body[-1] + 500 * np.sin(0.7 * t)[:, None] * side            # the target moves in the room
    raw_valid = np.ones((T, M), dtype=bool)
    fill = np.zeros((T, M), dtype=np.int8)
    err = np.full((T, M), np.nan)
    spike = np.zeros((T, M), dtype=bool)
    clean_xyz = xyz.copy()
    i = labels.index
    seg0 = ms.segments[2].markers
    # a gap of one marker filled by PCA, error known
    raw_valid[300:340, i(seg0[0])] = False
    fill[300:340, i(seg0[0])] = FILL_CODES["pca"]
    err[300:340, i(seg0[0])] = np.linspace(1, 6, 40)
    # an unfilled stretch: two markers of a segment, so it has no rotation there
    seg1 = ms.segments[1].markers
    raw_valid[500:560, [i(seg1[0]), i(seg1[1])]] = False
    fill[500:560, [i(seg1[0]), i(seg1[1])]] = FILL_CODES["unfilled"]
    # a removed spike, refilled by linear
    sp = i(ms.segments[-1].markers[0])
    raw_xyz = xyz.copy()
    raw_xyz[620, sp] += np.array([0.0, 400.0, 0.0])
    spike[620, sp] = True
    fill[620, sp] = FILL_CODES["linear"]
    err[620, sp] = 0.8
    # a label swap, repaired: in the raw capture the pelvis' first two markers exchange names
    a, b = i(ms.segments[0].markers[0]), i(ms.segments[0].markers[1])
    raw_xyz[700:760, [a, b]] = raw_xyz[700:760, [b, a]]
    fill[700:760, [a, b]] = FILL_CODES["swap_repaired"]
    raw_xyz[~raw_valid] = np.nan
    raw = Markers(labels=list(labels), xyz=raw_xyz, valid=raw_valid, rate_hz=rate)
    # the cleaning: stabilised (root at the origin, turned about the vertical when heading), cropped
    clean_valid = fill != FILL_CODES["unfilled"]
    clean_xyz = clean_xyz - clean_xyz[:, [0]]
    if heading:
        from scipy.spatial.transform import Rotation

        rot = Rotation.from_rotvec(np.outer(0.3 * np.sin(t), upv))
        clean_xyz = np.einsum("tij,tmj->tmi", rot.as_matrix(), clean_xyz)
    clean_xyz[~clean_valid] = np.nan
    lo, hi = 50, T - 50
    clean = Markers(labels=list(labels), xyz=clean_xyz[lo:hi], valid=clean_valid[lo:hi], rate_hz=rate,
                    first_frame=1 + lo)
    frames = np.arange(lo, hi)
    S = len(ms.segments)
    n = hi - lo
    quat = np.tile([1.0, 0, 0, 0], (n, S, 1))
    quat[500 - lo:560 - lo, 1] = np.nan                  # no rotation of segment 1 where its markers are gone
    rot_filled = np.zeros((n, S), dtype=bool)
    rot_filled[200 - lo:240 - lo, 3] = True
    joints = {"frame": frames, "char_rot": np.tile([1.0, 0, 0, 0], (n, 1)), "char_origin": np.zeros((n, 3)),
              "head_centre": np.tile(body[-2], (n, 1)), "target_dir": np.tile([1.0, 0, 0], (n, 1)),
              "quat": quat, "rot_filled": rot_filled}
    return ReplayInputs(key="s/take", kind="gaze_follow", markerset=ms, raw=raw, clean=clean, clean_frames=frames,
                        fill=fill[lo:hi], spike=spike[lo:hi], fill_error_mm=err[lo:hi], crop=(lo, hi),
                        swaps=[(labels[a], labels[b], 700, 760, True)], joints=joints,
                        rotation_errors=[(3, 200, 240, "slerp", 1.5)], heading_removed=heading,
                        feeds=True, needs_target=True)


def _trace_names(rep) -> list[str]:
    return [t.get("name", "") for t in rep.figure["data"]]


def _frame(rep, f: int) -> list[dict]:
    return next(fr["data"] for fr in rep.figure["frames"] if fr["name"] == str(f))


def _decode(arr) -> np.ndarray:
    import base64

    if isinstance(arr, list):
        return np.asarray(arr, dtype=np.float64)
    assert arr["dtype"] == "f4"
    return np.frombuffer(base64.b64decode(arr["bdata"]), dtype="<f4").astype(np.float64)


# ------------------------------------------------------------------------------------------ the data

def test_sample_colours_are_the_markers_tables_fill_spike_and_valid(sample_run: Path) -> None:
    """Each cleaned sample's category is the table's: unfilled where not valid, a removed spike where
    ``spike``, else its ``fill`` name; and the built frame puts every marker in its category's trace."""
    layout = open_output(sample_run)
    sessions, _ = load_sessions(layout)
    entry = next(e for e in take_entries(layout, sessions) if e.key == TAKE)
    inp = load_replay_inputs(layout, entry, sessions["session01"].markerset)
    t = pq.read_table(layout.table("session01", "follow_standing_03", "markers"),
                      columns=["marker", "frame", "fill", "spike", "valid"]).to_pydict()
    expected = {(m, f): ("unfilled" if not v else "spike" if s else fl)
                for m, f, fl, s, v in zip(t["marker"], t["frame"], t["fill"], t["spike"], t["valid"], strict=True)}
    cat = sample_categories(inp.fill, inp.spike, inp.clean.valid)
    got = {(lab, int(f)): CATEGORIES[cat[k, j]] for k, f in enumerate(inp.clean_frames)
           for j, lab in enumerate(inp.clean.labels)}
    assert got == expected
    assert {"measured", "unfilled"} <= set(expected.values()) and len(set(expected.values())) >= 3
    # the page's frames: the markers of each category's trace are those of the table at that frame
    rep = build_replay(inp)
    names = _trace_names(rep)
    for f in rep.frames[::7]:
        if not inp.crop[0] <= f < inp.crop[1]:
            continue
        data = _frame(rep, int(f))
        for name in CATEGORIES:
            trace = names.index(LEGEND[name])
            want = sorted(m for (m, fr), c in expected.items() if fr == f and c == name
                          and (name != "unfilled" or True))
            shown = sorted(data[trace]["text"])
            if name == "unfilled":
                assert set(shown) <= set(want)      # an unfilled marker never seen before has nowhere to be
            else:
                assert shown == want, (f, name)


def test_synthetic_take_categories_positions_and_raw_overlay() -> None:
    inp = synthetic_take()
    rep = build_replay(inp)
    names = _trace_names(rep)
    i = inp.clean.labels.index
    hs = inp.markerset.segments[-1].markers[0]
    # frame 620: the spike sample is drawn in the spike trace at its cleaned position; the raw one 400 mm off
    data = _frame(rep, 620)
    spike_tr = data[names.index(LEGEND["spike"])]
    assert spike_tr["text"] == [hs]
    k = 620 - inp.crop[0]
    got = np.array([_decode(spike_tr[a])[0] for a in "xyz"])
    assert np.allclose(got, inp.clean.xyz[k, i(hs)], atol=0.06)
    raw_tr = data[names.index("raw capture")]
    pos = raw_tr["text"].index(hs)
    raw = np.array([_decode(raw_tr[a])[pos] for a in "xyz"])
    assert 395 < np.linalg.norm(raw - got) < 405
    # frame 720: the swapped pair is drawn as repaired swaps, and its raw labels are shown where they were
    data = _frame(rep, 720)
    pel = list(inp.markerset.segments[0].markers[:2])
    assert sorted(data[names.index(LEGEND["swap_repaired"])]["text"]) == sorted(pel)
    assert sorted(data[names.index("raw labels of swapped markers")]["text"]) == sorted(pel)
    # outside the swap and the spike, the raw capture moved into the cleaned axes lies on the cleaned markers
    raw_in = raw_in_clean_axes(inp)
    same = inp.clean.valid & (inp.fill == 0)
    diff = raw_in[inp.clean_frames][same] - inp.clean.xyz[same]
    assert np.abs(diff).max() < 1e-6


def test_raw_is_brought_into_the_cleaned_axes_when_the_heading_was_removed() -> None:
    inp = synthetic_take(heading=True)
    raw_in = raw_in_clean_axes(inp)
    same = inp.clean.valid & (inp.fill == 0)
    assert np.abs(raw_in[inp.clean_frames][same] - inp.clean.xyz[same]).max() < 1e-6
    # outside the crop the raw root marker sits at the origin
    assert np.abs(raw_in[:50, 0]).max() < 1e-6


def test_worst_moments_name_the_frames_of_what_happened() -> None:
    inp = synthetic_take()
    got: dict = {}
    for m in worst_moments(inp):
        got.setdefault(m.kind, m)                 # the worst of each kind
    assert set(got) == {"no_row", "swap", "fill_error", "rotation", "spike"}
    assert 500 <= got["no_row"].frame < 560 and "spine1 rotation missing" in got["no_row"].label
    assert got["swap"].frame == 700 and "PELVIS0/PELVIS1" in got["swap"].label
    assert got["fill_error"].frame == 339 and "6.0 mm" in got["fill_error"].label    # the error's peak
    assert 200 <= got["rotation"].frame < 240 and "spine3" in got["rotation"].label
    assert got["spike"].frame == 620 and "400 mm" in got["spike"].label
    for m in got.values():
        assert m.label.endswith(f"frame {m.frame}")


def test_decimation_keeps_every_worst_moment_at_full_rate() -> None:
    moments = [5, 1000, 1003, 25_000, 71_999]
    frames, stride, half = choose_frames(72_000, moments, 120.0, budget=600)
    assert half == window_half(120.0)
    kept = set(frames.tolist())
    for m in moments:
        assert set(range(max(0, m - half), min(72_000, m + half + 1))) <= kept
    assert stride > 100 and set(range(0, 72_000, stride)) <= kept
    assert 0 in kept and 71_999 in kept and len(frames) <= 600 + 5
    assert np.all(np.diff(frames) > 0)
    # a short take is shown whole
    frames, stride, _ = choose_frames(300, [10], 30.0, budget=600)
    assert stride == 1 and frames.tolist() == list(range(300))
    # and a built replay has a frame, a slider step and a jump button for every moment
    inp = synthetic_take()
    rep = build_replay(inp, budget=60)
    names = {fr["name"] for fr in rep.figure["frames"]}
    steps = [s["args"][0][0] for s in rep.figure["layout"]["sliders"][0]["steps"]]
    buttons = rep.figure["layout"]["updatemenus"][-1]["buttons"]
    assert [b["args"][0][0] for b in buttons] == [str(m.frame) for m in rep.moments]
    for m in rep.moments:
        assert str(m.frame) in names and str(m.frame) in steps
        assert all(str(f) in names for f in range(m.frame - rep.window, m.frame + rep.window + 1)
                   if 0 <= f < inp.raw.n_frames)
    assert 0 < rep.window < window_half(inp.raw.rate_hz) and len(names) < inp.raw.n_frames


def test_a_long_take_stays_within_the_size_bound() -> None:
    """Ten minutes at 120 Hz: the page is at most 2 MB, its frames spread over the whole take."""
    inp = synthetic_take(T=72_000, rate=120.0, seed=3)
    page, rep = replay_html(inp, RELATIVE_PLOTLY)
    assert len(page.encode()) <= REPLAY_MAX_BYTES
    assert 150 <= len(rep.frames) <= 600 and rep.frames[-1] == 71_999
    gaps = np.diff(rep.frames)
    assert gaps.max() == rep.stride and rep.stride >= 100


def test_the_same_inputs_give_the_same_bytes() -> None:
    a = replay_html(synthetic_take(), RELATIVE_PLOTLY)[0]
    b = replay_html(synthetic_take(), RELATIVE_PLOTLY)[0]
    assert a == b
    assert f'src="{RELATIVE_PLOTLY}"' in a and "http" not in a.replace("https://plot.ly", "")
    assert 'id="replay"' in a and not re.search(r"[0-9a-f]{8}-[0-9a-f]{4}-", a)   # no random div ids


def test_hostile_marker_labels_are_escaped_in_the_page() -> None:
    """Marker labels are data: `<!--<script>` and the others of :data:`HOSTILE_LABELS` come back whole from the
    page's JSON and leave its script element whole; a label named like a placeholder of the script is not
    replaced by its value."""
    inp = synthetic_take()
    names = dict(zip([inp.raw.labels[1], inp.raw.labels[2], inp.raw.labels[4], inp.raw.labels[5]], HOSTILE_LABELS,
                     strict=True))
    for m in (inp.raw, inp.clean):
        m.labels = [names.get(lab, lab) for lab in m.labels]
    inp.markerset = MarkerSet(path="markerset.toml", up_axis="z", units="mm", root="ROOT", target="POLE",
                              clapper=(), head_centre=None, segments=tuple(
                                  Segment(s.name, tuple(names.get(n, n) for n in s.markers), s.parent)
                                  for s in inp.markerset.segments))
    page = replay_html(inp, RELATIVE_PLOTLY)[0]
    check_page_escapes(page, HOSTILE_LABELS)
    alone = replay_html(inp, "inline:" + "/* plotly */")[0]
    check_page_escapes(alone, HOSTILE_LABELS)


@pytest.mark.parametrize("skeleton, up", [(TEN, "z"), (FOUR, "y")])
def test_both_skeletons_stand_up_in_equal_millimetres(skeleton, up) -> None:
    inp = synthetic_take(skeleton, up)
    rep = build_replay(inp)
    scene = rep.figure["layout"]["scene"]
    want = {a: float(a == up) for a in "xyz"}
    assert scene["camera"]["up"] == want
    spans = np.array([np.diff(scene[f"{a}axis"]["range"])[0] for a in "xyz"])
    ratio = np.array([scene["aspectratio"][a] for a in "xyz"])
    assert np.allclose(ratio, spans / spans.max(), atol=1e-3)            # 1 mm is as long on every axis
    # the sticks join every pair of a segment's markers, and nothing across segments but the root's
    pairs = stick_pairs(inp.markerset, inp.clean.labels)
    seg_of = {m: s.name for s in inp.markerset.segments for m in s.markers}
    labs = inp.clean.labels
    assert all(seg_of.get(labs[a]) == seg_of.get(labs[b]) or "ROOT" in (labs[a], labs[b]) for a, b in pairs)
    for s in inp.markerset.segments:
        n = len(s.markers)
        assert sum(seg_of.get(labs[a]) == s.name and seg_of.get(labs[b]) == s.name for a, b in pairs) == \
            n * (n - 1) // 2
    # the whole body is inside the view, vertical along the up axis
    k = up_axis = "xyz".index(up)
    lo = np.array([scene[f"{a}axis"]["range"][0] for a in "xyz"])
    hi = np.array([scene[f"{a}axis"]["range"][1] for a in "xyz"])
    pts = inp.clean.xyz[:, 1:-1][inp.clean.valid[:, 1:-1]]
    assert (pts >= lo).all() and (pts <= hi).all()
    assert spans[up_axis] == spans.max() and k == up_axis


def test_layer_buttons_show_and_hide_the_cleaned_and_raw_traces() -> None:
    rep = build_replay(synthetic_take())
    names = _trace_names(rep)
    assert {names[i] for i in RAW_TRACES} == {"raw: sticks", "raw capture", "raw labels of swapped markers"}
    assert "cleaned: sticks" in {names[i] for i in CLEANED_TRACES}
    menu = next(m for m in rep.figure["layout"]["updatemenus"] if m["buttons"][0]["label"] == "cleaned and raw")
    only = {b["label"]: dict(zip(b["args"][1], b["args"][0]["visible"], strict=True)) for b in menu["buttons"]}
    assert all(only["cleaned only"][i] for i in CLEANED_TRACES) and not any(only["cleaned only"][i]
                                                                            for i in RAW_TRACES)
    assert all(only["raw only"][i] for i in RAW_TRACES) and not any(only["raw only"][i] for i in CLEANED_TRACES)


# ----------------------------------------------------------------------------------- the page in Chromium

def _chromium(args: list[str], tmp: Path) -> subprocess.CompletedProcess:
    base = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars",
            f"--user-data-dir={tmp / 'profile'}", "--virtual-time-budget=8000"]
    return subprocess.run(base + args, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "HOME": str(tmp)})


def _shot(url: str, tmp: Path, name: str) -> np.ndarray:
    from PIL import Image

    path = tmp / f"{name}.png"
    res = _chromium([f"--screenshot={path}", "--window-size=1200,800", url], tmp)
    assert res.returncode == 0 and path.exists(), res.stderr[-2000:]
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.int16)


def _dom_frame(url: str, tmp: Path) -> str:
    res = _chromium(["--dump-dom", url], tmp)
    assert res.returncode == 0, res.stderr[-2000:]
    assert 'data-ready="1"' in res.stdout, "the page's script did not finish"
    return re.search(r'data-frame="(\d*)"', res.stdout).group(1)


@pytest.mark.skipif(not CHROMIUM.exists(), reason="Chromium not installed here (/usr/bin/chromium; "
                    "apt-get install chromium): CI installs it")
def test_chromium_draws_the_replay_the_slider_moves_it_and_a_jump_lands_on_its_frame(sample_run: Path,
                                                                                     tmp_path: Path) -> None:
    layout = open_output(sample_run)
    sessions, _ = load_sessions(layout)
    entry = next(e for e in take_entries(layout, sessions) if e.key == TAKE)
    page, rep = replay_html(load_replay_inputs(layout, entry, sessions["session01"].markerset), RELATIVE_PLOTLY)
    qc = tmp_path / "qc"
    (qc / "replay" / "session01").mkdir(parents=True)
    (qc / PLOTLY_JS).write_bytes(plotly_js())
    path = qc / "replay" / "session01" / "follow_standing_03.html"
    path.write_text(page)
    url = path.resolve().as_uri()
    fig = json.loads(re.search(r"var fig=(\{.*?\}), info=", page, re.S).group(1).replace("<\\/", "</"))
    buttons = fig["layout"]["updatemenus"][-1]["buttons"]
    named = [int(re.search(r"frame (\d+)$", b["label"]).group(1)) for b in buttons]
    steps = fig["layout"]["sliders"][0]["steps"]
    assert named and named == [m.frame for m in rep.moments]

    # a jump button lands on the frame it names (the page's own record of the frame it shows)
    k = len(named) - 1
    assert _dom_frame(f"{url}#jump={k}", tmp_path) == str(named[k])
    # ... and shows what the slider shows at that frame; a slider step far from it shows another figure
    frame_of = [int(s["args"][0][0]) for s in steps]
    far = max((i for i, f in enumerate(frame_of) if rep.frames[0] <= f), key=lambda i: abs(frame_of[i] - named[k]))
    jumped = _shot(f"{url}#jump={k}", tmp_path, "jump")
    direct = _shot(f"{url}#step={frame_of.index(named[k])}", tmp_path, "step_there")
    other = _shot(f"{url}#step={far}", tmp_path, "step_far")
    h, w, _ = jumped.shape
    # the 3D view: right of the jump buttons, above the timeline
    area = (slice(int(0.08 * h), int(0.62 * h)), slice(int(0.3 * w), int(0.85 * w)))
    for img in (jumped, other):
        drawn = (np.abs(img[area] - 255).sum(axis=2) > 60).mean()
        assert drawn > 0.01, f"the 3D view is blank ({drawn:.4f} of its pixels drawn)"
        assert (img[area].max(axis=2) < 110).sum() > 150, "no marker or stick drawn"   # dark grey markers
    moved = (np.abs(other[area] - direct[area]).sum(axis=2) > 60).mean()
    assert moved > 0.002, "the slider did not change the figure"
    same = (np.abs(jumped - direct).sum(axis=2) > 60).mean()
    assert same < moved / 5, "the jump button did not land on the frame it names"


# ------------------------------------------------------------------------------------------ the command

@pytest.fixture(scope="module")
def out_copy(tmp_path_factory, sample_run: Path) -> Path:
    """A copy of the sample run (the datasets left out) that `gazepipe view` may write into, with the clean
    stage of one take made to have failed."""
    out = tmp_path_factory.mktemp("view") / "out"
    shutil.copytree(sample_run, out, ignore=shutil.ignore_patterns("datasets"))
    layout = open_output(out)
    layout.table("session01", "shift_y072_p00", "markers").unlink()
    rec_path = layout.record("session01", "shift_y072_p00", "clean")
    rec = json.loads(rec_path.read_text())
    rec.update(status="failed", error="clean: no rest period found at the end of the take")
    rec_path.write_text(json.dumps(rec))
    return out


def test_view_writes_the_page_of_any_take_and_prints_its_path(out_copy: Path, tmp_path: Path) -> None:
    res = CliRunner().invoke(cli, ["view", str(out_copy), "session01/shift_y036_p12"])
    assert res.exit_code == 0, res.output
    path = Path(res.stdout.strip().splitlines()[-1])
    assert path == out_copy / "qc" / "view" / "session01" / "shift_y036_p12.html"
    assert (out_copy / "qc" / PLOTLY_JS).read_bytes() == plotly_js()
    page = path.read_text()
    assert '<script src="../../plotly.min.js"' in page and "shift_y036_p12" in page
    # a take id alone, when one session has it; --to writes one file that stands alone
    dest = tmp_path / "alone.html"
    res = CliRunner().invoke(cli, ["view", str(out_copy), "neutral", "--to", str(dest)])
    assert res.exit_code == 0, res.output
    assert res.stdout.strip().splitlines()[-1] == str(dest)
    alone = dest.read_text()
    assert "<script src=" not in alone and len(alone) > len(plotly_js())


def test_view_says_what_is_wrong_in_one_line(out_copy: Path, tmp_path: Path) -> None:
    def run(*args: str):
        res = CliRunner().invoke(cli, ["view", *args])
        lines = res.output.strip().splitlines()
        assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: "), res.output
        return lines[0]

    line = run(str(out_copy), "session01/follow_standing_3")
    assert "no take 'session01/follow_standing_3'" in line and "session01/follow_standing_03" in line
    line = run(str(tmp_path / "nowhere"), "session01/neutral")
    assert "nowhere" in line and "not a folder" in line
    line = run(str(out_copy), "session01/shift_y072_p00")
    assert "clean stage failed" in line and "no rest period" in line
    line = run(str(out_copy), "session01/face_01")
    assert "face take" in line


def test_view_help_teaches() -> None:
    text = CliRunner().invoke(cli, ["view", "--help"]).output
    assert "gazepipe view out/ session01/follow_standing_01 --open" in text
    assert "--to" in text and "--open" in text and "OUT/qc/view/SESSION/TAKE.html" in text


# ------------------------------------------------------------------------------------------- the report

def test_the_report_links_a_replay_per_drawn_take_made_on_the_workers(sample_process_run: dict,
                                                                      tmp_path: Path) -> None:
    """`gazepipe run` (process executor) writes a replay page per drawn take and qc/plotly.min.js once; the
    page links each; `gazepipe validate` writes the same bytes; --no-plots draws none and deletes none."""
    out = sample_process_run["out"]
    qc = out / "qc"
    report = json.loads((qc / "report.json").read_text())
    html = (qc / "report.html").read_text()
    pages = sorted(p.relative_to(qc).as_posix() for p in (qc / "replay").rglob("*.html"))
    assert 1 <= len(pages) <= 6
    assert (qc / PLOTLY_JS).read_bytes() == plotly_js()
    for rel in pages:
        assert f'href="{rel}"' in html and "<iframe" not in html       # a link: the report loads no replay
        assert len((qc / rel).read_bytes()) <= REPLAY_MAX_BYTES
    keys = {f"{t['session']}/{t['take']}" for t in report["takes"]}
    assert {p[len("replay/"):-len(".html")] for p in pages} <= keys
    assert "<script" not in html and "http" not in html
    copy = tmp_path / "out"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("datasets"))
    res = CliRunner().invoke(cli, ["validate", str(copy)])
    assert res.exit_code == 0, res.output
    for rel in pages:
        assert (copy / "qc" / rel).read_bytes() == (qc / rel).read_bytes(), rel
    drawn, drawn_json = (copy / "qc" / "report.html").read_text(), (copy / "qc" / "report.json").read_bytes()
    res = CliRunner().invoke(cli, ["validate", str(copy), "--no-plots"])
    assert res.exit_code == 0, res.output
    # --no-plots draws none and deletes none: the pages stay, linked, and the page keeps the plots drawn before
    kept = (copy / "qc" / "report.html").read_text()
    for rel in pages:
        assert (copy / "qc" / rel).read_bytes() == (qc / rel).read_bytes(), rel
        assert f'href="{rel}"' in kept
    assert kept.count('<figure class="plot">') == drawn.count('<figure class="plot">') > 0
    assert "none drawn (--no-plots)" in kept and "Kept from the report drawn before" in kept
    assert (copy / "qc" / "report.json").read_bytes() == drawn_json


def test_validate_keeps_the_replays_of_unchanged_takes_it_does_not_draw(out_copy: Path, tmp_path: Path) -> None:
    """`validate` deletes no view of the current outputs: the replay pages of takes it does not draw this time
    stay while they are their take's page; a take gone loses its page; --no-plots draws and deletes none."""
    out = tmp_path / "out"
    shutil.copytree(out_copy, out)
    shutil.rmtree(out / "qc" / "replay")        # the run's pages (still current: they would be kept too)

    def validate(*args: str) -> str:
        res = CliRunner().invoke(cli, ["validate", str(out), "--plot-takes", "0", *args])
        assert res.exit_code in (0, 3), res.output
        return (out / "qc" / "report.html").read_text()

    validate("--plot-take", "shift_y0[03]*")
    replay = out / "qc" / "replay" / "session01"
    shifts = sorted(p.name for p in replay.glob("*.html"))
    assert shifts == ["shift_y000_p12.html", "shift_y036_p12.html", "shift_y036_pm12.html"]
    before = {n: (replay / n).read_bytes() for n in shifts}
    html = validate("--plot-take", "neutral")
    assert sorted(p.name for p in replay.glob("*.html")) == sorted(shifts + ["neutral.html"])
    assert all((replay / n).read_bytes() == data for n, data in before.items())
    assert 'href="replay/session01/neutral.html"' in html and "shift_y000_p12.html" not in html
    html = validate("--no-plots")
    assert sorted(p.name for p in replay.glob("*.html")) == sorted(shifts + ["neutral.html"])
    assert all(f'href="replay/session01/{n}"' in html for n in shifts + ["neutral.html"])
    # a take whose outputs are gone (or changed): its page, a view of what is no longer there, goes
    layout = open_output(out)
    shutil.rmtree(layout.take_dir("session01", "shift_y036_pm12"))
    shutil.rmtree(layout.record("session01", "shift_y036_pm12", "x").parent)
    validate("--plot-take", "neutral")
    assert sorted(p.name for p in replay.glob("*.html")) == ["neutral.html", "shift_y000_p12.html",
                                                             "shift_y036_p12.html"]


def test_per_frame_selection_is_each_rows_flatnonzero() -> None:
    from gazepipe.report.replay_page import _per_frame

    rng = np.random.default_rng(3)
    mask = rng.random((40, 7)) < 0.3
    mask[5] = False                                         # a frame with nothing to show
    mask[-1] = False
    got = _per_frame(mask)
    assert len(got) == 40 and all(np.array_equal(g, np.flatnonzero(m)) for g, m in zip(got, mask, strict=True))
    assert [g.size for g in _per_frame(np.zeros((3, 0), bool))] == [0, 0, 0]
