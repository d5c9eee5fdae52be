"""`gazepipe export` and `gazepipe fill`: files users open in their own viewers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.io.c3d import read_c3d
from gazepipe.io.capture import read_markers
from gazepipe.io.export import write_markers
from gazepipe.model import FILL_CODES
from gazepipe.schemas.markers import table_to_markers
from tests.helpers import CORPUS


def invoke(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


@pytest.fixture
def cleaned(sample_run) -> Path:
    """An output folder with the sample session's cleaned takes: the shared run of the whole pipeline (which
    cleans every take as ``gazepipe clean`` does), read only."""
    return sample_run


def test_exported_c3d_reingests_with_same_coordinates_and_gap_mask(cleaned, tmp_path):
    take = "follow_sitting_01"
    table = pq.read_table(cleaned / "takes" / "session01" / take / "markers.parquet")
    markers, frames, fill, _ = table_to_markers(table)
    assert (fill == FILL_CODES["unfilled"]).any()  # a target gap the filler refused: the mask matters
    dest = tmp_path / "t.c3d"
    res = invoke("export", str(cleaned), take, "--to", str(dest))
    assert res.exit_code == 0, res.stderr
    for reader in ("ezc3d", "c3d"):
        back = read_c3d(dest) if reader == "ezc3d" else _read_with_py_c3d(dest)
        assert back.labels == markers.labels
        np.testing.assert_array_equal(back.valid, markers.valid)
        # C3D float storage is float32: compare at its precision (values are up to ~3000 mm)
        np.testing.assert_allclose(back.xyz[back.valid], markers.xyz[markers.valid], atol=5e-4)
        assert back.first_frame == markers.first_frame + frames[0]


def _read_with_py_c3d(path: Path):
    """Decode with the pure-Python `c3d` reader, independently of gazepipe's reader."""
    import c3d as pyc3d

    with open(path, "rb") as fh:
        reader = pyc3d.Reader(fh)
        labels = [s.strip() for s in reader.point_labels]
        pts = np.stack([p for _, p, _ in reader.read_frames()])
        first = reader.first_frame
    from gazepipe.model import Markers
    valid = pts[:, :, 3] >= 0
    xyz = np.where(valid[..., None], pts[:, :, :3], np.nan)
    return Markers(labels=labels, xyz=xyz, valid=valid, rate_hz=1.0, first_frame=first)


def test_export_csv_round_trip(cleaned, tmp_path):
    dest = tmp_path / "t.csv"
    assert invoke("export", str(cleaned), "shift_y036_p12", "--to", str(dest)).exit_code == 0
    back = read_markers(dest)
    table = pq.read_table(cleaned / "takes" / "session01" / "shift_y036_p12" / "markers.parquet")
    markers, _, _, _ = table_to_markers(table)
    np.testing.assert_array_equal(back.valid, markers.valid)
    np.testing.assert_allclose(back.xyz[back.valid], markers.xyz[markers.valid], rtol=0, atol=1e-9)
    # frame and time columns say what the take's tables say: source frame, seconds since the capture's start
    csv = np.genfromtxt(dest, delimiter=",", names=True, usecols=(0, 1))
    rows = table.filter(pc.equal(table["marker"], table["marker"][0])).sort_by("frame")
    np.testing.assert_array_equal(csv["time"], rows["time_s"].to_numpy())
    np.testing.assert_array_equal(csv["frame"], rows["source_frame"].to_numpy())


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
    filled, _, _ = fill_capture(orig, max_gap_s=1.0, spikes=False)
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
