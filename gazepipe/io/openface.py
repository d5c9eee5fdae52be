"""OpenFace FeatureExtraction CSV reader (2.x and older layouts).

Columns are picked by name after stripping spaces (headers written with ", " separators and Windows builds that
pad values with spaces both occur). OpenFace's ``gaze_0_*`` is the eye on the image's left, which is the subject's
RIGHT eye; ``gaze_1_*`` is the subject's left eye. Gaze vectors are in camera axes: x right, y down, z forward.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gazepipe.errors import InputError
from gazepipe.io.limits import MAX_FRAME
from gazepipe.io.tracks import read_columns
from gazepipe.model import EyeTrack
from gazepipe.timebase import implausible_rate, video_frames

__all__ = ["EyeTrack", "read_openface"]

_GAZE = [f"gaze_{e}_{a}" for e in (0, 1) for a in "xyz"]
_REQUIRED = ["frame", "timestamp", "success", "confidence", *_GAZE]
_OPTIONAL = ["face_id", "AU45_c", "AU45_r", "gaze_angle_x"]


#: largest gaze-vector component taken as a direction (OpenFace writes unit vectors)
_MAX_GAZE_COMPONENT = 10.0


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        n = np.linalg.norm(v, axis=1, keepdims=True)
        return np.where(n > 0, v / n, np.nan)


def _clock_problem(time_s: np.ndarray, frame: np.ndarray) -> str | None:
    """Why the video rate the timestamps give (as the eyes stage measures it, :func:`video_frames`) cannot be a
    face camera's, with what to do; None when it can."""
    if time_s.size < 2:
        return None
    _, period = video_frames(time_s, frame)
    odd = implausible_rate(1.0 / period, "video") if np.isfinite(period) and period > 0 else None
    if odd is None:
        return None
    step = float(np.median(np.diff(time_s)))
    return (f"timestamps step {step * 1000:.4g} ms ({odd}): not the video's clock, yet they place the eyes on "
            "the mocap frames; run FeatureExtraction on the video file itself (-f), or give an image sequence "
            "its frame rate")


def read_openface(path: str | Path) -> EyeTrack:
    """Read an OpenFace FeatureExtraction CSV.

    Parameters
    ----------
    path : the CSV file.

    Returns
    -------
    EyeTrack with both eyes mapped to the subject's own left/right, unit gaze vectors in camera axes, times in
    seconds on the video clock, and blinks from ``AU45_c == 1`` (or ``AU45_r >= 1`` when ``AU45_c`` is absent).
    Rows with ``success == 0`` are kept and flagged. When several faces are tracked (``face_id``), face 0 is kept
    (else the most frequent one) and a warning says so. Timestamps whose rate no face camera has
    (:data:`~gazepipe.timebase.PLAUSIBLE_HZ`, e.g. 1 ms steps: 1000 Hz) are kept, with a warning saying what to
    do.

    Raises
    ------
    InputError : missing file, empty file, missing required column, empty or non-numeric cell, frames that do
        not increase. One line, naming the file and the column.
    """
    path = Path(path)
    what = "OpenFace CSV"
    cols, warnings = read_columns(path, _REQUIRED, _OPTIONAL, what=what)
    layout = "openface2" if ("face_id" in cols or "gaze_angle_x" in cols) else "openface_legacy"

    keep = None
    face_id = None
    if "face_id" in cols:
        ids = cols["face_id"].astype(np.int64)
        uniq, counts = np.unique(ids, return_counts=True)
        if uniq.size > 1:
            face_id = 0 if 0 in uniq else int(uniq[np.argmax(counts)])
            keep = ids == face_id
            seen = ", ".join(f"{u}: {c} rows" for u, c in zip(uniq, counts, strict=True))
            warnings.append(f"{uniq.size} faces tracked ({seen}); kept face_id {face_id}")
        else:
            face_id = int(uniq[0])
    if keep is not None:
        cols = {k: v[keep] for k, v in cols.items()}

    frame = cols["frame"]
    if not np.all(frame == np.round(frame)):
        raise InputError(path, f"{what}: frame numbers are not whole numbers", key="frame")
    out = (frame < 0) | (frame > MAX_FRAME)
    if out.any():
        r = int(np.argmax(out)) + 1
        raise InputError(path, f"{what}: frame number {frame[r - 1]:.10g} in data row {r} is out of range "
                               f"(0 to {MAX_FRAME})", key="frame")
    frame = frame.astype(np.int64)
    steps = np.diff(frame)
    if np.any(steps <= 0):
        r = int(np.flatnonzero(steps <= 0)[0]) + 2
        raise InputError(path, f"{what}: frame numbers do not increase at data row {r}", key="frame")
    jumps = np.flatnonzero(steps > 1)
    if jumps.size:
        r = int(jumps[0])
        warnings.append(f"{int((steps[jumps] - 1).sum())} dropped video frame(s) in {jumps.size} gap(s) "
                        f"(first after frame {frame[r]}, data row {r + 1}): bridged by the eye gap rules")
    time_s = cols["timestamp"].astype(np.float64)
    if np.any(np.diff(time_s) < 0):
        r = int(np.flatnonzero(np.diff(time_s) < 0)[0]) + 2
        raise InputError(path, f"{what}: timestamps go backwards at data row {r}", key="timestamp")

    flat = int(np.count_nonzero(np.diff(time_s) == 0))
    if flat:
        warnings.append(f"{flat} timestamp step(s) of zero (image sequence or broken video clock?)")
    odd = _clock_problem(time_s, frame)
    if odd is not None:
        warnings.append(odd)

    success = cols["success"] >= 0.5
    n_fail = int((~success).sum())
    if n_fail:
        warnings.append(f"{n_fail} of {success.size} rows have success == 0 (kept, flagged)")
    g0 = np.stack([cols[f"gaze_0_{a}"] for a in "xyz"], axis=1)
    g1 = np.stack([cols[f"gaze_1_{a}"] for a in "xyz"], axis=1)
    # OpenFace writes unit vectors; a component past the bound is a corrupted cell, not a direction
    absurd = (np.abs(g0) > _MAX_GAZE_COMPONENT).any(axis=1) | (np.abs(g1) > _MAX_GAZE_COMPONENT).any(axis=1)
    if absurd.any():
        r = int(np.argmax(absurd)) + 1
        warnings.append(f"{int(absurd.sum())} rows have a gaze component beyond +-{_MAX_GAZE_COMPONENT:g} "
                        f"(corrupted values; first at data row {r}): flagged as failed")
        success = success & ~absurd
        g0[absurd] = g1[absurd] = 0.0

    if "AU45_c" in cols:
        blink = cols["AU45_c"] >= 0.5
    elif "AU45_r" in cols:
        blink = cols["AU45_r"] >= 1.0
        warnings.append("no AU45_c column: blinks taken from AU45_r >= 1")
    else:
        blink = None
        warnings.append("no AU45_c or AU45_r column: no blink information")

    return EyeTrack(
        time_s=time_s,
        frame=frame,
        success=success,
        confidence=cols["confidence"].astype(np.float64),
        gaze_left=_unit(g1),   # gaze_1: the eye on the image's right = the subject's left eye
        gaze_right=_unit(g0),  # gaze_0: the eye on the image's left = the subject's right eye
        blink=blink,
        face_id=face_id,
        layout=layout,
        warnings=warnings,
    )
