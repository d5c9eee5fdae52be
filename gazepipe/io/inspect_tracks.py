"""What ``gazepipe inspect`` says about a file: marker captures (:func:`gazepipe.io.capture.inspect_capture`),
OpenFace eye-tracking CSVs and Live Link Face blendshape CSVs, each read with the reader the pipeline uses."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from gazepipe.arkit import ARKIT_NAMES, HEAD_NAMES, normalise_name
from gazepipe.errors import InputError
from gazepipe.io.c3d_summary import c3d_storage
from gazepipe.io.capture import inspect_capture, track_file_format
from gazepipe.io.livelinkface import read_livelinkface
from gazepipe.io.openface import read_openface
from gazepipe.io.signatures import not_a_capture
from gazepipe.io.tracks import read_header
from gazepipe.timebase import video_frames

__all__ = ["inspect_file", "inspect_livelinkface", "inspect_openface", "not_a_capture"]

#: what ``gazepipe inspect`` reads
READS = "inspect reads C3D, Vicon CSV, QTM TSV, wide CSV, OpenFace CSV and Live Link Face CSV"


#: a Live Link Face row counts as a blink when an eye's ``eyeBlink`` coefficient is above this
LLF_BLINK_ABOVE = 0.5


def inspect_file(path: str | Path, *, rate_hz: float | None = None, timecode_fps: float = 60.0,
                 min_confidence: float = 0.8) -> dict[str, Any]:
    """Summarise any file ``gazepipe inspect`` reads; its ``format`` key says which summary it is.

    ``rate_hz`` serves marker CSVs and Live Link Face CSVs (which carry no rate); ``timecode_fps`` is the rate
    a Live Link Face timecode counts; ``min_confidence`` is the OpenFace confidence a valid sample needs.
    A C3D's summary also has processor, storage, point_scale, analog_channels and analog_rate_hz
    (:func:`gazepipe.io.c3d_summary.c3d_storage`). Every problem with the file, a file that is not a capture
    (:func:`not_a_capture`) included, is an :class:`~gazepipe.errors.InputError` naming it.
    """
    what = not_a_capture(path)
    if what is not None:
        raise InputError(path, f"not a capture file ({what}; {READS})")
    kind = track_file_format(path)
    if kind == "openface":
        return inspect_openface(path, min_confidence=min_confidence)
    if kind == "livelinkface":
        return inspect_livelinkface(path, rate_hz=rate_hz, timecode_fps=timecode_fps)
    info = inspect_capture(path, rate_hz=rate_hz)
    if info.get("format") == "c3d":
        info.update(c3d_storage(path) or {})
    return info


def _share(mask: np.ndarray) -> float | None:
    return float(np.count_nonzero(mask)) / mask.size if mask.size else None


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def inspect_openface(path: str | Path, *, min_confidence: float = 0.8) -> dict[str, Any]:
    """Summarise an OpenFace FeatureExtraction CSV as the eyes stage sees it (SPEC §3.5).

    Keys: path, format (``openface``), layout, rows, rate_hz and frame_period_s (from the frame numbers and
    timestamps, as the eyes stage estimates them; ``None`` when the timestamps never advance), duration_s (the
    video frames spanned times the period), missing_frames (video frames without a row), face_id,
    success_share, valid_share and valid_rule (``success == 1`` and ``confidence >= min_confidence``),
    blink_share and blink_rule (the reader's blinks, which the eyes stage masks: ``AU45_c == 1``, else
    ``AU45_r >= 1``; ``None`` without an AU45 column), warnings.
    """
    p = Path(path)
    eye = read_openface(p)
    header = set(read_header(p))
    n = eye.n_frames
    _, period = video_frames(eye.time_s, eye.frame)
    spanned = int(eye.frame[-1] - eye.frame[0]) + 1 if n else 0
    blink_rule = "AU45_c == 1" if "AU45_c" in header else "AU45_r >= 1" if "AU45_r" in header else None
    return {
        "path": str(p),
        "format": "openface",
        "layout": eye.layout,
        "rows": n,
        "rate_hz": _finite_or_none(1.0 / period),
        "frame_period_s": _finite_or_none(period),
        "duration_s": _finite_or_none(spanned * period),
        "missing_frames": spanned - n,
        "face_id": eye.face_id,
        "success_share": _share(eye.success),
        "valid_share": _share(eye.success & (eye.confidence >= min_confidence)),
        "valid_rule": f"success == 1 and confidence >= {min_confidence:g}",
        "blink_share": None if eye.blink is None else _share(eye.blink),
        "blink_rule": blink_rule,
        "warnings": list(eye.warnings),
    }


def inspect_livelinkface(path: str | Path, *, rate_hz: float | None = None,
                         timecode_fps: float = 60.0) -> dict[str, Any]:
    """Summarise a Live Link Face CSV as the face stage reads it.

    Keys: path, format (``livelinkface``), rows, rate_hz (given, else estimated from the timecode: a warning
    says so), frame_period_s, duration_s (capture frames spanned over the rate), timecode_fps, first_timecode,
    dropped_frames, blendshape_count, lost_rows (rows written while tracking was lost: ``BlendShapeCount`` 0 and no
    values), valid_share and valid_rule (the file has no validity flag: a row is counted valid when it holds
    values and some blendshape is not zero; ARKit writes all zeros when it loses the face),
    blink_share (either eye), blink_left_share, blink_right_share and blink_rule (``eyeBlinkLeft`` /
    ``eyeBlinkRight`` above :data:`LLF_BLINK_ABOVE`), head_columns (the head yaw, pitch and roll columns are
    there), head_tracking (they are there and vary), head_range_deg (yaw, pitch, roll: max − min in degrees,
    ``None`` without head tracking), warnings.
    """
    p = Path(path)
    face = read_livelinkface(p, rate_hz=rate_hz, timecode_fps=timecode_fps)
    n = face.n_frames
    spanned = int(face.frame_index[-1]) + 1 if n else 0
    values = np.asarray(face.values, dtype=np.float64)
    tracked = face.valid_rows
    left = tracked & (values[:, ARKIT_NAMES.index("eyeBlinkLeft")] > LLF_BLINK_ABOVE)
    right = tracked & (values[:, ARKIT_NAMES.index("eyeBlinkRight")] > LLF_BLINK_ABOVE)
    head_columns = set(HEAD_NAMES) <= {normalise_name(c) for c in read_header(p)}
    head = np.asarray(face.head, dtype=np.float64)
    known = head[np.isfinite(head).all(axis=1)]
    span = np.degrees(np.ptp(known, axis=0)) if known.shape[0] else np.zeros(len(HEAD_NAMES))
    tracking = bool(head_columns and known.shape[0] and np.any(span > 0))
    return {
        "path": str(p),
        "format": "livelinkface",
        "rows": n,
        "rate_hz": float(face.rate_hz),
        "frame_period_s": 1.0 / float(face.rate_hz),
        "duration_s": spanned / float(face.rate_hz),
        "timecode_fps": float(face.timecode_fps),
        "first_timecode": str(face.timecode[0]) if n else None,
        "dropped_frames": int(face.dropped_frames),
        "blendshape_count": face.blendshape_count,
        "lost_rows": int(np.count_nonzero(~tracked)),
        "valid_share": _share(tracked & np.any(values != 0, axis=1)),
        "valid_rule": "tracking not lost and some blendshape is not zero",
        "blink_share": _share(left | right),
        "blink_left_share": _share(left),
        "blink_right_share": _share(right),
        "blink_rule": f"eyeBlinkLeft or eyeBlinkRight > {LLF_BLINK_ABOVE:g}",
        "head_columns": head_columns,
        "head_tracking": tracking,
        "head_range_deg": ({"yaw": float(span[0]), "pitch": float(span[1]), "roll": float(span[2])}
                           if tracking else None),
        "warnings": list(face.warnings),
    }
