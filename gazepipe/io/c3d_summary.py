"""``gazepipe inspect`` of a C3D file in one streaming pass: what :func:`gazepipe.io.c3d.read_c3d_info` would
report, in memory that does not grow with the file.

A well-formed capture of two million frames is a gigabyte on disk and several in memory once decoded to
float64 millimetres. Its summary (gap share per marker, corrupt samples, markers never seen, bit-identical
copies) needs no frame twice, so it is gathered chunk by chunk: counts per marker, the first corrupt sample,
and a digest per marker for the copies. The result is the same as the full read's (tested on every corpus
file), and :func:`summarise_c3d` is what inspect uses whenever the full read would hold more than
:data:`STREAM_OVER_BYTES`.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from gazepipe.errors import printable
from gazepipe.io import c3d as _c3d
from gazepipe.io.limits import MAX_ABS_MM, coordinate_span

__all__ = ["STREAM_OVER_BYTES", "c3d_storage", "summarise_c3d"]

#: inspect streams a C3D whose decoded markers (float64 mm) would take more than this
STREAM_OVER_BYTES = 256 << 20


def summarise_c3d(path: str | Path, *, default_units: str = "mm") -> dict[str, Any] | None:
    """The C3D part of :func:`gazepipe.io.capture.inspect_capture`, read in one pass of bounded memory.

    Returns the summary dict (keys as ``inspect_capture``'s), or None when the
    file's parameters disagree with its header and it is small enough for the full read's cross-check with the
    ``c3d`` package (the caller then reads it whole). Raises :class:`InputError` as the full read does.
    """
    def body(p: Path, fh, meta, lay) -> dict[str, Any] | None:
        too_big = lay.n_frames * lay.n_points * 3 * 8 > _c3d._PYC3D_MAX_BYTES
        if not lay.ezc3d_safe and not too_big:
            return None
        return _summarise(p, fh, meta, lay, default_units)

    return _c3d.read_guarded(path, body)


def _summarise(p: Path, fh, meta, lay, default_units: str) -> dict[str, Any]:
    notes: list[str] = list(lay.notes)
    units, to_mm, raw_labels, is_model, marker_idx = _c3d._points(p, meta, lay, default_units)
    t, n_m = lay.n_frames, marker_idx.size
    if not lay.ezc3d_safe:
        notes.append("the parameters disagree with the header (check ANALOG:RATE, POINT:USED) and the file "
                     "is too large for a cross-check with the c3d package; decoded from the header layout")

    # per marker: gaps by the residual word or a non-finite coordinate; samples at exactly (0, 0, 0) that
    # are not such gaps (gaps too when the marker is seen elsewhere); samples seen away from the origin;
    # corrupt (far) samples that are not gaps; whether one valid sample is away from the origin
    n_gap = np.zeros(n_m, dtype=np.int64)
    n_zero = np.zeros(n_m, dtype=np.int64)
    n_far = np.zeros(n_m, dtype=np.int64)
    nonzero = np.zeros(n_m, dtype=bool)
    seen = np.zeros(n_m, dtype=bool)
    infinite, first_inf, first_far = 0, None, None
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)     # the valid samples' span (see coordinate_span)
    digests = [hashlib.blake2b(digest_size=16) for _ in range(n_m)]
    for a, n, buf in _c3d._frame_chunks(p, fh, lay):
        xyz, word4 = _c3d._decode_frames(buf, lay, n)
        g, z = _c3d._gap_parts(xyz[:, marker_idx], word4[:, marker_idx], lay.is_float)
        chunk = xyz[:, marker_idx] * to_mm
        del xyz, word4
        inf = _c3d._any3(np.isinf(chunk))
        if inf.any():
            infinite += int(np.count_nonzero(inf))
            if first_inf is None:
                first_inf = divmod(int(np.argmax(inf.ravel())) + a * n_m, n_m)
        far = _c3d._any3(np.abs(chunk) > MAX_ABS_MM) & ~g
        if far.any() and first_far is None:
            first_far = divmod(int(np.argmax(far.ravel())) + a * n_m, n_m)
        zero_only = z & ~g
        n_gap += g.sum(axis=0)
        n_zero += zero_only.sum(axis=0)
        n_far += far.sum(axis=0)
        nonzero |= (~g & ~z).any(axis=0)
        seen |= (~g & ~z & ~far).any(axis=0)
        c_lo, c_hi = coordinate_span(chunk, ~g & ~far)
        lo, hi = np.fmin(lo, c_lo), np.fmax(hi, c_hi)
        # what the full read compares for copies, in a form that needs no other chunk: coordinates (0 at
        # gaps) and the two gap masks
        coords = np.where(g[..., None], 0.0, chunk)
        for k in range(n_m):
            digests[k].update(coords[:, k].tobytes())
            digests[k].update(np.packbits(g[:, k]).tobytes())
            digests[k].update(np.packbits(z[:, k]).tobytes())
        del chunk, g, z, coords

    labels, renamed = _c3d.make_unique([raw_labels[i] for i in marker_idx])
    if renamed:
        notes.append(_c3d._list_note("empty or duplicate labels renamed",
                                     [f"{old!r} -> {printable(new)}" for _, old, new in renamed]))
    n_valid = t - n_gap - np.where(nonzero, n_zero, 0) - n_far
    if infinite and first_inf is not None:
        notes.append(f"{infinite} samples with an infinite coordinate made gaps (first at frame "
                     f"{lay.first_frame + first_inf[0]}, marker {printable(labels[first_inf[1]])})")
    if first_far is not None:
        cols = np.flatnonzero(n_far)
        notes.append(f"{int(n_far.sum())} samples farther than {MAX_ABS_MM:,.0f} mm from the origin (corrupted "
                     f"values) made gaps (first at frame {lay.first_frame + first_far[0]}, marker "
                     f"{printable(labels[first_far[1]])}), in "
                     + _c3d._list_note("markers", [printable(labels[i]) for i in cols]))
    _c3d._check_span(p, lay, units, default_units, lo, hi, notes)
    at_origin = (n_valid > 0) & ~seen
    if at_origin.any():
        notes.append(_c3d._list_note("markers at exactly (0, 0, 0) in every valid sample (never seen?)",
                                     [printable(labels[i]) for i in np.flatnonzero(at_origin)]))
    if t * n_m and not n_valid.any():
        notes.append("every marker sample is invalid (100 % gaps)")
    elif t * n_m and (n_valid == t).all():
        notes.append("no marker sample is invalid (0 % gaps): check how this system writes gaps")
    buckets: dict[bytes, list[int]] = {}
    for k in np.flatnonzero(n_valid > 0).tolist():
        buckets.setdefault(digests[k].digest(), []).append(k)
    groups = sorted((g for g in buckets.values() if len(g) > 1), key=lambda g: g[0])
    if groups:
        notes.append(_c3d._list_note("groups of bit-identical trajectories",
                                     ["=".join(printable(labels[i]) for i in g) for g in groups], limit=6))
    rate = lay.stated_rate_hz
    gaps = 1.0 - n_valid / t
    return {
        "path": str(p), "format": "c3d", "reader": "numpy", "rate_hz": rate, "frames": t,
        "first_frame": lay.first_frame, "duration_s": t / rate, "units": units, "n_markers": n_m,
        "markers": [{"label": lab, "gap_fraction": float(g)} for lab, g in zip(labels, gaps, strict=True)],
        "model_outputs": [raw_labels[i].strip() for i in np.flatnonzero(is_model)],
        "duplicates": [[labels[i] for i in g] for g in groups],
        "warnings": notes,
        "processor": lay.processor, "storage": "float" if lay.is_float else "int",
        "analog_channels": lay.analog_channels,
    }


def c3d_storage(path: str | Path) -> dict[str, Any] | None:
    """How a C3D file stores its data, from its header and parameters only: ``processor`` (intel, dec, mips),
    ``storage`` (``int`` or ``float``), ``point_scale`` (POINT:SCALE as written: negative for float storage,
    where it scales only the residuals), ``analog_channels`` and ``analog_rate_hz`` (``None`` without analog
    channels or ANALOG:RATE). ``None`` when the metadata cannot be decoded (the full read says why)."""
    from gazepipe.io.c3d_meta import HEAD_BYTES, MetaError, parse_c3d_meta

    try:
        with open(path, "rb") as fh:
            meta = parse_c3d_meta(fh.read(HEAD_BYTES))
            lay = meta.layout(os.fstat(fh.fileno()).st_size)
    except (OSError, MetaError, ValueError):
        return None
    rate = meta.get_number("ANALOG", "RATE") if lay.analog_channels else None
    return {"processor": lay.processor, "storage": "float" if lay.is_float else "int",
            "point_scale": float(lay.scale), "analog_channels": int(lay.analog_channels),
            "analog_rate_hz": float(rate) if rate is not None and np.isfinite(rate) and rate > 0 else None}
