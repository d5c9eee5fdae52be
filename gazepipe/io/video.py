"""Video probing and windowed frame decoding (OpenCV).

Frame times come from the container (the frames' own presentation timestamps), never from the nominal rate: a
camera labelled 60 fps may run at 59.94 or drop frames. :func:`probe_video` walks the stream's undecoded
packets to collect them. :class:`FrameReader` decodes windows of frames through one open capture, for the
sync stage to look at the frames around each clap of a take (grabbing forward to a window a little ahead,
seeking to one further away); :func:`read_frames` decodes a single window.
"""

from __future__ import annotations

from pathlib import Path
from typing import NoReturn

import cv2
import numpy as np

from gazepipe.errors import InputError
from gazepipe.io.native_log import native_output, summarise
from gazepipe.model import VideoProbe

__all__ = ["FrameReader", "VideoProbe", "probe_video", "read_frames"]


_N_THREADS = getattr(cv2, "CAP_PROP_N_THREADS", None)


def _open(path: Path, threads: int | None = 1) -> cv2.VideoCapture:
    """Open a video; ``threads`` decoding threads when the FFmpeg backend takes the setting (None: its default).

    One thread by default: takes already run in parallel, and a small head-camera picture decodes faster on one
    thread than handed between several (about 1.5x at 128x96). Call it inside :func:`native_output`: what
    FFmpeg says of a file it cannot open goes into the error.
    """
    if not path.exists():
        raise InputError(path, "no such file")
    if path.is_dir():
        raise InputError(path, "is a folder, not a video file")
    if path.stat().st_size == 0:
        raise InputError(path, "empty file")
    cap = None
    if threads is not None and _N_THREADS is not None:
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, [_N_THREADS, int(threads)])
        if not cap.isOpened():
            cap.release()
            cap = None
    if cap is None:
        cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise InputError(path, "OpenCV cannot open this video (unknown container or codec, or a damaged file)")
    return cap


def _damage(said: list[str], when: str) -> str:
    """A warning that FFmpeg reported problems with the file while ``when``."""
    return f"FFmpeg reported {len(said)} problem(s) {when}, frames may be damaged: {summarise(said)}"


def _raise_with(err: InputError, said: list[str]) -> NoReturn:
    """Re-raise ``err`` with what FFmpeg said added to its problem."""
    if said:
        raise InputError(err.path, f"{err.problem} (FFmpeg: {summarise(said, 1)})", key=err.key,
                         take=err.take) from err
    raise err


def _said(fn, *args):
    """``(fn(*args), what FFmpeg printed meanwhile)``; an InputError raised by ``fn`` comes back with what
    FFmpeg said of the file added to it."""
    failed: InputError | None = None
    with native_output() as said:
        try:
            result = fn(*args)
        except InputError as err:
            failed = err
    if failed is not None:
        _raise_with(failed, said)
    return result, said


def _walk(path: Path, raw: bool) -> tuple[list[float], float, int, int, int] | None:
    """Grab every frame; return (POS_MSEC per frame, fps, width, height, declared frame count).

    ``raw`` asks OpenCV's FFmpeg backend for the undecoded packets (``CAP_PROP_FORMAT = -1``): no picture is
    decoded at all, and the packets' own timestamps come back. ``None`` when raw mode is not available.
    """
    cap = _open(path)  # inside the caller's native_output()
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
    walked, said = _said(_walk, path, True)
    if walked is not None:
        ms = np.sort(np.asarray(walked[0], dtype=np.float64))  # packets come in decode order
        usable = ms.size > 0 and (ms.size == walked[4] or walked[4] <= 0) and bool(np.all(np.diff(ms) > 0))
    if walked is None or not usable:
        source = "decoded"
        walked, more = _said(_walk, path, False)
        said += [m for m in more if m not in said]
        ms = np.asarray(walked[0], dtype=np.float64)
    _, fps, width, height, header_frames = walked
    if ms.size == 0:
        _raise_with(InputError(path, "no readable frames in the video"), said)
    warnings: list[str] = [_damage(said, "reading the video")] if said else []
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


class FrameReader:
    """The frames of one video through one open capture, decoded in stream order where possible.

    Calling it with ``(start, stop)`` returns the frames [start, stop) as :func:`read_frames` does: it is a
    ``read_window`` for the sync stage, which asks for a few windows per take, mostly in increasing order. A
    window starting at the next frame costs only its decoding; one a little further ahead (at most ``max_skip``
    frames) is reached by grabbing the frames in between (decoded, never converted); one behind or further ahead
    by seeking, checked against the probe's timestamps when they are given (an inexact seek falls back to
    grabbing from the start, and seeks are not trusted again in this file).

    Parameters
    ----------
    path : the video.
    gray, scale : as for :func:`read_frames`.
    timestamps_s : the probe's timestamps, to check seeks.
    max_skip : most frames grabbed to reach a window ahead rather than seeking (a seek decodes from the
        previous key frame anyway).
    threads : decoding threads (None: the backend's default, usually one per core). The frames are the same.

    Use it as a context manager, or call :meth:`close`. What FFmpeg reports while decoding (a damaged frame)
    is kept in :attr:`messages`; :meth:`damage_warning` puts it in words.

    Raises
    ------
    InputError : unreadable file (when opened), or a window starting past the last frame (when called).
    """

    def __init__(self, path: str | Path, *, gray: bool = True, scale: float = 1.0,
                 timestamps_s: np.ndarray | None = None, max_skip: int = 300, threads: int | None = 1) -> None:
        if not scale > 0:
            raise ValueError(f"scale must be positive, got {scale}")
        self.path = Path(path)
        self.gray, self.scale, self.max_skip = gray, float(scale), int(max_skip)
        self.timestamps_s = None if timestamps_s is None else np.asarray(timestamps_s, dtype=np.float64)
        ts = self.timestamps_s
        self._tolerance = 0.5 * float(np.median(np.diff(ts))) if ts is not None and ts.size > 1 else 1e-3
        self.threads = threads
        self._cap: cv2.VideoCapture | None = None
        self._cap, self.messages = _said(_open, self.path, threads)
        self._next: int | None = 0  # the frame the next grab() returns; None when unknown
        self._seek_ok = True

    def damage_warning(self) -> str | None:
        """A warning naming what FFmpeg reported while decoding, or None when it said nothing."""
        return _damage(self.messages, "decoding frames") if self.messages else None

    def __enter__(self) -> FrameReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __call__(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """(timestamps (M,) s, frames (M, H, W) or (M, H, W, 3) uint8) of the frames [start, stop)."""
        if start < 0 or stop <= start:
            raise ValueError(f"need 0 <= start < stop, got [{start}, {stop})")
        if self._cap is None:
            raise ValueError(f"{self.path}: the reader is closed")
        failed: InputError | None = None
        with native_output() as said:
            try:
                window = self._window(start, stop)
            except InputError as err:
                failed = err
        self.messages += [m for m in said if m not in self.messages]
        if failed is not None:   # with what FFmpeg said of every window so far
            _raise_with(failed, self.messages)
        return window

    def _capture(self) -> cv2.VideoCapture:
        """The open capture (the methods below run only under ``__call__``, which checked the reader is open)."""
        assert self._cap is not None
        return self._cap

    def _window(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        pending = self._reach(start)  # the timestamp of frame ``start`` when a seek check already grabbed it
        cap = self._capture()
        ts: list[float] = []
        frames: list[np.ndarray] = []
        interp = cv2.INTER_AREA if self.scale < 1 else cv2.INTER_LINEAR
        for i in range(start, stop):
            if pending is None:
                if not cap.grab():
                    self._next = None
                    break
                t = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            else:
                t, pending = pending, None
            good, img = cap.retrieve()
            if not good:
                self._next = None
                break
            self._next = i + 1
            if self.gray and img.ndim == 3:
                img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            if self.scale != 1.0:
                img = cv2.resize(img, None, fx=self.scale, fy=self.scale, interpolation=interp)
            ts.append(t)
            frames.append(img)
        if not frames:
            raise InputError(self.path, f"no frame at index {start} (the video is shorter)")
        return np.asarray(ts, dtype=np.float64), np.stack(frames).astype(np.uint8, copy=False)

    def _grab(self, n: int) -> None:
        cap = self._capture()
        for _ in range(n):  # grab() skips the colour conversion and the copy to numpy
            if not cap.grab():
                self._next = None
                return
            assert self._next is not None   # known whenever _reach grabs forward
            self._next += 1

    def _reach(self, start: int) -> float | None:
        """Put the capture before frame ``start``; returns that frame's timestamp when a checked seek has
        already grabbed it (the next retrieve() returns it), else None (the next grab() returns it)."""
        ahead = None if self._next is None else start - self._next
        if ahead is not None and 0 <= ahead <= self.max_skip:
            self._grab(ahead)
            return None
        if self._seek_ok and start > 0:
            checked = self._seek(start)
            if checked is not False:
                self._next = start
                return checked
            self._seek_ok = False
            self._next = None  # wherever the inexact seek left the capture
        if self._next is None or start < self._next:
            self._capture().release()
            self._cap = _open(self.path, self.threads)
            self._next = 0
        self._grab(start - self._next)
        return None

    def _seek(self, start: int) -> float | None | bool:
        """Seek to frame ``start``: False when the seek cannot be trusted; else None, or the frame's timestamp
        when the check against the probe's timestamps grabbed it."""
        cap = self._capture()
        if not cap.set(cv2.CAP_PROP_POS_FRAMES, float(start)):
            return False
        ts = self.timestamps_s
        if ts is None or start >= ts.size:
            return None  # nothing to check against (past the end: the call reports the short video)
        if not cap.grab():
            return False
        got = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        return got if abs(got - ts[start]) <= self._tolerance else False  # within half a frame


def read_frames(path: str | Path, start: int, stop: int, *, gray: bool = True, scale: float = 1.0,
                timestamps_s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Decode the frames [start, stop) of a video, and only those (opening it for this window alone; a caller
    reading several windows of one video should keep a :class:`FrameReader` instead).

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
    if start < 0 or stop <= start:
        raise ValueError(f"need 0 <= start < stop, got [{start}, {stop})")
    with FrameReader(path, gray=gray, scale=scale, timestamps_s=timestamps_s, max_skip=0) as reader:
        return reader(start, stop)
