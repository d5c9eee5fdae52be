"""OpenFace FeatureExtraction CSV reader: the real corpus file, synthetic 2.x / padded layouts, bad input."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gazepipe.errors import InputError
from gazepipe.io.openface import read_openface
from tests.helpers import TESTS

CORPUS = TESTS / "data" / "corpus" / "openface" / "pyfeat_OpenFace_Test.csv"


def _raw(path: Path) -> pd.DataFrame:
    """The file as plain pandas sees it, names stripped: an independent view to compare against."""
    df = pd.read_csv(path)
    df.columns = [c.strip() for c in df.columns]
    return df


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=1, keepdims=True)


# ---------------------------------------------------------------- the real file

def test_corpus_file_parses():
    tr = read_openface(CORPUS)
    raw = _raw(CORPUS)
    assert tr.n_frames == 100 == len(raw)
    assert tr.layout == "openface_legacy" and tr.face_id is None
    np.testing.assert_array_equal(tr.frame, np.arange(1, 101))
    # timestamps step by 0.001 s (PROVENANCE.md), start at 0
    assert tr.time_s[0] == 0.0
    np.testing.assert_allclose(np.diff(tr.time_s), 0.001, atol=1e-9)
    assert tr.success.all()
    np.testing.assert_array_equal(tr.confidence, raw["confidence"].to_numpy())


def test_corpus_eyes_swapped_to_subject_left_right():
    tr = read_openface(CORPUS)
    raw = _raw(CORPUS)
    g0 = raw[["gaze_0_x", "gaze_0_y", "gaze_0_z"]].to_numpy()
    g1 = raw[["gaze_1_x", "gaze_1_y", "gaze_1_z"]].to_numpy()
    # the file's vectors are unit-ish already
    assert np.all(np.abs(np.linalg.norm(g0, axis=1) - 1) < 0.01)
    assert np.all(np.abs(np.linalg.norm(g1, axis=1) - 1) < 0.01)
    # gaze_0 (image's left eye) is the subject's RIGHT eye
    np.testing.assert_allclose(tr.gaze_right, _unit(g0), atol=1e-12)
    np.testing.assert_allclose(tr.gaze_left, _unit(g1), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tr.gaze_left, axis=1), 1.0, atol=1e-12)
    # subject looks roughly into the camera: -z
    assert np.all(tr.gaze_left[:, 2] < -0.9) and np.all(tr.gaze_right[:, 2] < -0.9)
    # converging eyes: the subject's right eye (image left, smaller x) points toward +x, the left eye toward -x
    assert np.median(tr.gaze_right[:, 0]) > np.median(tr.gaze_left[:, 0])


def test_corpus_blinks_from_au45_c():
    tr = read_openface(CORPUS)
    raw = _raw(CORPUS)
    np.testing.assert_array_equal(tr.blink, raw["AU45_c"].to_numpy() == 1)
    assert 0 < tr.blink.sum() < 100


# ---------------------------------------------------------------- synthetic layouts

def _frame_rows(n: int, *, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    g0 = _unit(rng.normal([0.1, 0.05, -1.0], 0.05, (n, 3)))
    g1 = _unit(rng.normal([-0.1, 0.05, -1.0], 0.05, (n, 3)))
    cols = {
        "frame": np.arange(1, n + 1),
        "timestamp": np.round(np.arange(n) / 60.0, 3),
        "confidence": np.round(rng.uniform(0.85, 0.98, n), 2),
        "success": np.ones(n, int),
    }
    for e, g in ((0, g0), (1, g1)):
        for i, a in enumerate("xyz"):
            cols[f"gaze_{e}_{a}"] = np.round(g[:, i], 6)
    return cols


def _write(path: Path, cols: dict[str, np.ndarray], *, sep: str = ", ", pad: int = 0) -> Path:
    names = list(cols)
    n = len(next(iter(cols.values())))
    lines = [sep.join(names)]
    for r in range(n):
        lines.append(sep.join(f"{cols[c][r]}".rjust(pad) for c in names))
    path.write_text("\n".join(lines) + "\n")
    return path


def _openface2(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """The 2.x column order: frame, face_id, timestamp, confidence, success, gaze, gaze_angle, eye landmarks, AUs."""
    base = _frame_rows(n, seed=seed)
    cols = {"frame": base.pop("frame"), "face_id": np.zeros(n, int), **base}
    cols["gaze_angle_x"] = np.round(np.arctan2(cols["gaze_0_x"], -cols["gaze_0_z"]), 3)
    cols["gaze_angle_y"] = np.round(np.arctan2(cols["gaze_0_y"], -cols["gaze_0_z"]), 3)
    for i in range(56):
        cols[f"eye_lmk_x_{i}"] = np.full(n, 300.0 + i)
    for i in range(56):
        cols[f"eye_lmk_y_{i}"] = np.full(n, 200.0 + i)
    cols["AU45_r"] = np.zeros(n)
    cols["AU45_c"] = np.zeros(n, int)
    return cols


def test_openface2_layout(tmp_path):
    cols = _openface2(20)
    cols["AU45_c"][[3, 4]] = 1
    tr = read_openface(_write(tmp_path / "of2.csv", cols))
    assert tr.layout == "openface2" and tr.face_id == 0
    np.testing.assert_allclose(tr.gaze_right[:, 0], _unit(np.stack([cols[f"gaze_0_{a}"] for a in "xyz"], 1))[:, 0])
    np.testing.assert_array_equal(np.flatnonzero(tr.blink), [3, 4])
    np.testing.assert_array_equal(tr.time_s, cols["timestamp"])
    assert tr.warnings == []


def test_windows_padded_values_and_header(tmp_path):
    cols = _openface2(12)
    p = tmp_path / "padded.csv"
    names = list(cols)
    lines = [", ".join(f" {c} " for c in names)]
    for r in range(12):
        lines.append(",".join(f"{cols[c][r]}".rjust(12) + "  " for c in names))
    p.write_text("\r\n".join(lines) + "\r\n")
    tr = read_openface(p)
    assert tr.n_frames == 12
    np.testing.assert_array_equal(tr.frame, np.arange(1, 13))
    np.testing.assert_array_equal(tr.confidence, cols["confidence"])


def test_multiple_faces_keep_face_zero(tmp_path):
    a, b = _openface2(10, seed=1), _openface2(10, seed=2)
    b["face_id"][:] = 1
    # OpenFace writes one row per face per frame
    cols = {k: np.stack([a[k], b[k]], 1).reshape(-1) for k in a}
    tr = read_openface(_write(tmp_path / "two.csv", cols))
    assert tr.face_id == 0 and tr.n_frames == 10
    np.testing.assert_array_equal(tr.confidence, a["confidence"])
    assert any("kept face_id 0" in w for w in tr.warnings)


def test_multiple_faces_without_zero_keep_most_frequent(tmp_path):
    cols = _openface2(9)
    cols["face_id"][:] = [3, 2, 3, 3, 2, 3, 3, 3, 3]
    cols["frame"] = np.array([1, 1, 2, 3, 3, 4, 5, 6, 7])
    tr = read_openface(_write(tmp_path / "f.csv", cols))
    assert tr.face_id == 3
    np.testing.assert_array_equal(tr.frame, [1, 2, 3, 4, 5, 6, 7])


def test_success_zero_rows_are_kept_and_flagged(tmp_path):
    cols = _openface2(10)
    cols["success"][[2, 5]] = 0
    cols["confidence"][[2, 5]] = 0.03
    for e in (0, 1):
        for a in "xyz":
            cols[f"gaze_{e}_{a}"][2] = 0.0  # junk: a zero vector
    tr = read_openface(_write(tmp_path / "s.csv", cols))
    assert tr.n_frames == 10
    np.testing.assert_array_equal(~tr.success, np.isin(np.arange(10), [2, 5]))
    assert np.isnan(tr.gaze_left[2]).all() and np.isnan(tr.gaze_right[2]).all()
    assert np.isfinite(tr.gaze_left[5]).all()
    assert any("success == 0" in w for w in tr.warnings)


def test_blink_from_au45_r_when_au45_c_absent(tmp_path):
    cols = _frame_rows(6)
    cols["AU45_r"] = np.array([0.0, 0.99, 1.0, 2.5, 0.2, 1.01])
    tr = read_openface(_write(tmp_path / "r.csv", cols))
    np.testing.assert_array_equal(tr.blink, [False, False, True, True, False, True])
    assert any("AU45_r" in w for w in tr.warnings)


def test_no_au45_means_no_blink_info(tmp_path):
    tr = read_openface(_write(tmp_path / "n.csv", _frame_rows(5)))
    assert tr.blink is None
    assert any("no blink" in w for w in tr.warnings)


def test_truncated_last_row_is_dropped_with_warning(tmp_path):
    p = _write(tmp_path / "cut.csv", _frame_rows(8))
    text = p.read_text()
    p.write_text(text[: text.rstrip("\n").rfind(",") - 3])  # cut inside the last row
    tr = read_openface(p)
    assert tr.n_frames == 7
    assert any("last row" in w for w in tr.warnings)


# ---------------------------------------------------------------- bad input

def _bad_files(tmp: Path) -> list[tuple[Path, str | None]]:
    out = []
    out.append((tmp / "missing.csv", None))
    (tmp / "empty.csv").write_text("")
    out.append((tmp / "empty.csv", None))
    (tmp / "header_only.csv").write_text(", ".join(_frame_rows(1)) + "\n")
    out.append((tmp / "header_only.csv", None))
    c = _frame_rows(5)
    del c["gaze_1_z"]
    out.append((_write(tmp / "nocol.csv", c), "gaze_1_z"))
    c = _frame_rows(5)
    c["confidence"] = c["confidence"].astype(object)
    c["confidence"][2] = "abc"
    out.append((_write(tmp / "junk.csv", c), "confidence"))
    c = _frame_rows(5)
    c["gaze_0_y"] = c["gaze_0_y"].astype(object)
    c["gaze_0_y"][1] = ""
    out.append((_write(tmp / "hole.csv", c), "gaze_0_y"))
    c = _frame_rows(5)
    c["frame"] = np.array([1, 2, 2, 3, 4])
    out.append((_write(tmp / "dupframe.csv", c), "frame"))
    (tmp / "binary.csv").write_bytes(b"\xff\xfe\x00\x81garbage\x00\x9c" * 10)
    out.append((tmp / "binary.csv", None))
    return out


def test_bad_input_is_one_line_input_error(tmp_path):
    for path, column in _bad_files(tmp_path):
        with pytest.raises(InputError) as ei:
            read_openface(path)
        msg = str(ei.value)
        assert "\n" not in msg
        assert str(path) in msg, msg
        if column:
            assert column in msg, msg


def test_zero_timestamp_steps_are_reported(tmp_path):
    cols = _frame_rows(6)
    cols["timestamp"] = np.zeros(6)
    tr = read_openface(_write(tmp_path / "z.csv", cols))
    assert any("5 timestamp step(s) of zero" in w for w in tr.warnings)


def test_dropped_frames_are_reported_with_the_row(tmp_path):
    cols = _frame_rows(30)
    keep = np.r_[0:10, 14:20, 21:30]            # frames 11-14 and 21 never written
    tr = read_openface(_write(tmp_path / "d.csv", {k: v[keep] for k, v in cols.items()}))
    dropped = [w for w in tr.warnings if "dropped" in w]
    assert dropped == ["5 dropped video frame(s) in 2 gap(s) (first after frame 10, data row 10): bridged by the "
                       "eye gap rules"], tr.warnings
    np.testing.assert_array_equal(tr.frame, cols["frame"][keep])
    assert not any("dropped" in w for w in read_openface(_write(tmp_path / "a.csv", cols)).warnings)


@pytest.mark.parametrize("value", ["-1e300", "1e30", "12.5"])
def test_absurd_gaze_values_are_flagged_without_numpy_warnings(tmp_path, value):
    cols = {k: v.astype(object) for k, v in _frame_rows(12).items()}
    cols["gaze_1_y"][7] = value
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # an overflow in the norm would be a RuntimeWarning
        tr = read_openface(_write(tmp_path / "v.csv", cols))
    assert any("gaze component beyond" in w and "data row 8" in w for w in tr.warnings), tr.warnings
    assert not tr.success[7] and tr.success.sum() == 11
    assert np.isnan(tr.gaze_left[7]).all() and np.isfinite(tr.gaze_left[np.arange(12) != 7]).all()
