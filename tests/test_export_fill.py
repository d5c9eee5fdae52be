"""`gazepipe export` and `gazepipe fill`: files users open in their own viewers."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.io.c3d import read_c3d
from gazepipe.io.capture import read_markers
from gazepipe.io.export import write_markers
from gazepipe.io.session_toml import load_session
from gazepipe.model import FILL_CODES
from gazepipe.schemas.markers import table_to_markers
from tests.helpers import CORPUS, SAMPLE


def invoke(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


@pytest.fixture
def cleaned(sample_run) -> Path:
    """An output folder with the sample session's cleaned takes: the shared run of the whole pipeline (which
    cleans every take as ``gazepipe clean`` does), read only."""
    return sample_run


def _exported(out: Path, take: str, dest: Path, *args: str) -> dict:
    """``gazepipe export OUT session01/TAKE --to DEST ARGS``: exit 0; its sidecar."""
    res = invoke("export", str(out), f"session01/{take}", "--to", str(dest), *args)
    assert res.exit_code == 0, res.stderr
    assert f"wrote {dest}" in res.stdout
    return json.loads(Path(f"{dest}.gazepipe.json").read_text())


def _cleaned_take(out: Path, take: str):
    """The cleaned markers table of a take: (markers, the capture rows they keep, fill codes)."""
    markers, frames, fill, _ = table_to_markers(pq.read_table(out / "takes" / "session01" / take / "markers.parquet"))
    return markers, frames, fill


def _ezc3d(path: Path) -> dict:
    """What ezc3d reads of a C3D: labels, (T, M, 3) points, (T, M) residuals, first frame, rate, parameters."""
    import ezc3d

    c = ezc3d.c3d(str(path))
    return {"labels": [s.strip() for s in c["parameters"]["POINT"]["LABELS"]["value"]],
            "xyz": c["data"]["points"][:3].transpose(2, 1, 0),
            "residual": c["data"]["meta_points"]["residuals"][0].T,
            "first_frame": c["header"]["points"]["first_frame"] + 1,
            "rate": float(c["parameters"]["POINT"]["RATE"]["value"][0]), "params": c["parameters"]}


def _check_back_to_the_capture(out: Path, session: Path, take: str, dest: Path) -> None:
    """The acceptance of `gazepipe export` (issue 46): the exported C3D, read by ezc3d and by the `c3d` package,
    holds every measured sample of the raw capture to 1e-6 mm (ezc3d's reading of the capture file itself),
    every filled sample marked (residual 0 in both readers, listed in the sidecar, and nothing else at 0), the
    crop in its events and parameters, and the filled samples in the lab frame (the cleaned table's positions
    moved by the capture's own root marker)."""
    side = _exported(out, take, dest)
    got, src = _ezc3d(dest), _ezc3d(session / "mocap" / f"{take}.c3d")
    raw = read_c3d(session / "mocap" / f"{take}.c3d")        # which samples the capture measured
    clean, frames, fill = _cleaned_take(out, take)
    assert got["labels"] == src["labels"] == raw.labels
    assert got["first_frame"] == src["first_frame"] == raw.first_frame
    assert abs(got["rate"] - raw.rate_hz) < 1e-4 and got["xyz"].shape == src["xyz"].shape   # the whole take
    # measured: every sample the capture measured and the cleaning kept as measured, as the capture has it
    code = np.full(raw.valid.shape, FILL_CODES["measured"], np.int8)
    code[frames] = fill
    measured = raw.valid & (code == FILL_CODES["measured"])
    assert np.abs(got["xyz"][measured] - src["xyz"][measured]).max() <= 1e-6
    # filled: the fill codes of the cleaned table, residual 0 in both readers and listed; measured ones > 0
    filled = np.isin(code, [FILL_CODES[k] for k in ("linear", "pchip", "rigid", "pca")]) & (code != 0)
    filled[np.setdiff1d(np.arange(raw.n_frames), frames)] = False
    assert filled.any() and (got["residual"][filled] == 0).all()
    written = np.isfinite(got["residual"]) & (got["residual"] >= 0)
    assert (got["residual"][written & ~filled] > 0).all()
    listed = np.zeros_like(filled)
    for label, runs in side["filled"].items():
        for first, last, method in runs:
            rows = np.arange(first, last + 1) - raw.first_frame
            listed[rows, raw.labels.index(label)] = True
            assert (code[rows, raw.labels.index(label)] == FILL_CODES[method]).all()
    np.testing.assert_array_equal(listed, filled)
    py = _read_with_py_c3d(dest)
    assert py.labels == raw.labels and py.first_frame == raw.first_frame
    np.testing.assert_array_equal(py.residual[filled], 0.0)
    assert (py.residual[written & ~filled] > 0).all()
    np.testing.assert_allclose(py.xyz[measured], src["xyz"][measured], rtol=0, atol=1e-6)
    # the crop: the events, GAZEPIPE:CROP and the sidecar name the first and last kept frame
    first, last = raw.first_frame + frames[0], raw.first_frame + frames[-1]
    ev = got["params"]["EVENT"]
    times = dict(zip(ev["LABELS"]["value"], ev["TIMES"]["value"][0] * 60 + ev["TIMES"]["value"][1], strict=True))
    assert round(times["gazepipe crop start"] * raw.rate_hz) + 1 == first
    assert round(times["gazepipe crop end"] * raw.rate_hz) + 1 == last
    assert list(got["params"]["GAZEPIPE"]["CROP"]["value"]) == [first, last]
    assert (side["crop"]["first"], side["crop"]["last"]) == (first, last)
    # the lab frame: a filled sample is the cleaned one moved as the frame's measured markers moved (by the root
    # marker's position, where it was measured)
    rows, cols = np.nonzero(filled)
    k = np.searchsorted(frames, rows)
    both = raw.valid[frames] & (fill == FILL_CODES["measured"])
    assert both[k].any(axis=1).all()
    ref = np.argmax(both[k], axis=1)                          # a marker measured in both, in each filled frame
    moved = clean.xyz[k, cols] + raw.xyz[rows, ref] - clean.xyz[k, ref]
    np.testing.assert_allclose(got["xyz"][rows, cols], moved, rtol=0, atol=2e-3)
    root = raw.labels.index(load_session(session / "session.toml").markerset.root)
    at_root = raw.valid[rows, root] & (fill[k, root] == FILL_CODES["measured"])   # not a ghost the cleaning filled
    assert at_root.sum() >= 50
    np.testing.assert_allclose(got["xyz"][rows, cols][at_root], clean.xyz[k, cols][at_root]
                               + raw.xyz[rows, root][at_root], rtol=0, atol=2e-3)
    truth = np.load(session / "truth" / f"{take}.npz")["markers_true"]
    err = np.linalg.norm(got["xyz"][filled] - truth[filled], axis=-1)
    assert err.mean() < 3.0, err.mean()    # the fills' own error (estimated within 5 mm), not a frame's offset


def test_export_brings_a_cleaned_take_back_to_the_capture(cleaned, tmp_path):
    _check_back_to_the_capture(cleaned, SAMPLE, "follow_sitting_01", tmp_path / "t.c3d")


@pytest.fixture(scope="module")
def four_segment_run(tmp_path_factory) -> tuple[Path, Path]:
    """A y-up session on the four-segment markerset with label swaps, occlusion bursts and ghost spikes, cleaned
    (`gazepipe clean`): (session folder, output folder)."""
    from gazepipe.synth import SynthConfig, generate_session
    from gazepipe.synth.skeleton import FOUR_SEGMENTS

    root = tmp_path_factory.mktemp("export4")
    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=25.0, head_camera=False, face_takes=(),
                      shift_targets=((36.0, 12.0),), segments=FOUR_SEGMENTS, up_axis="y", label_swaps=2,
                      occlusion_bursts=2, spikes_per_marker_min=2.0)
    session = generate_session(root / "s", seed=3, config=cfg)
    res = invoke("clean", str(session), "--out", str(root / "out"), "--executor", "serial", "--log-format", "json")
    assert res.exit_code == 0, res.output[-2000:]
    return session, root / "out"


def test_export_brings_a_y_up_four_segment_take_back_with_its_repaired_swaps(four_segment_run, tmp_path):
    """The same on the y-up four-segment layout; a sample put back under its own name is the capture's sample of
    the marker that carried it (its position there to float precision, against the truth within the noise)."""
    session, out = four_segment_run
    take = "follow_standing_01"
    dest = tmp_path / "t.c3d"
    _check_back_to_the_capture(out, session, take, dest)
    raw, got = read_c3d(session / "mocap" / f"{take}.c3d"), read_c3d(dest)
    _, frames, fill = _cleaned_take(out, take)
    swapped = np.zeros(raw.valid.shape, bool)
    swapped[frames] = fill == FILL_CODES["swap_repaired"]
    assert swapped.sum() >= 20
    rows, cols = np.nonzero(swapped)
    d = np.linalg.norm(raw.xyz[rows] - got.xyz[rows, cols][:, None, :], axis=-1)      # (n, M)
    assert (np.nanmin(d, axis=1) == 0).all()
    truth = np.load(session / "truth" / f"{take}.npz")["markers_true"]
    assert np.linalg.norm(got.xyz[swapped] - truth[swapped], axis=-1).max() < 5.0   # noise 0.5 mm a coordinate


def test_export_stabilised_is_the_cleaned_table_inside_the_crop(four_segment_run, tmp_path):
    session, out = four_segment_run
    take = "follow_standing_01"
    side = _exported(out, take, tmp_path / "s.c3d", "--frame", "stabilised")
    assert side["frame"] == "stabilised"
    clean, frames, _ = _cleaned_take(out, take)
    got = read_c3d(tmp_path / "s.c3d")
    np.testing.assert_array_equal(got.valid[frames], clean.valid)
    np.testing.assert_array_equal(got.xyz[frames][clean.valid], clean.xyz[clean.valid])   # float32 both ways
    raw = read_c3d(session / "mocap" / f"{take}.c3d")
    root = raw.labels.index(load_session(session / "session.toml").markerset.root)
    before = np.arange(frames[0])
    ok = raw.valid[before] & raw.valid[before, root][:, None]
    moved = raw.xyz[before] - raw.xyz[before, root][:, None, :]
    np.testing.assert_allclose(got.xyz[before][ok], moved[ok], rtol=0, atol=1e-3)


@pytest.mark.parametrize("fmt, name", [("nexus", "t.csv"), ("qtm", "t.tsv"), ("wide", "w.csv")])
def test_export_text_formats_read_back_by_gazepipe_and_pandas(cleaned, tmp_path, fmt, name):
    """Nexus CSV, QTM TSV and wide CSV of the same take: gazepipe reads each back as the C3D export (the C3D's
    float32 apart), pandas reads the rows with the column layout the README gives, and the QTM TSV carries the
    crop as EVENT lines."""
    import pandas as pd

    from gazepipe.io.export_text import qtm_header_lines
    from gazepipe.io.limits import exact_floats

    exact = exact_floats()      # pandas before 3.1 may parse a float one unit in the last place off without it

    take = "follow_standing_03"
    side_c3d = _exported(cleaned, take, tmp_path / "t.c3d")
    side = _exported(cleaned, take, tmp_path / name, "--format", fmt)
    assert side["filled"] == side_c3d["filled"] and side["crop"] == side_c3d["crop"] and side["format"] == fmt
    ref, back = read_c3d(tmp_path / "t.c3d"), read_markers(tmp_path / name)
    assert back.labels == ref.labels and back.first_frame == ref.first_frame
    assert abs(back.rate_hz - ref.rate_hz) < 1e-9
    np.testing.assert_array_equal(back.valid, ref.valid)
    np.testing.assert_allclose(back.xyz[back.valid], ref.xyz[ref.valid], rtol=1e-7, atol=0)
    measured = _ezc3d(tmp_path / "t.c3d")["residual"] > 0
    assert np.array_equal(back.xyz[measured], read_c3d(SAMPLE / "mocap" / f"{take}.c3d").xyz[measured])
    if fmt == "nexus":
        df = pd.read_csv(tmp_path / name, skiprows=[0, 1, 2, 4], **exact)
        x = df[["X", "Y", "Z"]].to_numpy()
    elif fmt == "qtm":
        df = pd.read_csv(tmp_path / name, sep="\t", skiprows=qtm_header_lines(tmp_path / name), **exact)
        x = df[[f"{ref.labels[0]} {a}" for a in "XYZ"]].to_numpy()
        events = [ln.split("\t") for ln in (tmp_path / name).read_text().splitlines() if ln.startswith("EVENT\t")]
        assert [int(e[2]) for e in events] == [side["crop"]["first"], side["crop"]["last"]]
    else:
        df = pd.read_csv(tmp_path / name, **exact)
        x = df[[f"{ref.labels[0]}_{a}" for a in "xyz"]].to_numpy()
    assert len(df) == ref.n_frames
    np.testing.assert_array_equal(np.isfinite(x).all(axis=1), back.valid[:, 0])
    np.testing.assert_array_equal(x[back.valid[:, 0]], back.xyz[back.valid[:, 0], 0])


def test_export_without_the_capture_file_falls_back_to_the_table(cleaned, tmp_path):
    """An output folder copied away from its session (no capture file to read again): measured samples are the
    markers_raw table's (float32: exact for this float C3D), residuals stand-ins, and the command says so."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(cleaned / "takes" / "session01" / "neutral", out / "takes" / "session01" / "neutral")
    res = invoke("export", str(out), "neutral", "--to", str(tmp_path / "n.c3d"))
    assert res.exit_code == 0, res.stderr
    assert "capture file not read again" in res.stdout
    side = json.loads((tmp_path / "n.c3d.gazepipe.json").read_text())
    assert side["measured_values"].startswith("markers_raw") and side["residuals"]["stand_in_mm"] == 0.01
    raw, got = read_c3d(SAMPLE / "mocap" / "neutral.c3d"), _ezc3d(tmp_path / "n.c3d")
    both = raw.valid & (got["residual"] > 0)
    assert both.sum() >= 0.9 * raw.valid.sum()
    np.testing.assert_array_equal(got["xyz"][both], raw.xyz[both])


def test_export_accepts_session_slash_take_and_refuses_a_path(cleaned, tmp_path):
    """`export` takes SESSION/TAKE as `view` and `status` name takes; an id that is not one (a path climbing
    out of OUT) is refused before any path is made from it."""
    res = invoke("export", str(cleaned), "session01/shift_y036_p12", "--to", str(tmp_path / "a.c3d"))
    assert res.exit_code == 0, res.stderr
    res = invoke("export", str(cleaned), "shift_y036_p12", "--session", "session01", "--to", str(tmp_path / "b.c3d"))
    assert res.exit_code == 0, res.stderr
    assert (tmp_path / "a.c3d").read_bytes() == (tmp_path / "b.c3d").read_bytes()
    for bad in ("session01/../../x", "../session01/neutral", "session01/neutral/x"):
        res = invoke("export", str(cleaned), bad, "--to", str(tmp_path / "c.c3d"))
        assert res.exit_code == 2 and "not a" in res.stderr and "Traceback" not in res.stderr, bad
        assert len(res.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "c.c3d").exists()


def test_export_unknown_take_is_one_line(cleaned, tmp_path):
    res = invoke("export", str(cleaned), "nope", "--to", str(tmp_path / "x.c3d"))
    assert res.exit_code == 2 and "nope" in res.stderr and "Traceback" not in res.stderr


def test_export_of_a_face_take_says_it_has_no_markers(tmp_path):
    out = tmp_path / "out"
    (out / "takes" / "s1" / "face_01").mkdir(parents=True)
    (out / "takes" / "s1" / "face_01" / "face.parquet").write_bytes(b"")  # only its existence is looked at
    res = invoke("export", str(out), "face_01", "--to", str(tmp_path / "f.csv"))
    assert res.exit_code == 2 and "face take" in res.stderr and not (tmp_path / "f.csv").exists()


def test_export_to_a_missing_folder_is_a_usage_error(cleaned, tmp_path):
    res = invoke("export", str(cleaned), "neutral", "--to", str(tmp_path / "nodir" / "x.csv"))
    assert res.exit_code == 2 and "does not exist" in res.stderr
    assert not (tmp_path / "nodir").exists()


def _read_with_py_c3d(path: Path) -> SimpleNamespace:
    """Decode with the pure-Python `c3d` reader, independently of gazepipe's reader: labels, first frame,
    (T, M, 3) positions (NaN at gaps), (T, M) residuals (the package's: the low byte times |POINT:SCALE|)."""
    import warnings

    import c3d as pyc3d

    with open(path, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")       # "no analog data"
        reader = pyc3d.Reader(fh)
        labels = [s.strip() for s in reader.point_labels]
        pts = np.stack([p for _, p, _ in reader.read_frames()])
        first = reader.first_frame
    valid = pts[:, :, 3] >= 0
    return SimpleNamespace(labels=labels, first_frame=first, residual=pts[:, :, 3],
                           xyz=np.where(valid[..., None], pts[:, :, :3], np.nan))


def _walking_truth():
    """Walking_Hybrid_2 as read, and its gap-free distinct trajectories (T, M, 3) mm with their labels
    (PROVENANCE: each trajectory is stored 2-3 times bit for bit; the copies are dropped)."""
    src = read_c3d(CORPUS / "c3d" / "Walking_Hybrid_2.c3d")
    _, keep = np.unique(np.nan_to_num(src.xyz).transpose(1, 0, 2).reshape(src.n_markers, -1), axis=0,
                        return_index=True)
    keep = np.sort(keep)
    keep = keep[src.valid[:, keep].all(axis=0)]
    return src, src.xyz[:, keep], [src.labels[i] for i in keep]


def _six_gaps(shape: tuple[int, int], seed: int) -> np.ndarray:
    """A (T, M) valid mask with 24-frame gaps (0.1 s at 240 Hz) in six random markers."""
    valid = np.ones(shape, bool)
    rng = np.random.default_rng(seed)
    for m in rng.choice(shape[1], 6, replace=False):
        start = int(rng.integers(30, shape[0] - 60))
        valid[start:start + 24, m] = False
    return valid


def test_fill_command_fills_hidden_samples_of_real_data(tmp_path):
    """Hide samples of a gap-free real capture, fill with the stand-alone filler, compare with the truth."""
    src, truth, labels = _walking_truth()
    valid = _six_gaps(truth.shape[:2], seed=3)
    from gazepipe.model import Markers
    holed = Markers(labels=labels, xyz=np.where(valid[..., None], truth, np.nan), valid=valid,
                    rate_hz=src.rate_hz, first_frame=src.first_frame)
    inp, out = tmp_path / "in.c3d", tmp_path / "out.c3d"
    write_markers(inp, holed)
    res = invoke("fill", str(inp), str(out), "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["gaps"]["total"] == 6 and summary["gaps"]["filled"] == 6
    back = read_c3d(out)
    assert back.valid.all()
    err = np.linalg.norm(back.xyz[~valid] - truth[~valid], axis=-1)
    assert err.mean() < 10.0          # 0.1 s gaps in gait at 240 Hz: a few mm expected; 10 mm is a loose bound
    np.testing.assert_allclose(back.xyz[valid], truth[valid], atol=5e-4)  # measured samples untouched (float32)


def test_fill_refuses_a_different_output_format(tmp_path):
    res = invoke("fill", str(CORPUS / "c3d" / "gait-raw.c3d"), str(tmp_path / "x.csv"))
    assert res.exit_code == 2 and "x.csv" in res.stderr


def _sample_blocks(path: Path, samples: np.ndarray) -> np.ndarray:
    """Byte offsets of the four point words of each (frame, point) in ``samples`` (n, 2) of a C3D file."""
    from gazepipe.io.c3d_meta import parse_c3d_meta

    data = path.read_bytes()
    lay = parse_c3d_meta(data).layout(len(data))
    start = lay.data_offset + (samples[:, 0] * lay.frame_words + 4 * samples[:, 1]) * lay.word_bytes
    return (start[:, None] + np.arange(4 * lay.word_bytes)).ravel()


@pytest.mark.parametrize("name", ["gait-raw", "Eb015pr", "Eb015si", "Walking_Hybrid_2"])
def test_fill_c3d_changes_only_the_filled_samples(name, tmp_path):
    """Integer/DEC, DEC float, MIPS float and Intel float files: the output is the input with the filled samples'
    words rewritten and nothing else (analog data, parameters, model outputs, residuals kept byte for byte); the
    filled positions read back as the filler computed them, to the file's storage precision."""
    from gazepipe.io.c3d import read_c3d_info
    from gazepipe.stages.clean.standalone import fill_capture

    src, out = CORPUS / "c3d" / f"{name}.c3d", tmp_path / f"{name}.c3d"
    res = invoke("fill", str(src), str(out))
    assert res.exit_code == 0, res.stderr
    before, after = src.read_bytes(), out.read_bytes()
    assert len(before) == len(after)
    m0, info = read_c3d_info(src)
    m1 = read_c3d(out)
    new = m1.valid & ~m0.valid
    assert new.any()
    expected, _, _ = fill_capture(m0)
    np.testing.assert_array_equal(m1.valid, expected.valid)
    assert np.array_equal(m1.xyz[m0.valid], m0.xyz[m0.valid])  # measured samples bit for bit
    # storage precision: float32 (relative), or the integer scale (half a step)
    if info["storage"] == "float":
        tol = 1e-6 * np.abs(expected.xyz[new]) + 1e-4
    else:
        from gazepipe.io.c3d_meta import parse_c3d_meta

        tol = 0.5 * abs(parse_c3d_meta(before).layout(len(before)).scale) + 1e-6
    assert (np.abs(m1.xyz[new] - expected.xyz[new]) <= tol).all()
    assert not m0.model_outputs  # so marker i is point i of the file
    changed = np.flatnonzero(np.frombuffer(before, np.uint8) != np.frombuffer(after, np.uint8))
    t, m = np.nonzero(new)
    allowed = _sample_blocks(src, np.stack([t, m], axis=1))
    assert np.isin(changed, allowed).all()


def test_fill_never_keeps_an_implausibly_fast_fill(tmp_path):
    """At the end of Walking_Hybrid_2 the whole right leg is hidden; PCA from the other markers moved a toe
    marker 256 mm in one frame (60 m/s). No filled step may exceed the limit the filler states."""
    from gazepipe.stages.clean.gapfill import step_limits

    src = CORPUS / "c3d" / "Walking_Hybrid_2.c3d"
    out = tmp_path / "w.c3d"
    res = invoke("fill", str(src), str(out), "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    m0, m1 = read_c3d(src), read_c3d(out)
    limits = step_limits(m0.xyz, m0.valid)
    steps = np.linalg.norm(np.diff(m1.xyz, axis=0), axis=2)
    touched = (m1.valid & ~m0.valid)
    near_fill = (touched[1:] | touched[:-1]) & m1.valid[1:] & m1.valid[:-1]
    assert near_fill.any()
    assert (steps[near_fill] <= np.broadcast_to(limits, steps.shape)[near_fill]).all()
    gaps = summary["gap_list"]
    implausible = [g for g in gaps if g["reason"] == "every fill implausibly fast"]
    assert implausible and all(g["method"] == "unfilled" and g["at_edge"] for g in implausible)
    assert summary["unfilled_reasons"]["every fill implausibly fast"] == len(implausible)
    assert summary["gaps"]["edge_filled"] == sum(g["at_edge"] and g["method"] != "unfilled" for g in gaps)
    assert len(gaps) == summary["gaps"]["total"]
    text = invoke("fill", str(src), str(tmp_path / "x.c3d")).stdout
    assert "at the file's start or end" in text
    assert "warning: 25 groups of bit-identical trajectories" in text  # what inspect says, fill says too
    assert any("bit-identical" in w for w in summary["warnings"])


@pytest.mark.parametrize("path", sorted((CORPUS / "c3d").glob("*.c3d")), ids=lambda p: p.stem)
def test_fill_on_every_real_c3d_keeps_to_what_it_can_show(path, tmp_path):
    """``gazepipe fill`` on each real C3D of the corpus, as it comes: every filled gap has an error estimate
    (the others stay gaps, counted by reason in the summary, and the text says why); no step into, across or
    out of a fill is faster than the fastest step measured in the file (spikes left out: the summary's, at
    most the raw fastest); no unlabeled trajectory is filled by default; what the file says is what it wrote."""
    from gazepipe.stages.clean.gapfill import unlabeled_markers

    out = tmp_path / path.name
    res = invoke("fill", str(path), str(out), "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    gaps = summary["gap_list"]
    filled = [g for g in gaps if g["method"] != "unfilled"]
    assert all(g["error_mm"] is not None for g in filled), [g for g in filled if g["error_mm"] is None][:3]
    left = [g for g in gaps if g["method"] == "unfilled"]
    assert summary["gaps"]["unfilled"] == len(left)
    assert {k: v["gaps"] for k, v in summary["unfilled_by_reason"].items()} == summary["unfilled_reasons"]
    assert sum(v["samples"] for v in summary["unfilled_by_reason"].values()) == sum(g["frames"] for g in left)
    m0, m1 = read_c3d(path), read_c3d(out)
    new = m1.valid & ~m0.valid
    assert new.sum() == sum(g["frames"] for g in filled) - summary.get("samples_written_as_gaps", 0)
    steps = np.linalg.norm(np.diff(m1.xyz, axis=0), axis=2)
    near = (new[1:] | new[:-1]) & m1.valid[1:] & m1.valid[:-1]
    measured = m0.valid[1:] & m0.valid[:-1]
    fastest = summary["fastest_measured_step_mm"]
    raw = np.linalg.norm(np.diff(np.where(m0.valid[..., None], m0.xyz, 0.0), axis=0), axis=2)
    assert fastest <= (raw[measured].max() if measured.any() else 0.0) + 1e-9
    # (float32 or integer storage may move a written sample by a fraction of a millimetre)
    assert not near.any() or steps[near].max() <= fastest + 0.01, (steps[near].max(), fastest)
    assert not new[:, unlabeled_markers(m0.labels)].any()


def test_fill_text_says_what_stayed_unfilled_and_why(tmp_path):
    """A trajectory seen only every eighth frame for a while, alone in its file: nothing can be hidden beside
    its gaps, nor seen through them, to check a fill on, so they stay gaps; the text summary counts them, with
    their samples and the reason, as the JSON does."""
    from gazepipe.model import Markers
    from gazepipe.stages.clean.gapfill import REASON_NO_ESTIMATE

    src, truth, labels = _walking_truth()
    valid = np.ones((truth.shape[0], 1), bool)
    valid[100:300:8] = False
    valid[100:300] = ~valid[100:300]           # measured every eighth frame from 100 to 300
    inp = tmp_path / "in.c3d"
    write_markers(inp, Markers(labels=labels[:1], xyz=np.where(valid[..., None], truth[:, :1], np.nan),
                               valid=valid, rate_hz=src.rate_hz, first_frame=src.first_frame))
    summary = json.loads(invoke("fill", str(inp), str(tmp_path / "a.c3d"), "--json").stdout)
    # 25 gaps of 7 frames; the first and the last have the measured take beside them to hide and are filled
    assert summary["unfilled_by_reason"] == {REASON_NO_ESTIMATE: {"gaps": 23, "samples": 161}}
    assert summary["gaps"]["filled"] == 2
    assert [g["first_frame"] - src.first_frame for g in summary["gap_list"] if g["method"] != "unfilled"] == [101, 293]
    text = invoke("fill", str(inp), str(tmp_path / "b.c3d")).stdout
    assert f"left as gaps: 23 gap(s), 161 samples: {REASON_NO_ESTIMATE}" in text


def test_fill_leaves_unlabeled_trajectories_unless_asked(tmp_path):
    """Trajectories named as labellers name what they could not label (Vicon ``*12``, ``Unlabeled 3``, with a
    subject prefix) keep their gaps, and the summary and the text say so; ``--fill-unlabeled`` fills them too.
    The others are filled either way."""
    from gazepipe.model import Markers
    from gazepipe.stages.clean.gapfill import unlabeled_markers

    src, truth, labels = _walking_truth()
    valid = _six_gaps(truth.shape[:2], seed=5)
    holed_cols = np.flatnonzero(~valid.all(axis=0))
    names = list(labels)
    for k, new_name in zip(holed_cols[:3], ("*12", "Unlabeled 3", "Subject:*155"), strict=True):
        names[k] = new_name
    assert unlabeled_markers(names) == sorted(holed_cols[:3].tolist())
    inp = tmp_path / "in.c3d"
    write_markers(inp, Markers(labels=names, xyz=np.where(valid[..., None], truth, np.nan), valid=valid,
                               rate_hz=src.rate_hz, first_frame=src.first_frame))
    res = invoke("fill", str(inp), str(tmp_path / "out.c3d"), "--json")
    summary = json.loads(res.stdout)
    assert summary["unlabeled"] == {"markers": ["*12", "Unlabeled 3", "Subject:*155"], "filled": False}
    back = read_c3d(tmp_path / "out.c3d")
    assert not back.valid[:, holed_cols[:3]].all(axis=0).any() and back.valid[:, holed_cols[3:]].all()
    assert summary["unfilled_reasons"] == {"an unlabeled trajectory (filled only when asked)": 3}
    assert "3 unlabeled trajectories left as they are" in invoke("fill", str(inp), str(tmp_path / "t.c3d")).stdout
    res = invoke("fill", str(inp), str(tmp_path / "all.c3d"), "--fill-unlabeled", "--json")
    assert json.loads(res.stdout)["unlabeled"]["filled"] is True
    assert read_c3d(tmp_path / "all.c3d").valid.all()


def test_plausible_fill_falls_back_then_gives_up():
    """The blend is kept when smooth; a jumping first choice gives way to the next method by validation error;
    with every method jumping the gap stays unfilled."""
    from gazepipe.stages.clean.gapfill import REASON_IMPLAUSIBLE, _plausible_fill

    t = np.arange(40, dtype=float)
    xyz = np.stack([t, 0 * t, 0 * t], axis=1)  # 1 mm per frame
    xyz[10:20] = np.nan
    smooth = np.stack([np.arange(10, 20.0), np.zeros(10), np.zeros(10)], axis=1)
    jump = smooth.copy()
    jump[5, 0] += 50.0
    methods = ("rigid", "pca", "pchip", "linear")
    w, fill, note = _plausible_fill(xyz, 10, 20, {"pca": smooth}, {"pca": 1.0}, {"pca": 1.0}, methods, 3.0)
    assert fill is smooth and note == ""
    errors = {"pca": 0.5, "pchip": 2.0, "linear": 1.0}
    preds = {"pca": jump, "pchip": smooth + 0.1, "linear": smooth}
    w, fill, note = _plausible_fill(xyz, 10, 20, preds, {"pca": 1.0}, errors, methods, 3.0)
    assert w == {"linear": 1.0} and fill is preds["linear"] and "linear used" in note
    w, fill, note = _plausible_fill(xyz, 10, 20, {"pca": jump}, {"pca": 1.0}, {"pca": 0.5}, methods, 3.0)
    assert fill is None and note == REASON_IMPLAUSIBLE


def test_step_limits_cover_a_still_marker_with_the_fastest_markers_steps_and_no_more():
    """A still marker may be filled moving as fast as the fastest marker was measured to move, never faster:
    the capture's fastest measured step caps every marker's limit (2.5 x its own 99th percentile, 1.5 x the
    largest one, and a step of the fast marker that is its fastest by far)."""
    from gazepipe.stages.clean.gapfill import fastest_step, step_limits

    t = np.arange(100, dtype=float)
    fast = np.stack([10.0 * t, 0 * t, 0 * t], axis=1)   # 10 mm per frame
    still = np.zeros((100, 3)) + 5.0
    slow = np.stack([2.0 * t, 0 * t, 0 * t], axis=1)    # 2 mm per frame
    xyz = np.stack([fast, still, slow], axis=1)
    valid = np.ones((100, 3), bool)
    np.testing.assert_allclose(step_limits(xyz, valid), [10.0, 10.0, 10.0])
    xyz[50:, 0, 0] += 12.0                              # one 22 mm step: the fastest measured
    p99 = np.percentile(np.r_[np.full(98, 10.0), 22.0], 99)
    np.testing.assert_allclose(step_limits(xyz, valid), [22.0, 1.5 * p99, 1.5 * p99])
    assert fastest_step(xyz, valid) == 22.0
    valid[50, 0] = False                                # the step is not measured: the cap falls back
    assert fastest_step(xyz, valid) == 10.0 and step_limits(xyz, valid).max() == 10.0


def test_fill_refuses_to_overwrite_its_input_or_write_into_a_missing_folder(tmp_path):
    src = tmp_path / "in.c3d"
    src.write_bytes((CORPUS / "c3d" / "gait-raw.c3d").read_bytes())
    res = invoke("fill", str(src), str(src))
    assert res.exit_code == 2 and "input file" in res.stderr
    assert src.read_bytes() == (CORPUS / "c3d" / "gait-raw.c3d").read_bytes()
    res = invoke("fill", str(src), str(tmp_path / "nodir" / "out.c3d"))
    assert res.exit_code == 2 and "does not exist" in res.stderr and not (tmp_path / "nodir").exists()


def test_status_compares_with_the_parameters_given(cleaned, tmp_path):
    res = invoke("status", str(cleaned), "--json")
    assert res.exit_code == 0
    rows = json.loads(res.stdout)["units"]
    assert rows and not any(r["state"] == "stale" for r in rows if r["stage"] == "clean")
    rows = json.loads(invoke("status", str(cleaned), "--json", "--param", "clean.max_gap_s=0.5").stdout)["units"]
    stale = [r for r in rows if r["stage"] == "clean" and r["state"] == "stale"]
    assert stale and all("param" in r["detail"] for r in stale)
    res = invoke("status", str(tmp_path))
    assert res.exit_code == 2 and "not a gazepipe output folder" in res.stderr


@pytest.mark.parametrize("path, what", [("openface/pyfeat_OpenFace_Test.csv", "OpenFace"),
                                        ("livelinkface/alex_rom_3_first300.csv", "Live Link Face")])
def test_fill_names_eye_and_face_tracks_instead_of_misreading_them(path, what, tmp_path):
    res = invoke("fill", str(CORPUS / path), str(tmp_path / "out.csv"))
    assert res.exit_code == 1 and what in res.stderr and "not a marker capture" in res.stderr
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("ext", [".c3d", ".csv"])
def test_fill_remove_spikes_replaces_a_spike_only_when_asked(ext, tmp_path):
    """A 300 mm one-frame spike in a gap-free real trajectory: counted, with the file's own glitches, and kept by
    default; with --remove-spikes it becomes a gap and is filled near the truth, and only the samples counted as
    spikes change."""
    from gazepipe.model import Markers

    src, truth, labels = _walking_truth()
    clean_in = tmp_path / f"clean{ext}"
    write_markers(clean_in, Markers(labels=labels, xyz=truth, valid=np.ones(truth.shape[:2], bool),
                                    rate_hz=src.rate_hz, first_frame=src.first_frame))
    res = invoke("fill", str(clean_in), str(tmp_path / f"clean_out{ext}"), "--json")
    own = json.loads(res.stdout)["spikes"]       # the capture's own one-frame glitches (foot markers at rest)
    spiked = truth.copy()
    spiked[200, 3, 2] += 300.0
    m = Markers(labels=labels, xyz=spiked, valid=np.ones(truth.shape[:2], bool),
                rate_hz=src.rate_hz, first_frame=src.first_frame)
    inp = tmp_path / f"in{ext}"
    write_markers(inp, m)
    res = invoke("fill", str(inp), str(tmp_path / f"kept{ext}"), "--json")
    assert res.exit_code == 0, res.stderr
    got = json.loads(res.stdout)["spikes"]
    assert got["samples"] == own["samples"] + 1 and got["removed"] is False
    assert got["per_marker"][m.labels[3]] == own["per_marker"].get(m.labels[3], 0) + 1
    if ext == ".c3d":
        assert (tmp_path / f"kept{ext}").read_bytes() == inp.read_bytes()
    np.testing.assert_allclose(read_markers(tmp_path / f"kept{ext}").xyz, read_markers(inp).xyz)
    res = invoke("fill", str(inp), str(tmp_path / f"out{ext}"), "--remove-spikes")
    assert res.exit_code == 0, res.stderr
    assert "turned into gaps before filling" in res.stdout
    back, before = read_markers(tmp_path / f"out{ext}"), read_markers(inp)
    assert back.valid.all()
    assert np.linalg.norm(back.xyz[200, 3] - truth[200, 3]) < 5.0   # was 300 mm off
    changed = (back.xyz != before.xyz).any(axis=2)
    assert changed[200, 3] and changed.sum() == got["samples"]


def test_fill_writes_a_position_its_integer_c3d_cannot_hold_as_a_gap(tmp_path):
    """ART-Human stores 16-bit integers at 0.049 mm (±1605 mm): the head marker's refilled corrupt stretch lies
    above that, so it is written as gaps, said in a warning, and the file stays readable."""
    src, out = CORPUS / "c3d" / "ART-Human_2persons_integer.c3d", tmp_path / "a.c3d"
    res = invoke("fill", str(src), str(out), "--remove-spikes", "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["samples_written_as_gaps"] == summary["spikes"]["per_marker"]["Human1:HEADZ"] == 10
    assert any("16-bit integer range" in w for w in summary["warnings"])
    m0, m1 = read_c3d(src), read_c3d(out)
    gone = m0.valid & ~m1.valid
    assert gone.sum() == 10 and (m1.valid | gone).all()
    # the other spikes are filled within range (a fill within the storage step of the sample reads back as it);
    # nothing else changes
    refilled = m1.valid & (m1.xyz != m0.xyz).any(axis=2)
    assert 1 <= refilled.sum() <= summary["spikes"]["samples"] - 10


def _text_export(fmt: str, truth: np.ndarray, valid: np.ndarray, labels: list[str]) -> tuple[str, bytes]:
    """The Walking capture as a third-party text export with gaps: a Vicon Nexus CSV in metres with CRLF
    line ends and Devices and Model Outputs blocks around the trajectories; an older QTM TSV writing gaps as
    0.000; a wide CSV with an extra numeric column. Returns (file name, bytes)."""
    n_t, n_m, _ = truth.shape

    def cells(t: int, scale: float, dec: int, gap: str) -> list[str]:
        return [f"{truth[t, m, a] * scale:.{dec}f}" if valid[t, m] else gap for m in range(n_m) for a in range(3)]

    if fmt == "vicon":
        rows = ["Devices", "1000", ",,Plate - Force,,", "Frame,Sub Frame,Fx,Fy,Fz", ",,N,N,N", "330,0,0.1,0.2,0.3",
                "", "Trajectories", "240", ",," + ",".join(f"Sub:{lab},," for lab in labels),
                "Frame,Sub Frame," + ",".join("X,Y,Z" for _ in labels), ",," + ",".join("m,m,m" for _ in labels)]
        rows += [f"{330 + t},0," + ",".join(cells(t, 1e-3, 6, "")) for t in range(n_t)]
        rows += ["", "Model Outputs", "240", ",,Sub:LHipAngles,,", "Frame,Sub Frame,X,Y,Z", ",,deg,deg,deg",
                 "330,0,1,2,3", ""]
        return "v.csv", "\r\n".join(rows).encode()
    if fmt == "qtm":
        rows = [f"NO_OF_FRAMES\t{n_t}", "NO_OF_CAMERAS\t8", f"NO_OF_MARKERS\t{n_m}", "FREQUENCY\t240",
                "NO_OF_ANALOG\t0", "ANALOG_FREQUENCY\t0", "DESCRIPTION\t--", "TIME_STAMP\t2019-11-28, 13:43:42",
                "DATA_INCLUDED\t3D", "MARKER_NAMES\t" + "\t".join(labels),
                "Frame\tTime\t" + "\t".join(f"{lab} {a}" for lab in labels for a in "XYZ")]
        rows += [f"{t + 1}\t{t / 240:.5f}\t" + "\t".join(cells(t, 1.0, 3, "0.000")) for t in range(n_t)]
        return "q.tsv", ("\n".join(rows) + "\n").encode()
    rows = ["frame,time,cond," + ",".join(f"{lab}_{a}" for lab in labels for a in "xyz")]
    rows += [f"{t},{t / 240:.6f},1," + ",".join(cells(t, 1.0, 4, "")) for t in range(n_t)]
    return "w.csv", ("\n".join(rows) + "\n").encode()


@pytest.mark.parametrize(("fmt", "mm_per_unit", "decimals"), [("vicon", 1000.0, 6), ("qtm", 1.0, 3), ("wide", 1.0, 4)])
def test_fill_text_export_changes_only_the_filled_cells(fmt, mm_per_unit, decimals, tmp_path):
    """A Vicon CSV, a QTM TSV and a wide CSV come back in their own layout (extension, header, other blocks,
    units, decimals, line ends): only the data rows holding a filled sample differ, measured values read
    back bit for bit, and the filled values are the filler's own to the file's precision."""
    from gazepipe.stages.clean.standalone import fill_capture

    _, truth, labels = _walking_truth()
    valid = _six_gaps(truth.shape[:2], seed=4)
    name, data = _text_export(fmt, truth, valid, labels)
    inp, out = tmp_path / name, tmp_path / f"filled_{name}"
    inp.write_bytes(data)
    res = invoke("fill", str(inp), str(out), "--json")
    assert res.exit_code == 0, res.stderr
    gaps = json.loads(res.stdout)["gaps"]
    assert gaps["total"] == 6 and gaps["filled"] == 6
    before, after = data.split(b"\n"), out.read_bytes().split(b"\n")
    assert len(after) == len(before)
    changed = [i for i, (a, b) in enumerate(zip(before, after, strict=True)) if a != b]
    # the rows of frames with a gap, nothing else (header lines and other blocks come before or after them)
    first = before.index(b"Trajectories\r") + 5 if fmt == "vicon" else 11 if fmt == "qtm" else 1
    assert changed == (first + np.flatnonzero(~valid.all(axis=1))).tolist()
    assert all(b.endswith(b"\r") for b in after[first:first + truth.shape[0]]) == (fmt == "vicon")
    orig, back = read_markers(inp), read_markers(out)
    assert back.valid.all() and back.labels == orig.labels
    np.testing.assert_array_equal(back.xyz[valid], orig.xyz[valid])
    filled, _, _ = fill_capture(orig, spikes=False)     # the command's defaults
    step = mm_per_unit * 10.0 ** -decimals     # one unit in the last written decimal, mm
    np.testing.assert_allclose(back.xyz[~valid], filled.xyz[~valid], rtol=0, atol=0.5 * step + 1e-9)
    err = np.linalg.norm(back.xyz[~valid] - truth[~valid], axis=-1)
    assert err.mean() < 10.0          # 0.1 s gaps in gait at 240 Hz, as for the C3D above


def test_fill_keeps_the_input_extension(tmp_path):
    _, truth, labels = _walking_truth()
    name, data = _text_export("qtm", truth, np.ones(truth.shape[:2], bool), labels)
    (tmp_path / name).write_bytes(data)
    res = invoke("fill", str(tmp_path / name), str(tmp_path / "out.csv"))
    assert res.exit_code == 2 and "out.csv" in res.stderr and ".tsv" in res.stderr


def test_fill_counts_apart_what_it_fills_in_dropped_frames(tmp_path):
    """Frame numbers missing from a wide CSV become gap rows the filler fills, but the copy has no line for
    them: the summary says how many filled samples were not written, and the copy keeps its lines."""
    _, truth, labels = _walking_truth()
    valid = np.ones(truth.shape[:2], bool)
    name, data = _text_export("wide", truth, valid, labels)
    lines = data.split(b"\n")
    dropped = [101, 102, 103]                        # data lines of frames 100-102 (line 0 is the header)
    kept = b"\n".join(ln for i, ln in enumerate(lines) if i not in dropped)
    inp, out = tmp_path / name, tmp_path / f"filled_{name}"
    inp.write_bytes(kept)
    res = invoke("fill", str(inp), str(out), "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["samples_not_written"] == len(dropped) * len(labels)
    assert any("dropped frames" in w and "not written" in w for w in summary["warnings"])
    assert out.read_bytes() == kept                  # nothing else to fill: the copy is the input
    plain = invoke("fill", str(inp), str(tmp_path / "again.csv"))
    assert "not written" in plain.stdout


def _listed(side: dict, labels: list[str], first_frame: int, shape: tuple[int, int], key: str = "filled"):
    """(T, M) mask of the samples a sidecar lists under ``key``, and their methods {(row, col): method}."""
    mask, methods = np.zeros(shape, bool), {}
    for label, runs in side[key].items():
        for run in runs:
            rows = np.arange(run[0], run[1] + 1) - first_frame
            mask[rows, labels.index(label)] = True
            methods.update({(int(r), labels.index(label)): (run[2] if len(run) > 2 else None) for r in rows})
    return mask, methods


def test_fill_lists_its_filled_samples_where_the_files_residuals_cannot_mark_them(tmp_path):
    """The sample's C3D writes residual 0 for every measured sample, as for a filled one: `fill` says so in one
    warning line and lists every filled sample, with its gap's method, in OUT.gazepipe.json."""
    src, out = SAMPLE / "mocap" / "follow_standing_03.c3d", tmp_path / "f.c3d"
    res = invoke("fill", str(src), str(out), "--json")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    side_path = tmp_path / "f.c3d.gazepipe.json"
    assert summary["sidecar"] == str(side_path)
    assert [w for w in summary["warnings"] if "listed in" in w] == [w for w in summary["warnings"] if "residual" in w]
    m0, m1 = read_c3d(src), read_c3d(out)
    side = json.loads(side_path.read_text())
    listed, methods = _listed(side, m0.labels, m0.first_frame, m0.valid.shape)
    np.testing.assert_array_equal(listed, m1.valid & ~m0.valid)
    for g in summary["gap_list"]:
        if g["method"] != "unfilled":
            assert methods[(g["first_frame"] - m0.first_frame, m0.labels.index(g["marker"]))] == g["method"]
    text = invoke("fill", str(src), str(tmp_path / "g.c3d")).stdout
    assert sum("listed in" in line for line in text.splitlines()) == 1


def test_fill_needs_no_sidecar_where_residuals_mark_the_measured_samples(tmp_path):
    """A C3D whose measured samples carry residuals and cameras (as Vicon and QTM write them): the filled samples'
    fourth word 0 is the mark both byte orders read (the `c3d` package and ezc3d), so no sidecar and no warning;
    a sidecar an earlier OUT left is removed, since it would describe another file."""
    from gazepipe.io.c3d_write import write_c3d_points

    src, truth, labels = _walking_truth()
    valid = _six_gaps(truth.shape[:2], seed=5)
    words = np.where(valid, float(0x7F03), -1.0)            # seven cameras, residual 3 steps
    inp, out = tmp_path / "in.c3d", tmp_path / "out.c3d"
    write_c3d_points(inp, labels, truth, words, rate_hz=src.rate_hz, first_frame=1, scale=-0.1)
    stale = tmp_path / "out.c3d.gazepipe.json"
    stale.write_text("{}")
    res = invoke("fill", str(inp), str(out), "--json", "--force")
    assert res.exit_code == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["sidecar"] is None and not stale.exists()
    assert not any("listed in" in w for w in summary["warnings"])
    back = _read_with_py_c3d(out)
    new = ~valid & np.isfinite(back.xyz).all(axis=2)
    assert new.sum() == (~valid).sum()
    np.testing.assert_array_equal(back.residual[new], 0.0)
    np.testing.assert_allclose(back.residual[valid], 0.3, atol=1e-6)
    ez = _ezc3d(out)["residual"]
    assert (ez[new] == 0).all() and (ez[valid] > 0).all()


def test_fill_of_a_text_export_lists_its_filled_samples(tmp_path):
    _, truth, labels = _walking_truth()
    valid = _six_gaps(truth.shape[:2], seed=4)
    name, data = _text_export("qtm", truth, valid, labels)
    inp, out = tmp_path / name, tmp_path / f"filled_{name}"
    inp.write_bytes(data)
    res = invoke("fill", str(inp), str(out))
    assert res.exit_code == 0, res.stderr
    assert "text export has no residuals" in res.stdout
    side = json.loads((tmp_path / f"filled_{name}.gazepipe.json").read_text())
    m0 = read_markers(inp)
    listed, _ = _listed(side, m0.labels, m0.first_frame, m0.valid.shape)
    np.testing.assert_array_equal(listed, ~valid)


def test_export_keeps_the_captures_own_residuals_and_cameras(tmp_path):
    """A capture whose fourth words hold residuals and camera masks (as Vicon and QTM write them): the export
    writes each measured sample's word as the capture has it, under the capture's POINT:SCALE (so the residual
    keeps its meaning), a stand-in of one residual step only where the capture's residual byte is 0, and 0 for
    every filled sample."""
    from gazepipe.io.c3d_write import read_point_words, write_c3d_points
    from tests.helpers import run_session, session_copy

    session = session_copy(tmp_path / "s", {"neutral": None, "shift_y036_p12": None})
    path = session / "mocap" / "shift_y036_p12.c3d"
    m = read_c3d(path)
    t, k = np.indices(m.valid.shape)
    words = np.where(m.valid, 0x7F00 + (t + 3 * k) % 60, -1.0).astype(np.float64)   # some residual bytes 0
    write_c3d_points(path, m.labels, m.xyz, words, rate_hz=m.rate_hz, first_frame=m.first_frame, scale=-0.05)
    run_session(session, tmp_path / "out")
    side = _exported(tmp_path / "out", "shift_y036_p12", tmp_path / "e.c3d")
    got, scale = read_point_words(tmp_path / "e.c3d")
    assert scale == pytest.approx(0.05) and side["residuals"]["source"] == "capture file"
    back = read_c3d(tmp_path / "e.c3d")
    filled = back.valid & ~m.valid
    measured = back.valid & m.valid
    assert filled.any() and (got[filled] == 0).all()
    has = measured & (words % 256 > 0)
    np.testing.assert_array_equal(got[has], words[has])
    zero = measured & (words % 256 == 0)
    assert zero.any() and (got[zero] == 0x7F01).all()
    assert side["residuals"]["stand_ins"] == int(zero.sum())
