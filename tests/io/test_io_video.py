"""Video probe and windowed decoding, on small videos written with this OpenCV build."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from gazepipe.errors import InputError
from gazepipe.io.video import FrameReader, probe_video, read_frames
from tests.helpers import REPO

W, H, N, FPS = 64, 48, 30, 30.0


def _level(i: np.ndarray | int) -> np.ndarray | int:
    """Grey level written into frame i: distinct per frame, far from 0 and 255."""
    return 20 + 7 * np.asarray(i)


def _write(path: Path, fourcc: str, fps: float = FPS, n: int = N) -> Path:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (W, H))
    assert w.isOpened(), f"this OpenCV build cannot write {fourcc}"
    for i in range(n):
        img = np.full((H, W, 3), _level(i), np.uint8)
        img[:, : W // 4, 2] = 200  # a red stripe, to tell colour from grey
        w.write(img)
    w.release()
    return path


def _decode_all(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Independent reference: decode every frame in order; (times in s, grey frames)."""
    cap = cv2.VideoCapture(str(path))
    ts, frames = [], []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        ts.append(cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0)
        frames.append(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    cap.release()
    return np.asarray(ts), np.stack(frames)


@pytest.fixture(scope="module", params=[("MJPG", "avi"), ("mp4v", "mp4")])
def video(request, tmp_path_factory) -> Path:
    cc, ext = request.param
    return _write(tmp_path_factory.mktemp("vid") / f"v.{ext}", cc)


def test_probe(video):
    pr = probe_video(video)
    assert (pr.n_frames, pr.width, pr.height) == (N, W, H)
    assert pr.nominal_fps == pytest.approx(FPS)
    assert pr.timestamp_source == "packets"
    np.testing.assert_allclose(pr.timestamps_s, _decode_all(video)[0], atol=1e-9)
    np.testing.assert_allclose(pr.timestamps_s, np.arange(N) / FPS, atol=1e-6)
    assert pr.warnings == []


def test_probe_ntsc_rate(tmp_path):
    p = _write(tmp_path / "ntsc.avi", "MJPG", fps=30000 / 1001, n=12)
    pr = probe_video(p)
    np.testing.assert_allclose(pr.timestamps_s, np.arange(12) * 1001 / 30000, atol=1e-6)


def test_read_window_decodes_the_right_frames(video):
    pr = probe_video(video)
    _, every = _decode_all(video)
    for kw in ({}, {"timestamps_s": pr.timestamps_s}):
        ts, fr = read_frames(video, 17, 27, **kw)
        assert fr.shape == (10, H, W) and fr.dtype == np.uint8
        np.testing.assert_allclose(ts, pr.timestamps_s[17:27], atol=1e-9)
        # the same pixels as decoding the whole video in order
        np.testing.assert_array_equal(fr, every[17:27])
        # and the grey level identifies the frame written (neighbours are 7 levels apart; lossy codecs move it
        # by up to 3)
        levels = fr[:, :, W // 2:].reshape(10, -1).mean(axis=1)
        np.testing.assert_array_equal(np.rint((levels - _level(0)) / 7), np.arange(17, 27))


def test_read_window_falls_back_to_grabbing_when_seek_disagrees(video):
    pr = probe_video(video)
    _, every = _decode_all(video)
    # timestamps that no seek can match force the frame-by-frame walk; the frames must still be right
    ts, fr = read_frames(video, 11, 14, timestamps_s=pr.timestamps_s + 1.0)
    np.testing.assert_array_equal(fr, every[11:14])
    np.testing.assert_allclose(ts, pr.timestamps_s[11:14], atol=1e-9)


def test_read_window_colour_scale_and_clipping(video):
    ts, fr = read_frames(video, 0, 3, gray=False)
    assert fr.shape == (3, H, W, 3)
    assert fr[0, :, : W // 4 - 2, 2].mean() > 150  # the red stripe is in the red channel (BGR)
    ts, fr = read_frames(video, 5, 7, scale=0.5)
    assert fr.shape == (2, H // 2, W // 2)
    ts, fr = read_frames(video, N - 3, N + 10)  # stop past the end is clipped
    assert fr.shape[0] == 3
    with pytest.raises(InputError):
        read_frames(video, N + 5, N + 10)
    with pytest.raises(ValueError):
        read_frames(video, 5, 5)


@pytest.mark.parametrize("max_skip,threads", [(0, 1), (4, 1), (300, 1), (4, None)])
def test_frame_reader_windows_in_any_order(video, max_skip, threads):
    """One open capture serves windows ahead (next frame, a little ahead, far ahead), behind, overlapping and
    clipped at the end: every window has the frames and timestamps of decoding the whole video in order (with
    the backend's default threads), with seeks (max_skip 0) or with grabs forward, on one decoding thread or
    the backend's default."""
    pr = probe_video(video)
    _, every = _decode_all(video)
    windows = [(0, 5), (5, 9), (12, 15), (25, 27), (3, 8), (6, 10), (2, 4), (20, 40), (0, 1)]
    for ts_arg in (pr.timestamps_s, None):
        with FrameReader(video, timestamps_s=ts_arg, max_skip=max_skip, threads=threads) as reader:
            for a, b in windows:
                ts, fr = reader(a, b)
                stop = min(b, N)
                np.testing.assert_array_equal(fr, every[a:stop])
                np.testing.assert_allclose(ts, pr.timestamps_s[a:stop], atol=1e-9)
            with pytest.raises(InputError):
                reader(N + 2, N + 4)
            ts, fr = reader(1, 3)  # still usable after a window past the end
            np.testing.assert_array_equal(fr, every[1:3])


def test_frame_reader_stops_trusting_an_inexact_seek(video):
    pr = probe_video(video)
    _, every = _decode_all(video)
    with FrameReader(video, timestamps_s=pr.timestamps_s + 1.0, max_skip=0) as reader:
        for a, b in [(11, 14), (20, 22), (4, 6), (28, 30)]:
            ts, fr = reader(a, b)
            np.testing.assert_array_equal(fr, every[a:b])
            np.testing.assert_allclose(ts, pr.timestamps_s[a:b], atol=1e-9)
    reader = FrameReader(video, gray=False, scale=0.5)
    assert reader(2, 4)[1].shape == (2, H // 2, W // 2, 3)
    reader.close()
    with pytest.raises(ValueError):
        reader(0, 1)


def test_bad_videos(tmp_path):
    (tmp_path / "empty.mp4").write_bytes(b"")
    (tmp_path / "text.mp4").write_text("this is not a video\n" * 50)
    (tmp_path / "dir.mp4").mkdir()
    for p in [tmp_path / "missing.mp4", tmp_path / "empty.mp4", tmp_path / "text.mp4", tmp_path / "dir.mp4"]:
        for call in (lambda q: probe_video(q), lambda q: read_frames(q, 0, 2), lambda q: FrameReader(q)):
            with pytest.raises(InputError) as ei:
                call(p)
            msg = str(ei.value)
            assert "\n" not in msg and str(p) in msg, msg


SAMPLE_VIDEO = REPO / "sample_data" / "session01" / "video" / "follow_standing_03.mp4"


def _flipped(dest: Path, seed: int) -> Path:
    """The sample's head-camera video with a few dozen random bytes overwritten past its first tenth."""
    rng = np.random.default_rng([24, seed])
    data = bytearray(SAMPLE_VIDEO.read_bytes())
    for _ in range(int(rng.integers(5, 60))):
        data[int(rng.integers(len(data) // 10, len(data)))] = int(rng.integers(0, 256))
    dest.write_bytes(bytes(data))
    return dest


def test_ffmpeg_output_goes_into_the_error_not_onto_stderr(tmp_path, capfd):
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(SAMPLE_VIDEO.read_bytes()[: SAMPLE_VIDEO.stat().st_size // 2])
    for call in (probe_video, FrameReader):
        with pytest.raises(InputError) as ei:
            call(cut)
        msg = str(ei.value)
        assert str(cut) in msg and "moov atom not found" in msg and "\n" not in msg, msg
    out, err = capfd.readouterr()
    assert "moov" not in out + err and err == ""


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_damaged_video_is_decoded_with_a_warning(tmp_path, capfd, seed):
    video = _flipped(tmp_path / f"flip{seed}.mp4", seed)
    probe = probe_video(video)
    with FrameReader(video, timestamps_s=probe.timestamps_s) as reader:
        _, frames = reader(0, probe.n_frames)
        warning = reader.damage_warning()
    assert 0 < frames.shape[0] <= probe.n_frames   # a damaged frame can end the stream early
    # a frame's data was overwritten: the decoder says so, and the reader keeps what it said
    assert warning is not None and "FFmpeg reported" in warning and "damaged" in warning, warning
    assert reader.messages and all("\n" not in m and "@ 0x" not in m for m in reader.messages)
    assert capfd.readouterr().err == ""


def test_an_intact_video_reports_no_damage(capfd):
    probe = probe_video(SAMPLE_VIDEO)
    with FrameReader(SAMPLE_VIDEO, timestamps_s=probe.timestamps_s) as reader:
        reader(0, probe.n_frames)
        assert reader.damage_warning() is None and reader.messages == []
    assert not any("FFmpeg" in w for w in probe.warnings)
    assert capfd.readouterr().err == ""


def test_native_output_catches_descriptor_2_and_gives_it_back(capfd):
    import os

    from gazepipe.io.native_log import native_output

    with native_output() as said:
        os.write(2, b"[mpeg4 @ 0x55d5d9062380] illegal dc vlc\n\x1b[31mred\x1b[0m\nillegal dc vlc\n")
        with native_output() as inner:   # nested: the outer block catches it
            os.write(2, b"second\n")
    assert said == ["illegal dc vlc", "\\x1b[31mred\\x1b[0m", "second"] and inner == []
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"
