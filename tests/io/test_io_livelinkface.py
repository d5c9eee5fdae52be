"""Live Link Face CSV reader and ARKit name handling: the real corpus take, synthetic edits of it, bad input."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gazepipe.arkit import ARKIT_NAMES, EYE_NAMES, HEAD_NAMES, mirror_permutation, normalise_name
from gazepipe.errors import InputError
from gazepipe.io.livelinkface import read_livelinkface
from tests.helpers import TESTS

CORPUS = TESTS / "data" / "corpus" / "livelinkface" / "alex_rom_3_first300.csv"


def _tc_frames(tc: str, fps: int = 60) -> Fraction:
    """Hand conversion of one timecode to frames since midnight, exact."""
    hms, ff = tc.rsplit(":", 1)
    h, m, s = (int(x) for x in hms.split(":"))
    return Fraction((h * 60 + m) * 60 + s) * fps + Fraction(ff)


def _lines() -> list[str]:
    return CORPUS.read_text().splitlines()


# ---------------------------------------------------------------- ARKit names

def test_arkit_table():
    assert len(ARKIT_NAMES) == 52 == len(set(ARKIT_NAMES))
    assert ARKIT_NAMES[0] == "eyeBlinkLeft" and ARKIT_NAMES[-1] == "tongueOut"
    assert ARKIT_NAMES.index("jawLeft") < ARKIT_NAMES.index("jawRight")
    for n in ARKIT_NAMES + HEAD_NAMES + EYE_NAMES:
        assert normalise_name(n) == n
        assert normalise_name(n[0].upper() + n[1:]) == n      # Live Link Face PascalCase
        assert normalise_name(n.upper()) == n
    assert normalise_name("eyeBlink_L") == "eyeBlinkLeft"      # ARKit raw keys
    assert normalise_name("mouthUpperUp_R") == "mouthUpperUpRight"
    assert normalise_name(" JawOpen ") == "jawOpen"
    assert normalise_name("Timecode") is None and normalise_name("eyeBlink") is None


def test_mirror_permutation_pairs():
    names = ["jawOpen", "eyeBlinkLeft", "headYaw", "eyeBlinkRight", "headPitch", "leftEyeRoll", "rightEyeRoll"]
    perm, neg = mirror_permutation(names)
    assert [names[i] for i in perm] == ["jawOpen", "eyeBlinkRight", "headYaw", "eyeBlinkLeft", "headPitch",
                                        "rightEyeRoll", "leftEyeRoll"]
    np.testing.assert_array_equal(neg, [False, False, True, False, False, True, True])
    with pytest.raises(ValueError, match="partner"):
        mirror_permutation(["eyeBlinkLeft"])


# ---------------------------------------------------------------- the real take

def test_corpus_take():
    ft = read_livelinkface(CORPUS, rate_hz=30, timecode_fps=60)
    raw = pd.read_csv(CORPUS)
    assert ft.n_frames == 300 == len(raw)
    assert ft.blendshape_count == 61
    assert ft.names == ARKIT_NAMES and ft.values.shape == (300, 52) and ft.values.dtype == np.float32
    # by name, not position: the file writes JawRight before JawLeft
    for j, n in enumerate(ARKIT_NAMES):
        np.testing.assert_array_equal(ft.values[:, j], raw[n[0].upper() + n[1:]].to_numpy(np.float32))
    # time from the timecode, exact: first 13:13:04:31.652, last 13:13:14:29.571 at 60 fps
    first, last = raw["Timecode"].iloc[0], raw["Timecode"].iloc[-1]
    assert (first, last) == ("13:13:04:31.652", "13:13:14:29.571")
    expect = float((_tc_frames(last) - _tc_frames(first)) / 60)
    assert ft.time_s[0] == 0.0 and ft.time_s[-1] == pytest.approx(expect, abs=1e-12)
    # 30 Hz capture on a 60 fps timecode
    assert ft.rate_hz == 30.0
    np.testing.assert_allclose(np.diff(ft.time_s), 2 / 60, atol=0.002 / 60)


def test_corpus_take_steps_and_dropped_frames():
    ft = read_livelinkface(CORPUS, rate_hz=30)
    # every step in these 300 rows is 2 timecode frames (1.999-2.000): no 4-frame step, nothing dropped
    tc = pd.read_csv(CORPUS)["Timecode"]
    steps = np.diff([float(_tc_frames(t)) for t in tc])
    assert np.all(np.abs(steps - 2) < 0.01)
    assert ft.dropped_frames == 0
    np.testing.assert_array_equal(ft.frame_index, np.arange(300))


def test_corpus_head_off_eyes_in_radians():
    ft = read_livelinkface(CORPUS, rate_hz=30)
    assert np.isnan(ft.head).all()
    assert any("head tracking was off" in w for w in ft.warnings)
    raw = pd.read_csv(CORPUS)
    for j, n in enumerate(EYE_NAMES):
        np.testing.assert_array_equal(ft.eyes[:, j], raw[n[0].upper() + n[1:]].to_numpy())
    # radians: pitch a few to some 17 degrees, yaw within a few degrees
    assert 0.1 < np.median(ft.eyes[:, 1]) < 0.35 and np.abs(ft.eyes[:, [0, 3]]).max() < 0.2


def test_dropped_frames_detected(tmp_path):
    lines = _lines()
    # remove data rows 50 and 120-121 (file lines 51, 121, 122): three dropped capture frames in two gaps
    keep = [ln for i, ln in enumerate(lines) if i not in (51, 121, 122)]
    p = tmp_path / "drop.csv"
    p.write_text("\n".join(keep) + "\n")
    ft = read_livelinkface(p, rate_hz=30)
    assert ft.n_frames == 297 and ft.dropped_frames == 3
    expect = np.delete(np.arange(300), [50, 120, 121])
    np.testing.assert_array_equal(ft.frame_index, expect)
    assert any("3 dropped" in w and "2 gap" in w for w in ft.warnings)


def test_rate_estimated_and_cross_checked():
    est = read_livelinkface(CORPUS)
    assert est.rate_hz == 30.0 and any("not given" in w for w in est.warnings)
    wrong = read_livelinkface(CORPUS, rate_hz=60)
    assert any("median timecode step implies" in w for w in wrong.warnings)


def test_column_order_and_spelling_do_not_matter(tmp_path):
    raw = pd.read_csv(CORPUS, nrows=20)
    cols = list(raw.columns)
    rng = np.random.default_rng(3)
    shuffled = cols[:1] + list(rng.permutation(cols[1:]))
    df = raw[shuffled].rename(columns=lambda c: c[0].lower() + c[1:] if c not in ("Timecode",) else c)
    p = tmp_path / "shuffled.csv"
    df.to_csv(p, index=False, float_format="%.10f")
    a = read_livelinkface(CORPUS, rate_hz=30)
    b = read_livelinkface(p, rate_hz=30)
    np.testing.assert_array_equal(b.values, a.values[:20])
    np.testing.assert_array_equal(b.eyes, a.eyes[:20])


def _synthetic(tmp_path: Path, timecodes: list[str], *, head: float = 0.1) -> Path:
    n = len(timecodes)
    rng = np.random.default_rng(7)
    df = pd.DataFrame({"Timecode": timecodes, "BlendShapeCount": 61})
    for name in ARKIT_NAMES:
        df[name[0].upper() + name[1:]] = rng.uniform(0, 1, n)
    for name in HEAD_NAMES + EYE_NAMES:
        df[name[0].upper() + name[1:]] = head * rng.uniform(-1, 1, n)
    p = tmp_path / "syn.csv"
    df.to_csv(p, index=False)
    return p


def test_head_tracking_on_and_exact_fractions(tmp_path):
    tcs = ["01:02:03:04.250", "01:02:03:05.125", "01:02:03:06.000", "01:02:03:07.875"]
    ft = read_livelinkface(_synthetic(tmp_path, tcs), rate_hz=60)
    assert np.isfinite(ft.head).all()
    expect = [float((_tc_frames(t) - _tc_frames(tcs[0])) / 60) for t in tcs]
    np.testing.assert_allclose(ft.time_s, expect, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(ft.tc_frame, [223384, 223385, 223386, 223387])  # 3723 s · 60 + FF


def test_midnight_crossing_counts_on(tmp_path):
    tcs = ["23:59:59:58.000", "23:59:59:59.000", "00:00:00:00.000", "00:00:00:01.000"]
    ft = read_livelinkface(_synthetic(tmp_path, tcs), rate_hz=60)
    np.testing.assert_allclose(ft.time_s, np.arange(4) / 60, atol=1e-12)
    assert ft.dropped_frames == 0
    assert any("midnight" in w for w in ft.warnings)


@pytest.mark.parametrize("bad", [
    "13:13:04:xx.000",      # garbage
    "13:13:04",             # too short
    "25:00:00:00.000",      # hour out of range
    "13:13:04:60.000",      # FF counts 0..59 at 60 fps
    "13:13:04:01.000",      # goes backwards
    "12:00:00:00.000",      # jumps back an hour (not a midnight wrap)
])
def test_garbage_timecodes(tmp_path, bad):
    tcs = ["13:13:04:02.000", "13:13:04:04.000", bad, "13:13:04:08.000"]
    p = _synthetic(tmp_path, tcs)
    with pytest.raises(InputError) as ei:
        read_livelinkface(p, rate_hz=30)
    msg = str(ei.value)
    assert "\n" not in msg and str(p) in msg and "Timecode" in msg and "row" in msg


def test_bad_files(tmp_path):
    lines = _lines()
    cases = []
    cases.append((tmp_path / "missing.csv", None))
    (tmp_path / "empty.csv").write_text("")
    cases.append((tmp_path / "empty.csv", None))
    (tmp_path / "head.csv").write_text(lines[0] + "\n")
    cases.append((tmp_path / "head.csv", None))
    hdr = lines[0].split(",")
    i = hdr.index("MouthSmileLeft")
    (tmp_path / "nocol.csv").write_text("\n".join(",".join(r.split(",")[:i] + r.split(",")[i + 1:])
                                                  for r in lines[:10]) + "\n")
    cases.append((tmp_path / "nocol.csv", "mouthSmileLeft"))
    row = lines[5].split(",")
    row[10] = "oops"
    (tmp_path / "junk.csv").write_text("\n".join(lines[:5] + [",".join(row)] + lines[6:10]) + "\n")
    cases.append((tmp_path / "junk.csv", hdr[10]))
    for path, col in cases:
        with pytest.raises(InputError) as ei:
            read_livelinkface(path, rate_hz=30)
        msg = str(ei.value)
        assert "\n" not in msg and str(path) in msg, msg
        if col:
            assert col in msg, msg


# ---------------------------------------------------------------- tracking lost

LOST = [0, 1, 2, *range(100, 130), 299]      # data rows written while the face was lost: the first, a stretch, the last


def _lost_take(tmp_path: Path) -> Path:
    """The corpus take with some rows as the app writes them while ARKit has lost the face: the timecode, a
    BlendShapeCount of 0 and nothing after it (``12:22:06:30.534,0``)."""
    lines = _lines()
    for r in LOST:
        lines[r + 1] = lines[r + 1].split(",", 1)[0] + ",0"
    p = tmp_path / "lost.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_rows_written_while_tracking_was_lost_are_kept_invalid(tmp_path):
    """Tracking-loss rows do not refuse the take: they are kept as invalid rows (NaN values), counted and
    flagged, and every other row reads as an independent parse gives it, on the same frames and times."""
    ft = read_livelinkface(_lost_take(tmp_path), rate_hz=30)
    whole = read_livelinkface(CORPUS, rate_hz=30)
    assert ft.n_frames == 300 and ft.valid is not None
    np.testing.assert_array_equal(np.flatnonzero(~ft.valid), LOST)
    assert np.isnan(ft.values[LOST]).all() and np.isnan(ft.eyes[LOST]).all() and np.isnan(ft.head).all()
    keep = np.setdiff1d(np.arange(300), LOST)
    raw = pd.read_csv(CORPUS)
    for j, n in enumerate(ARKIT_NAMES):
        np.testing.assert_array_equal(ft.values[keep, j], raw[n[0].upper() + n[1:]].to_numpy(np.float32)[keep])
    np.testing.assert_array_equal(ft.time_s, whole.time_s)
    np.testing.assert_array_equal(ft.frame_index, whole.frame_index)
    assert ft.blendshape_count == 61 and ft.dropped_frames == 0
    note = [w for w in ft.warnings if "tracking was lost" in w]
    assert len(note) == 1 and "34 of 300 rows in 3 stretch(es)" in note[0] and "data row 1" in note[0]


def test_inspect_counts_lost_rows_as_invalid(tmp_path):
    from gazepipe.io.inspect_tracks import inspect_file

    info = inspect_file(_lost_take(tmp_path), rate_hz=30)
    assert info["lost_rows"] == len(LOST) and info["blendshape_count"] == 61
    assert info["valid_share"] == pytest.approx((300 - len(LOST)) / 300)
    assert info["rows"] == 300 and info["dropped_frames"] == 0


def test_short_rows_that_are_not_tracking_loss_are_still_refused(tmp_path):
    lines = _lines()
    lines[6] = lines[6].split(",", 1)[0] + ",61"                 # a count of 61 and no values: a broken row
    (tmp_path / "short.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="data row 6"):
        read_livelinkface(tmp_path / "short.csv", rate_hz=30)
    lines = _lines()
    cells = lines[6].split(",")
    lines[6] = ",".join([cells[0], "0", *cells[2:12]])           # a count of 0 but some values: not a lost row
    (tmp_path / "part.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="data row 6"):
        read_livelinkface(tmp_path / "part.csv", rate_hz=30)


def test_face_alignment_leaves_out_lost_rows(tmp_path):
    """A lost row pairs with nothing: the aligned rows are the valid ones, and no NaN reaches the values or their
    derivatives."""
    from gazepipe.stages.face.stage import align_face

    lost = read_livelinkface(_lost_take(tmp_path), rate_hz=30)
    clean = read_livelinkface(CORPUS, rate_hz=30)
    out = align_face(lost, clean)
    assert np.isfinite(out.tracked).all() and np.isfinite(out.d_tracked).all() and np.isfinite(out.clean).all()
    kept = np.setdiff1d(np.arange(300), LOST)
    np.testing.assert_array_equal(out.frame_index, kept[:-1])
    assert out.qc["unmatched_tracked"] == len(LOST) and out.qc["rows_matched"] == kept.size
    both = align_face(clean, lost)                               # lost rows in the clean track too
    np.testing.assert_array_equal(both.frame_index, kept[:-1])


def test_generated_tracking_loss_is_read_as_the_truth_has_it(tmp_path):
    """A generated face take whose tracked file has tracking-loss stretches (``SynthConfig.face_tracking_loss``):
    the reader's invalid rows are the truth's lost frames, its valid rows the tracker's values, and the take's
    alignment with its clean file leaves the lost rows out."""
    from gazepipe.stages.face.stage import align_face
    from gazepipe.synth import SynthConfig, generate_session, load_truth

    cfg = SynthConfig(follow_poses=(), shift_targets=(), neutral_s=0.0, head_camera=False,
                      face_takes=((60.0, 10.0),), face_tracking_loss=3)
    root = generate_session(tmp_path / "s", seed=5, config=cfg)
    truth = load_truth(root, "face_01")
    written = ~truth["face_tracked_dropped"]
    lost = truth["face_tracked_lost"][written]
    assert lost.sum() == truth["scalars"]["lost_tracked"] > 0
    ft = read_livelinkface(root / "face" / "face_01_tracked.csv", rate_hz=60)
    np.testing.assert_array_equal(ft.valid, ~lost)
    # both float32 roundings of the same number (the truth of the float64 value, the reader of its 10 decimals)
    np.testing.assert_allclose(ft.values[~lost], truth["face_tracked"][written][~lost], rtol=0, atol=1.2e-7)
    assert ft.dropped_frames == int(truth["face_tracked_dropped"].sum())
    clean = read_livelinkface(root / "face" / "face_01_clean.csv", rate_hz=60)
    out = align_face(ft, clean)
    assert np.isfinite(out.d_tracked).all() and not np.isin(out.frame_index, ft.frame_index[lost]).any()
    assert out.qc["unmatched_tracked"] >= int(lost.sum())
