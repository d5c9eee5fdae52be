"""face stage: timecode alignment of tracked and clean takes, Berson derivatives, mirroring."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from gazepipe.arkit import ALL_NAMES, ARKIT_NAMES, EYE_NAMES, HEAD_NAMES, mirror_face
from gazepipe.errors import StageError
from gazepipe.io.livelinkface import read_livelinkface
from gazepipe.stages.face.params import FaceParams
from gazepipe.stages.face.stage import align_face, forward_derivatives

RATE, TC_FPS = 30, 60
BASE = (10 * 3600 + 20 * 60 + 30) * TC_FPS  # 10:20:30:00 in timecode frames


def _tc(frames: float) -> str:
    whole = int(np.floor(frames))
    frac = frames - whole
    ff = whole % TC_FPS
    s = whole // TC_FPS
    return f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}:{ff:02d}.{round(frac * 1000):03d}"


def _take(path: Path, capture_frames: list[int], values: np.ndarray, *, offset_tc: float = 0.0) -> Path:
    """A Live Link Face file with rows at the given 30 Hz capture frames on a 60 fps timecode."""
    df = pd.DataFrame({"Timecode": [_tc(BASE + 2 * f + offset_tc) for f in capture_frames],
                       "BlendShapeCount": 61})
    for j, n in enumerate(ARKIT_NAMES):
        df[n[0].upper() + n[1:]] = values[capture_frames, j]
    for n in HEAD_NAMES + EYE_NAMES:
        df[n[0].upper() + n[1:]] = 0.0
    df.to_csv(path, index=False, float_format="%.8f")
    return path


@pytest.fixture
def pair(tmp_path):
    rng = np.random.default_rng(11)
    trk_all = rng.uniform(0, 1, (15, 52)).round(6)
    cln_all = rng.uniform(0, 1, (15, 52)).round(6)
    trk_frames = [f for f in range(15) if f not in (4, 7, 8)]   # the phone dropped 4, 7 and 8
    cln_frames = [f for f in range(15) if f != 10]              # the clean take lacks 10
    t = read_livelinkface(_take(tmp_path / "trk.csv", trk_frames, trk_all), rate_hz=RATE, timecode_fps=TC_FPS)
    c = read_livelinkface(_take(tmp_path / "cln.csv", cln_frames, cln_all), rate_hz=RATE, timecode_fps=TC_FPS)
    return t, c, trk_all, cln_all


def test_alignment_and_first_derivative_by_hand(pair):
    t, c, trk_all, cln_all = pair
    fa = align_face(t, c)
    matched = [0, 1, 2, 3, 5, 6, 9, 11, 12, 13, 14]
    out = matched[:-1]  # the last frame has no forward dt
    assert fa.n_frames == len(out) == 10
    np.testing.assert_array_equal(fa.frame_index, out)
    np.testing.assert_array_equal(fa.tracked, trk_all[out].astype(np.float32))
    np.testing.assert_array_equal(fa.clean, cln_all[out].astype(np.float32))
    assert list(fa.timecode[:2]) == [_tc(BASE), _tc(BASE + 2)]
    for i in range(10):
        f, g = matched[i], matched[i + 1]
        dt = (g - f) / RATE
        assert fa.time_s[i] == pytest.approx(f / RATE, abs=1e-12)
        assert fa.dt_s[i] == pytest.approx(dt, rel=1e-12)
        x0, x1 = trk_all[f].astype(np.float32), trk_all[g].astype(np.float32)
        np.testing.assert_allclose(fa.d_tracked[i, 0], (x1.astype(float) - x0) / dt, rtol=1e-12)
        y0, y1 = cln_all[f].astype(np.float32), cln_all[g].astype(np.float32)
        np.testing.assert_allclose(fa.d_clean[i, 0], (y1.astype(float) - y0) / dt, rtol=1e-12)
    qc = fa.qc
    assert (qc["rows_tracked"], qc["rows_clean"], qc["rows_matched"], qc["rows_out"]) == (12, 14, 11, 10)
    assert (qc["unmatched_tracked"], qc["unmatched_clean"], qc["last_frames_dropped"]) == (1, 3, 1)
    assert (qc["dropped_frames_tracked"], qc["dropped_frames_clean"]) == (3, 1)
    assert fa.names == ARKIT_NAMES


def test_second_derivative_by_hand(pair):
    t, c, trk_all, _ = pair
    fa = align_face(t, c, FaceParams(k=2))
    matched = [0, 1, 2, 3, 5, 6, 9, 11, 12, 13, 14]
    assert fa.n_frames == len(matched) - 2 and fa.qc["last_frames_dropped"] == 2
    x = trk_all.astype(np.float32).astype(float)
    for i in range(fa.n_frames):
        a, b, cc = matched[i], matched[i + 1], matched[i + 2]
        d_ab = (x[b] - x[a]) / ((b - a) / RATE)
        d_bc = (x[cc] - x[b]) / ((cc - b) / RATE)
        np.testing.assert_allclose(fa.d_tracked[i, 0], d_ab, rtol=1e-12)
        np.testing.assert_allclose(fa.d_tracked[i, 1], (d_bc - d_ab) / ((b - a) / RATE), rtol=1e-10)


def test_subframe_offsets_within_half_a_capture_frame_match(tmp_path):
    rng = np.random.default_rng(5)
    v = rng.uniform(0, 1, (8, 52)).round(6)
    frames = list(range(8))
    t = read_livelinkface(_take(tmp_path / "t.csv", frames, v), rate_hz=RATE)
    near = read_livelinkface(_take(tmp_path / "n.csv", frames, v, offset_tc=0.9), rate_hz=RATE)  # 15 ms
    assert align_face(t, near).qc["rows_matched"] == 8
    # 1.1 timecode frames late (18 ms): each clean row is now nearest to the next tracked row (15 ms)
    late = read_livelinkface(_take(tmp_path / "l.csv", frames, v, offset_tc=1.1), rate_hz=RATE)
    fa = align_face(t, late)
    assert fa.qc["rows_matched"] == 7 and fa.qc["max_match_error_s"] == pytest.approx(0.9 / 60, abs=1e-6)
    np.testing.assert_array_equal(fa.frame_index, np.arange(1, 7))
    np.testing.assert_array_equal(fa.clean, v[0:6].astype(np.float32))
    # an hour apart: nothing in common
    other = read_livelinkface(_take(tmp_path / "o.csv", frames, v, offset_tc=3600 * TC_FPS), rate_hz=RATE)
    with pytest.raises(StageError):
        align_face(t, other)


def test_forward_derivatives_constant_rate_polynomial():
    # x = t^2 sampled at 100 Hz: first forward difference is exactly 2t + h, second exactly 2
    h = 0.01
    t = np.arange(12) * h
    x = np.stack([t**2, 3 * t], axis=1)
    d = forward_derivatives(x, np.full(11, h), 2)
    np.testing.assert_allclose(d[:, 0, 0], 2 * t[:10] + h, rtol=1e-9)
    np.testing.assert_allclose(d[:, 1, 0], 2.0, rtol=1e-6)
    np.testing.assert_allclose(d[:, 0, 1], 3.0, rtol=1e-12)


# ---------------------------------------------------------------- mirroring

def test_mirror_face_example():
    names = ["eyeBlinkLeft", "eyeBlinkRight", "jawOpen", "headYaw", "headPitch", "headRoll",
             "leftEyeYaw", "leftEyePitch", "leftEyeRoll", "rightEyeYaw", "rightEyePitch", "rightEyeRoll"]
    v = np.arange(1, 13, dtype=np.float64)[None]
    m = mirror_face(v, names)[0]
    np.testing.assert_array_equal(m, [2, 1, 3, -4, 5, -6, -10, 11, -12, -7, 8, -9])


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_mirror_twice_is_identity_exactly(data):
    names = list(data.draw(st.permutations(ALL_NAMES)))
    dtype = data.draw(st.sampled_from([np.float32, np.float64]))
    n = data.draw(st.integers(0, 5))
    values = data.draw(hnp.arrays(dtype, (n, len(names)), elements=hnp.from_dtype(np.dtype(dtype))))
    once = mirror_face(values, names)
    twice = mirror_face(once, names)
    assert twice.dtype == values.dtype
    assert twice.tobytes() == values.tobytes()
