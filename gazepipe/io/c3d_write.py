"""C3D files written for the capture programs (``gazepipe export``): float storage, each sample's fourth word
as given, events and parameter groups.

A C3D sample is four words: X, Y, Z and a fourth word whose value, read as a 16-bit integer, holds the camera
mask in its high byte and the residual, in steps of ``|POINT:SCALE|`` mm, in its low byte (the C3D manual; the
real files of ``tests/data/corpus/c3d`` agree: Walking_Hybrid_2's high byte is 0x7F, seven cameras, in every
sample). Readers take a negative word for a gap and a residual of 0 for a sample not reconstructed from cameras
(filled, or modelled). ezc3d swaps the two bytes (its residual is the camera byte), so a measured sample
carries a non-zero value in both (:func:`measured_words`). :func:`write_c3d_points` writes the words it is
given bit for bit (ezc3d writes the file's structure; the words and the header's scale are set afterwards).

:func:`read_point_words` reads those words back from any C3D the readers of :mod:`gazepipe.io.c3d` accept, so
an export can keep each measured sample's own residual and camera mask.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gazepipe.errors import InputError
from gazepipe.io.c3d import _decode_frames, _frame_chunks, _model_points, read_guarded
from gazepipe.io.c3d_meta import parse_c3d_meta

#: the largest frame number a C3D header holds (16-bit words)
MAX_HEADER_FRAME = 65535


@dataclass(frozen=True)
class C3DEvent:
    """An entry of the EVENT group: its label, the source frame it marks, context and description."""

    label: str
    frame: int
    context: str = "General"
    description: str = ""


def word_bytes(words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The residual byte (low) and the camera byte (high) of each fourth word's 16-bit integer value; -1 for
    both where the word is negative or not finite (a gap)."""
    w = np.asarray(words, dtype=np.float64)
    ok = np.isfinite(w) & (w >= 0) & (w < 2.0**31)
    as_int = np.where(ok, w, 0).astype(np.int64)
    return np.where(ok, as_int & 0xFF, -1), np.where(ok, (as_int >> 8) & 0xFF, -1)


def measured_words(words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fourth words every reader takes for a measured sample: where a non-negative word has no residual (its low
    byte 0) or no camera (its high byte 0), that byte becomes 1, the other kept. Returns the words and the (T, M)
    mask of those given a stand-in.

    The C3D manual (and the ``c3d`` package, Vicon, QTM) read the residual from the low byte, ezc3d from the
    high byte: a word of 0 in either reads as "not reconstructed from cameras" to some reader, the mark of a
    filled sample. One step of ``|POINT:SCALE|`` and camera 1 is the smallest stand-in both can see."""
    low, high = word_bytes(words)
    stand_in = (low == 0) | (high == 0)
    value = np.maximum(high, 1) * 256 + np.maximum(low, 1)
    return np.where(stand_in, value.astype(np.float64), np.asarray(words, dtype=np.float64)), stand_in


def read_point_words(path: str | Path) -> tuple[np.ndarray, float]:
    """The fourth word of every marker sample of a C3D file (model outputs left out, markers in the order
    :func:`gazepipe.io.c3d.read_c3d` gives them): (T, M) float64 holding the stored value (the 16-bit integer for
    integer storage, the float for float storage); and ``|POINT:SCALE|``, the residual's step in the file's
    units."""
    def body(p: Path, fh, meta, lay) -> tuple[np.ndarray, float]:
        markers = np.flatnonzero(~_model_points(meta, meta.point_labels(lay.n_points)))
        out = np.empty((lay.n_frames, markers.size))
        for a, n, buf in _frame_chunks(p, fh, lay):
            _, word4 = _decode_frames(buf, lay, n)
            out[a: a + n] = word4[:, markers]
        return out, abs(float(lay.scale))
    return read_guarded(path, body)


def write_c3d_points(path: str | Path, labels: Sequence[str], xyz: np.ndarray, words: np.ndarray, *,
                     rate_hz: float, first_frame: int, scale: float, units: str = "mm",
                     events: Sequence[C3DEvent] = (),
                     groups: Mapping[str, Mapping[str, str | float | list[float]]] | None = None,
                     descriptions: Sequence[str] | None = None) -> None:
    """Write a float C3D file (Intel processor) of marker positions and their fourth words.

    Parameters
    ----------
    labels : the M point labels.
    xyz : (T, M, 3) positions in ``units``; written as float32 (NaN where the word is negative is fine).
    words : (T, M) fourth words, written as they are: negative for a gap (then the coordinates are written 0),
        else the 16-bit integer value camera mask * 256 + residual steps (0: not from cameras).
    rate_hz, first_frame : POINT:RATE and the header's first frame (source frame numbers, 1 - 65535).
    scale : POINT:SCALE, negative (float storage): ``|scale|`` is the residual's step in ``units``.
    events : EVENT group entries; times are (frame - 1) / rate (frame 1 at 0 s, as Vicon writes them).
    groups : further parameter groups, ``{group: {name: value}}`` (a value: a number, a text, or a list of
        numbers).
    descriptions : POINT:DESCRIPTIONS (default empty).

    Raises :class:`InputError` naming ``path`` when the frames do not fit a C3D header or the file cannot be
    written.
    """
    import ezc3d

    p = Path(path)
    pos = np.asarray(xyz, dtype=np.float64)
    word = np.asarray(words, dtype=np.float64)
    t, m = word.shape
    if pos.shape != (t, m, 3) or len(labels) != m:
        raise ValueError(f"{len(labels)} labels, positions {pos.shape} and words {word.shape} do not agree")
    if t == 0 or m == 0:
        raise InputError(p, "cannot write a C3D file without frames or markers")
    if not 1 <= first_frame <= MAX_HEADER_FRAME or first_frame + t - 1 > MAX_HEADER_FRAME:
        raise InputError(p, f"first frame {first_frame} and {t} frames do not fit a C3D header (frames "
                            f"1 - {MAX_HEADER_FRAME})")
    if not scale < 0:
        raise ValueError("a float C3D has a negative POINT:SCALE")
    gap = ~(word >= 0)
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = np.array([float(rate_hz)])
    c["parameters"]["POINT"]["SCALE"]["value"] = np.array([float(scale)])
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = tuple(descriptions or ["" for _ in labels])
    pts = np.ones((4, m, t))
    pts[:3] = np.where(gap[..., None] | ~np.isfinite(pos), 0.0, pos).transpose(2, 1, 0)
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = np.where(gap, -1.0, 0.0).T[None, :, :]
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, m, t), dtype=bool)
    c.add_parameter("POINT", "UNITS", units)
    c["header"]["points"]["first_frame"] = int(first_frame) - 1  # ezc3d counts from 0
    for e in events:
        seconds = (int(e.frame) - 1) / float(rate_hz)
        minutes = float(np.floor(seconds / 60.0))
        c.add_event(time=[minutes, seconds - 60.0 * minutes], context=e.context, label=e.label,
                    description=e.description, subject="")
    for group, params in (groups or {}).items():
        for name, value in params.items():
            c.add_parameter(group, name, value if isinstance(value, str)
                            else [float(v) for v in np.atleast_1d(np.asarray(value, dtype=np.float64))])
    try:
        c.write(str(p))
        _set_words(p, word, float(scale))
    except OSError as e:
        raise InputError(p, f"cannot write C3D file ({e.strerror or e})") from None
    except RuntimeError as e:     # ezc3d's own failures
        raise InputError(p, f"cannot write C3D file ({e})") from None


def _set_words(path: Path, words: np.ndarray, scale: float) -> None:
    """Set the fourth word of every sample of the float C3D file ezc3d wrote at ``path`` to ``words`` (T, M), and
    the header's scale to ``scale`` (ezc3d keeps -1 there whatever POINT:SCALE says)."""
    data = bytearray(path.read_bytes())
    meta = parse_c3d_meta(bytes(data))
    lay = meta.layout(len(data))
    if not lay.is_float or lay.processor != "intel":
        raise RuntimeError("ezc3d did not write Intel float storage")
    t, m = words.shape
    if (lay.n_frames, lay.n_points) != (t, m):
        raise RuntimeError(f"ezc3d wrote {lay.n_frames} frames of {lay.n_points} points, not {t} of {m}")
    struct.pack_into("<f", data, 12, scale)               # header words 7-8: the scale factor
    block = np.frombuffer(data, dtype="<f4", count=t * lay.frame_words, offset=lay.data_offset)
    block = block.reshape(t, lay.frame_words).copy()
    block[:, 3: 4 * m: 4] = words.astype("<f4")
    data[lay.data_offset: lay.data_offset + block.nbytes] = block.tobytes()
    path.write_bytes(bytes(data))
