"""Video probing and windowed frame decoding (OpenCV).

Frame times come from the container (the frames' own presentation timestamps), never from the nominal rate: a
camera labelled 60 fps may run at 59.94 or drop frames. :func:`probe_video` walks the stream's undecoded
packets to collect them; :func:`read_frames` seeks to a window and decodes
only that window, for the sync stage to look at the frames around a clap.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gazepipe.errors import InputError
from gazepipe.io.tracks import VideoProbe

__all__ = ["VideoProbe", "probe_video", "read_frames"]


def _open(path: Path) -> cv2.VideoCapture:
    if not path.exists():
        raise InputError(path, "no such file")
    if path.is_dir():
        raise InputError(path, "is a folder, not a video file")
    if path.stat().st_size == 0:
        raise InputError(path, "empty file")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise InputError(path, "OpenCV cannot open this video (unknown container or codec, or a damaged file)")
    return cap


def _walk(path: Path, raw: bool) -> tuple[list[float], float, int, int, int] | None:
    """Grab every frame; return (POS_MSEC per frame, fps, width, height, declared frame count).

    ``raw`` asks OpenCV's FFmpeg backend for the undecoded packets (``CAP_PROP_FORMAT = -1``): no picture is
    decoded at all, and the packets' own timestamps come back. ``None`` when raw mode is not available.
    """
    cap = _open(path)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        header_frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        if raw and not cap.set(cv2.CAP_PROP_FORMAT, -1):
            return None
        ms: list[float] = []
        while cap.grab():
            ms.append(cap.get(cv2.CAP_PROP_POS_MSEC))
    finally:
        cap.release()
    return ms, fps, width, height, header_frames


def probe_video(path: str | Path) -> VideoProbe:
    """Frame count, nominal rate, size and per-frame timestamps of a video, without decoding pictures.

    Timestamps are ``CAP_PROP_POS_MSEC`` per frame, in seconds, 0 at the stream's start, in presentation order.
    They are read from the undecoded packets (about a hundred times faster than grabbing decoded frames); when
    that is not possible or does not agree with the container's frame count, every frame is grabbed (decoded,
    not converted) instead. When the container gives no usable timestamps (not increasing), they fall back to
    frame index / nominal rate, with a warning.

    Raises
    ------
    InputError : missing, empty or unreadable file, or a video without a single frame.
    """
    path = Path(path)
    source = "packets"
    walked = _walk(path, raw=True)
    if walked is not None:
        ms = np.sort(np.asarray(walked[0], dtype=np.float64))  # packets come in decode order
        usable = ms.size > 0 and (ms.size == walked[4] or walked[4] <= 0) and bool(np.all(np.diff(ms) > 0))
    if walked is None or not usable:
        source = "decoded"
        walked = _walk(path, raw=False)
        ms = np.asarray(walked[0], dtype=np.float64)
    _, fps, width, height, header_frames = walked
    if ms.size == 0:
        raise InputError(path, "no readable frames in the video")
    warnings: list[str] = []
    ts = ms / 1000.0
    if ts.size > 1 and not np.all(np.diff(ts) > 0):
        if fps > 0:
            warnings.append("the container's frame timestamps do not increase; using frame index / nominal fps")
            ts = np.arange(ts.size, dtype=np.float64) / fps
            source = "nominal"
        else:
            raise InputError(path, "the video has neither increasing frame timestamps nor a frame rate")
    if header_frames and header_frames != ts.size:
        warnings.append(f"the container declares {header_frames} frames, {ts.size} were found")
    if fps > 0 and ts.size > 2:
        real = (ts.size - 1) / (ts[-1] - ts[0])
        if abs(real / fps - 1.0) > 0.001:
            warnings.append(f"nominal {fps:g} fps, but the frame timestamps give {real:.4f} fps")
    return VideoProbe(n_frames=int(ts.size), nominal_fps=fps, timestamps_s=ts, width=width, height=height,
                      header_frames=header_frames, timestamp_source=source, warnings=warnings)


def read_frames(path: str | Path, start: int, stop: int, *, gray: bool = True, scale: float = 1.0,
                timestamps_s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Decode the frames [start, stop) of a video, and only those.

    Parameters
    ----------
    path : the video.
    start, stop : half-open frame range (0-based, in stream order). ``stop`` past the end is clipped.
    gray : return single-channel luminance frames (else BGR).
    scale : resize factor applied to each frame (area interpolation when shrinking).
    timestamps_s : the probe's timestamps; when given, the seek is checked against them and, if the container
        seeked inexactly, the window is reached by grabbing frame by frame from the start instead.

    Returns
    -------
    timestamps : (M,) float64 seconds of the frames returned.
    frames : (M, H, W) uint8 (gray) or (M, H, W, 3) uint8 (BGR).

    Raises
    ------
    InputError : unreadable file, or ``start`` past the last frame.
    """
    path = Path(path)
    if start < 0 or stop <= start:
        raise ValueError(f"need 0 <= start < stop, got [{start}, {stop})")
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    cap = _open(path)
    try:
        ok = _seek(cap, start, timestamps_s)
        if not ok:
            cap.release()
            cap = _open(path)
            for _ in range(start):  # grab() skips the colour conversion and the copy to numpy
                if not cap.grab():
                    break
        ts: list[float] = []
        frames: list[np.ndarray] = []
        for _ in range(stop - start):
            if not cap.grab():
                break
            ts.append(cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0)
            good, img = cap.retrieve()
            if not good:
                break
            if gray and img.ndim == 3:
                img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            if scale != 1.0:
                interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
                img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=interp)
            frames.append(img)
    finally:
        cap.release()
    if not frames:
        raise InputError(path, f"no frame at index {start} (the video is shorter)")
    return np.asarray(ts[: len(frames)], dtype=np.float64), np.stack(frames).astype(np.uint8, copy=False)


def _seek(cap: cv2.VideoCapture, start: int, timestamps_s: np.ndarray | None) -> bool:
    """Seek so that the next grab() returns frame ``start``; False when the seek cannot be trusted."""
    if start == 0:
        return True
    if not cap.set(cv2.CAP_PROP_POS_FRAMES, float(start)):
        return False
    if timestamps_s is None:
        return True
    ts = np.asarray(timestamps_s, dtype=np.float64)
    if start >= ts.size:
        return True  # nothing to check against; read_frames reports the short video
    # peek at the next frame's time, then seek back to it
    if not cap.grab():
        return False
    got = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
    half = 0.5 * float(np.median(np.diff(ts))) if ts.size > 1 else 1e-3
    if abs(got - ts[start]) > half:
        return False
    return bool(cap.set(cv2.CAP_PROP_POS_FRAMES, float(start)))
