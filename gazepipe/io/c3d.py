"""C3D reader and writer.

Reading happens in three steps:

1. :func:`gazepipe.io.c3d_meta.parse_c3d_meta` decodes the header and the parameter section with bounded,
   pure-Python code and checks that the data section the header describes fits in the file. Nothing else touches a file that
   fails this step, so ezc3d (C++) never sees a truncated or malformed header or parameter section: on
   mutated files ezc3d was seen to hang (a description overrunning its record), to crash with SIGSEGV
   (ANALOG:SCALE or ANALOG:OFFSET missing or short) and to read truncated files without error.
2. The point block is decoded with numpy straight from the validated layout, a bounded number of frames at
   a time (``_decode_frames``), into the preallocated result: memory is the result, a few bytes of masks per
   sample and a buffer of a few megabytes, whatever the file's size (only the header and parameter section are
   read before the layout is checked against the file's size). This always provides the fourth word of every
   sample (residual and camera byte), which ezc3d does not return faithfully (it decodes integer residual
   words from the camera byte and hides 65535.0 words).
3. The coordinates are the numpy decode's: a file is decoded once. Only when the file's parameters disagree
   with its header (``ANALOG:RATE`` inconsistent with the header's analog word count, irregular layouts, MIPS
   processors) is a second reader asked, the pure-Python ``c3d`` package, and its coordinates are used only when
   they match the numpy decode; when they do not, the note says the header's layout was trusted. A file whose
   decode would exceed ``_PYC3D_MAX_BYTES`` is not handed to that package (it holds every frame as a separate
   array). (On every corpus file the test suite checks the numpy decode against ezc3d or ``c3d``.)

Gap rule (SPEC §1): a sample is invalid when its residual is negative, when any coordinate is NaN (or
infinite), when the residual word read as an unsigned 16-bit integer is 0xFFFF, or when it lies at exactly
(0, 0, 0) in a marker that has a non-zero valid sample elsewhere. A coordinate farther than
:data:`gazepipe.io.limits.MAX_ABS_MM` from the origin (in mm) is a corrupted value and becomes a gap too; infinite
and far samples are counted in a warning. POINT:RATE must lie within 1 Hz - 10 kHz.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np

from gazepipe.errors import InputError, printable
from gazepipe.io.c3d_meta import HEAD_BYTES, C3DMeta, Layout, MetaError, parse_c3d_meta
from gazepipe.io.limits import MAX_ABS_MM, coordinate_span, span_problem
from gazepipe.model import Markers, filled_samples
from gazepipe.timebase import unit_scale_to_mm

#: POINT parameters listing model outputs (angles, forces, …): those points are not markers.
#: ``MODELED_MARKERS`` is deliberately absent: modelled markers (joint centres) are positions in mm.
MODEL_OUTPUT_PARAMS: tuple[str, ...] = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS")

#: largest coordinate difference (mm) tolerated between a library's decode and the numpy decode
_AGREE_MM = 1e-3
#: bytes of the data section decoded at a time
_CHUNK_BYTES = 1 << 20
#: largest decode (bytes of float64 coordinates) handed to the pure-Python ``c3d`` package for a cross-check;
#: it keeps every frame as a separate array, so a larger file is decoded from the header layout alone
_PYC3D_MAX_BYTES = 256 << 20


def make_unique(labels: list[str]) -> tuple[list[str], list[tuple[int, str, str]]]:
    """Make labels unique without dropping any.

    Labels are stripped; an empty label becomes ``_unnamed``. The first occurrence of a name keeps it; the
    k-th repeat becomes ``NAME~k`` (k = 2, 3, …, skipping names already in use). Returns the new labels and
    ``(index, original, new)`` for every label that changed (empty ones included).
    """
    out: list[str] = []
    changed: list[tuple[int, str, str]] = []
    stripped = [(lab or "").strip() for lab in labels]
    bases = [s or "_unnamed" for s in stripped]
    reserved = set(bases)
    taken: set[str] = set()
    counts: dict[str, int] = {}
    for i, base in enumerate(bases):
        name = base
        if base in taken:
            k = counts.get(base, 1)
            while name in taken or name in reserved:
                k += 1
                name = f"{base}~{k}"
            counts[base] = k
        taken.add(name)
        out.append(name)
        if name != stripped[i]:
            changed.append((i, stripped[i], name))
    return out, changed


def _any3(a: np.ndarray) -> np.ndarray:
    """``a.any(axis=-1)`` for a last axis of 3 (x, y, z), as two element-wise ORs (a reduction over so short an
    axis is several times slower)."""
    return a[..., 0] | a[..., 1] | a[..., 2]


def _list_note(what: str, items: list[str], limit: int = 12) -> str:
    shown = ", ".join(items[:limit]) + (f", … ({len(items) - limit} more)" if len(items) > limit else "")
    return f"{len(items)} {what}: {shown}"


def gap_mask(xyz: np.ndarray, word4: np.ndarray, is_float: bool) -> np.ndarray:
    """Invalid samples under the SPEC §1 gap rule.

    Parameters
    ----------
    xyz : (T, P, 3) coordinates as stored (any unit).
    word4 : (T, P) fourth word of each sample: int16 for integer files, float32 for float files.
    is_float : whether the file stores floats (then the word holds an integer written as a float).

    Returns
    -------
    (T, P) bool, True where the sample is a gap.
    """
    gap, zero = _gap_parts(xyz, word4, is_float)
    nonzero_elsewhere = (~gap & ~zero).any(axis=0)
    return gap | (zero & nonzero_elsewhere[None, :])


def _gap_parts(xyz: np.ndarray, word4: np.ndarray, is_float: bool) -> tuple[np.ndarray, np.ndarray]:
    """The parts of :func:`gap_mask` that need no other frame: (T, P) gaps by the residual word or a
    non-finite coordinate, and (T, P) samples at exactly (0, 0, 0) (a gap when the marker is non-zero
    elsewhere)."""
    fin = np.isfinite(xyz)
    finite = fin[..., 0] & fin[..., 1] & fin[..., 2]
    if is_float:
        w = np.asarray(word4, dtype=np.float64)
        wfin = np.isfinite(w)
        negative = wfin & (w < 0)
        # the integer a float word holds, read as unsigned 16 bits (out-of-range words cannot be 0xFFFF)
        inrange = wfin & (np.abs(w) < 2.0**31)
        as_int = np.where(inrange, w, 0).astype(np.int64)
        ffff = inrange & ((as_int & 0xFFFF) == 0xFFFF)
    else:
        w16 = np.asarray(word4).astype(np.int16)
        negative = w16 < 0
        ffff = w16.view(np.uint16) == 0xFFFF
    gap = negative | ffff | ~finite
    zero = finite & ~_any3(xyz != 0)
    return gap, zero


def _decode_points(data: bytes, lay: Layout) -> tuple[np.ndarray, np.ndarray]:
    """Decode the point block of every frame of a whole file held in ``data``: (T, P, 3) float64 coordinates
    and (T, P) fourth words."""
    n = lay.n_frames * lay.frame_words
    buf = memoryview(data)[lay.data_offset: lay.data_offset + n * lay.word_bytes]
    return _decode_frames(buf, lay, lay.n_frames)


def _decode_frames(buf, lay: Layout, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Decode ``n_frames`` whole frames held in ``buf`` (bytes of the data section, starting at a frame):
    (n, P, 3) float64 coordinates as stored (integers times |POINT:SCALE|) and (n, P) fourth words."""
    if lay.is_float:
        if lay.processor == "dec":
            words = np.frombuffer(buf, dtype="<u2").reshape(-1, 2)[:, ::-1]
            arr = np.ascontiguousarray(words).view("<f4").reshape(-1) / np.float32(4.0)
        else:
            arr = np.frombuffer(buf, dtype=">f4" if lay.processor == "mips" else "<f4")
    else:
        arr = np.frombuffer(buf, dtype=">i2" if lay.processor == "mips" else "<i2")
    arr = arr.reshape(n_frames, lay.frame_words)[:, : 4 * lay.n_points].reshape(n_frames, lay.n_points, 4)
    if lay.is_float:
        xyz = arr[..., :3].astype(np.float64)
        word4 = arr[..., 3].astype(np.float32)
    else:
        xyz = arr[..., :3].astype(np.float64) * abs(lay.scale)
        word4 = arr[..., 3].astype(np.int16)
    return xyz, word4


def _agrees(lib_xyz: np.ndarray, own_xyz: np.ndarray, gap: np.ndarray) -> bool:
    """Whether a library's coordinates match the numpy decode on every non-gap sample."""
    if lib_xyz.shape != own_xyz.shape:
        return False
    ok = ~gap
    a, b = lib_xyz[ok], own_xyz[ok]
    tol = _AGREE_MM + 1e-6 * np.abs(b)
    return bool(np.all(np.abs(a - b) <= tol))


def _read_pyc3d(path: Path, lay: Layout) -> np.ndarray | None:
    """Coordinates from the ``c3d`` package, or None when its view of the layout differs from ours."""
    import c3d

    with open(path, "rb") as fh, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = c3d.Reader(fh)
        if (int(r.point_used) != lay.n_points or int(r.frame_count) != lay.n_frames
                or (float(r.point_scale) < 0) != lay.is_float
                or int(r.analog_used) * int(r.analog_per_frame) != lay.analog_words):
            return None
        # the package yields one frame at a time; this path only serves files ezc3d cannot read (MIPS)
        frames = [p[:, :3].astype(np.float64) for _, p, _ in
                  r.read_frames(copy=True, analog_transform=False, check_nan=False)]
    if len(frames) != lay.n_frames:
        return None
    return np.stack(frames) if frames else np.zeros((0, lay.n_points, 3))


def _duplicates(xyz: np.ndarray, valid: np.ndarray) -> list[list[int]]:
    """Groups (of 2 or more) of columns whose coordinates and validity are bit-identical.

    Columns are bucketed by a digest of their bytes, then compared exactly; never-valid columns are skipped
    (every empty marker would match every other).
    """
    buckets: dict[bytes, list[int]] = {}
    for k in range(xyz.shape[1]):
        if not valid[:, k].any():
            continue
        col = np.where(valid[:, k, None], xyz[:, k], 0.0)
        key = hashlib.blake2b(col.tobytes() + valid[:, k].tobytes(), digest_size=16).digest()
        buckets.setdefault(key, []).append(k)
    groups = []
    for members in buckets.values():
        while len(members) > 1:
            first = members[0]
            same = [k for k in members if np.array_equal(valid[:, k], valid[:, first])
                    and np.array_equal(xyz[valid[:, first], k], xyz[valid[:, first], first])]
            if len(same) > 1:
                groups.append(same)
            members = [k for k in members if k not in same]
    groups.sort(key=lambda g: g[0])
    return groups


def duplicate_trajectories(markers: Markers) -> list[list[str]]:
    """Labels of markers whose trajectories are bit-identical copies of each other, one list per group.

    Markers that are never valid are not reported (every empty marker would match every other).
    """
    return [[markers.labels[i] for i in g] for g in _duplicates(markers.xyz, markers.valid)]


def read_c3d_info(path: str | Path, *, default_units: str = "mm") -> tuple[Markers, dict]:
    """Read a C3D file; return the markers and facts about the file.

    The dict holds ``reader`` (``numpy``, or ``c3d`` when the parameters disagree with the header and that
    package's decode matched), ``processor`` (intel, dec, mips),
    ``storage`` (int, float), ``units`` (as found, None if absent), ``n_points`` (markers + model outputs)
    and ``analog_channels``.

    Only the header and parameter section are read before the layout they declare (frame and point counts,
    rates) is checked against the file's size and the physical ranges; the point blocks are then decoded
    :data:`_CHUNK_BYTES` at a time straight into the result, so memory is the result plus a bounded buffer.
    """
    return read_guarded(path, lambda p, fh, meta, lay: _assemble(p, fh, meta, lay, default_units))


def check_c3d(path: str | Path) -> None:
    """Refuse (:class:`InputError`) a C3D file whose header and parameters declare what the file cannot hold
    (more frames than its size, a rate outside 1 Hz - 10 kHz, no frames or points), reading only the header
    and parameter section: a look before the file is hashed or decoded, in bounded time and memory."""
    p = Path(path)
    with _open(p) as fh:
        _layout(p, fh)


def _open(p: Path):
    try:
        return open(p, "rb")  # noqa: SIM115 - the callers close it
    except FileNotFoundError:
        raise InputError(p, "file not found") from None
    except OSError as e:
        raise InputError(p, f"cannot read file ({e.strerror or e})") from None


def _layout(p: Path, fh) -> tuple[C3DMeta, Layout]:
    """The parameters and the layout they declare, checked against the file's size and physical ranges."""
    try:
        size = os.fstat(fh.fileno()).st_size
        head = fh.read(HEAD_BYTES)
    except OSError as e:
        raise InputError(p, f"cannot read file ({e.strerror or e})") from None
    try:
        meta = parse_c3d_meta(head)
        lay = meta.layout(size)
    except MetaError as e:
        raise _meta_error(p, e) from None
    if lay.n_frames <= 0:
        raise InputError(p, "C3D file has no frames")
    if lay.n_points <= 0:
        raise InputError(p, "C3D file has no 3D points")
    return meta, lay


def _meta_error(p: Path, e: MetaError) -> InputError:
    if e.key:
        return InputError(p, str(e), key=e.key)
    return InputError(p, f"not a readable C3D file: {e}")


def _frame_chunks(p: Path, fh, lay: Layout):
    """``(first frame index, frame count, bytes)`` of the data section, :data:`_CHUNK_BYTES` at a time."""
    frame_bytes = lay.frame_words * lay.word_bytes
    step = max(1, _CHUNK_BYTES // max(frame_bytes, 1))
    fh.seek(lay.data_offset)
    for a in range(0, lay.n_frames, step):
        n = min(step, lay.n_frames - a)
        buf = fh.read(n * frame_bytes)
        if len(buf) != n * frame_bytes:
            raise InputError(p, f"file ends inside frame {a + len(buf) // max(frame_bytes, 1) + 1} of "
                                f"{lay.n_frames} (changed while it was read?)")
        yield a, n, buf


def _points(p: Path, meta: C3DMeta, lay: Layout, default_units: str
            ) -> tuple[str | None, float, list[str], np.ndarray, np.ndarray]:
    """(units as found, mm per unit, every point's label, (P,) model-output flags, the markers' point indices)."""
    units = meta.get_str("POINT", "UNITS")
    units = units.strip() if units and units.strip() else None
    try:
        to_mm = unit_scale_to_mm(units, default_units)
    except KeyError:
        raise InputError(p, f"unknown point units {units!r}", key="POINT:UNITS") from None
    raw_labels = meta.point_labels(lay.n_points)
    is_model = _model_points(meta, raw_labels)
    return units, to_mm, raw_labels, is_model, np.flatnonzero(~is_model)


def read_guarded(path: str | Path, body):
    """Open a C3D file, check its layout and return ``body(p, fh, meta, lay)``: every failure an
    :class:`InputError` naming the file (what :func:`read_c3d_info` and the streaming summary share)."""
    p = Path(path)
    fh = _open(p)
    with fh:
        meta, lay = _layout(p, fh)
        try:
            return body(p, fh, meta, lay)
        except InputError:
            raise
        except OSError as e:
            raise InputError(p, f"cannot read file ({e.strerror or e})") from None
        except MetaError as e:
            raise _meta_error(p, e) from None
        except (ValueError, KeyError, IndexError, OverflowError) as e:
            raise InputError(p, f"not a readable C3D file: {e}") from None


def _assemble(p: Path, fh, meta: C3DMeta, lay: Layout, default_units: str) -> tuple[Markers, dict]:  # noqa: C901
    notes: list[str] = list(lay.notes)
    units, to_mm, raw_labels, is_model, marker_idx = _points(p, meta, lay, default_units)

    # one pass over the point blocks: coordinates of the markers (mm) straight into the result, the parts of
    # the gap rule per sample, and the samples beyond the physical bound or infinite
    t, n_m = lay.n_frames, marker_idx.size
    out = np.empty((t, n_m, 3))
    gap = np.empty((t, lay.n_points), dtype=bool)
    zero = np.empty((t, lay.n_points), dtype=bool)
    far = np.empty((t, n_m), dtype=bool)
    nonzero = np.zeros(lay.n_points, dtype=bool)
    infinite = 0
    first_inf: tuple[int, int] | None = None  # (frame index, marker) of the first infinite sample
    for a, n, buf in _frame_chunks(p, fh, lay):
        xyz, word4 = _decode_frames(buf, lay, n)
        g, z = _gap_parts(xyz, word4, lay.is_float)
        gap[a: a + n], zero[a: a + n] = g, z
        nonzero |= (~g & ~z).any(axis=0)
        chunk = np.multiply(xyz[:, marker_idx], to_mm, out=out[a: a + n])
        big = _any3(np.abs(chunk) > MAX_ABS_MM)         # NaN compares False; an infinity is big
        far[a: a + n] = big
        if big.any():
            inf = _any3(np.isinf(chunk))
            if first_inf is None and inf.any():
                first_inf = divmod(int(np.argmax(inf.ravel())) + a * n_m, n_m)
            infinite += int(np.count_nonzero(inf))
        del xyz, word4, g, z, chunk, big
    gap |= zero & nonzero[None, :]
    del zero

    reader = "numpy"
    if not lay.ezc3d_safe:      # parameters and header disagree: the c3d package's own view, when it agrees
        lib = None
        small = t * lay.n_points * 3 * 8 <= _PYC3D_MAX_BYTES
        if small:
            try:
                lib = _read_pyc3d(p, lay)
            except Exception:  # the pure-Python package fails on some valid files (e.g. odd TRIAL fields)
                lib = None
        if lib is not None and _agrees_with_file(p, fh, lay, lib, gap):
            np.multiply(lib[:, marker_idx], to_mm, out=out)
            far = _any3(np.abs(out) > MAX_ABS_MM)
            reader = "c3d"
        elif small:
            notes.append("the c3d package disagrees with the header's data layout (check ANALOG:RATE, "
                         "POINT:USED); decoded from the header layout")
        else:
            notes.append("the parameters disagree with the header (check ANALOG:RATE, POINT:USED) and the file "
                         "is too large for a cross-check with the c3d package; decoded from the header layout")
        del lib

    labels, renamed = make_unique([raw_labels[i] for i in marker_idx])
    if renamed:
        notes.append(_list_note("empty or duplicate labels renamed",
                                [f"{old!r} -> {printable(new)}" for _, old, new in renamed]))
    model_outputs = [raw_labels[i].strip() for i in np.flatnonzero(is_model)]

    valid = ~gap[:, marker_idx]
    del gap
    out[~valid] = np.nan
    if infinite and first_inf is not None:
        notes.append(f"{infinite} samples with an infinite coordinate made gaps (first at frame "
                     f"{lay.first_frame + first_inf[0]}, marker {printable(labels[first_inf[1]])})")
    beyond = far & valid
    if beyond.any():
        cols = np.flatnonzero(beyond.any(axis=0))
        t0, m0 = divmod(int(np.argmax(beyond.ravel())), n_m)
        notes.append(f"{int(beyond.sum())} samples farther than {MAX_ABS_MM:,.0f} mm from the origin (corrupted "
                     f"values) made gaps (first at frame {lay.first_frame + t0}, marker {printable(labels[m0])}), "
                     "in " + _list_note("markers", [printable(labels[i]) for i in cols]))
        valid &= ~beyond
        out[beyond] = np.nan
    del far, beyond
    _check_span(p, lay, units, default_units, *coordinate_span(out, valid), notes)
    at_origin = valid.any(axis=0) & ~(valid & _any3(out != 0)).any(axis=0)
    if at_origin.any():
        notes.append(_list_note("markers at exactly (0, 0, 0) in every valid sample (never seen?)",
                                [printable(labels[i]) for i in np.flatnonzero(at_origin)]))
    if valid.size and not valid.any():
        notes.append("every marker sample is invalid (100 % gaps)")
    elif valid.size and valid.all():
        notes.append("no marker sample is invalid (0 % gaps): check how this system writes gaps")

    markers = Markers(labels=labels, xyz=out, valid=valid, rate_hz=lay.stated_rate_hz,
                      first_frame=lay.first_frame, units=units, source_format="c3d",
                      model_outputs=model_outputs, warnings=notes)
    dups = _duplicates(markers.xyz, markers.valid)
    if dups:
        notes.append(_list_note("groups of bit-identical trajectories",
                                ["=".join(printable(labels[i]) for i in g) for g in dups], limit=6))
    info = {"reader": reader, "processor": lay.processor, "storage": "float" if lay.is_float else "int",
            "units": units, "n_points": lay.n_points, "analog_channels": lay.analog_channels}
    return markers, info


def _check_span(p: Path, lay: Layout, units: str | None, default_units: str, lo: np.ndarray, hi: np.ndarray,
                notes: list[str]) -> None:
    """Refuse a capture whose markers all sit within a millimetre of the origin, note one that spans more
    than any capture volume (:func:`gazepipe.io.limits.span_problem`), naming what scaled it: POINT:SCALE
    for integer storage, POINT:UNITS for float storage."""
    found = span_problem(lo, hi)
    if found is None:
        return
    refuse, why = found
    shown = units if units is not None else f"none, {default_units} assumed"
    if lay.is_float:
        key, what = "POINT:UNITS", f"units {shown!r} (float storage)"
    else:
        key, what = "POINT:SCALE", f"a scale of {abs(lay.scale):.3g} (integer storage, units {shown!r})"
    if refuse:
        raise InputError(p, f"{why}; {what} is implausible", key=key)
    notes.append(f"{key}: {why}; check {what}")


def _agrees_with_file(p: Path, fh, lay: Layout, lib: np.ndarray, gap: np.ndarray) -> bool:
    """Whether a library's (T, P, 3) coordinates match the numpy decode of the file on every non-gap sample
    (compared a chunk of frames at a time)."""
    if lib.shape != (lay.n_frames, lay.n_points, 3):
        return False
    for a, n, buf in _frame_chunks(p, fh, lay):
        own, _ = _decode_frames(buf, lay, n)
        if not _agrees(lib[a: a + n], own, gap[a: a + n]):
            return False
    return True


def _model_points(meta: C3DMeta, raw_labels: list[str]) -> np.ndarray:
    """(P,) bool: the points that are model outputs (listed in a POINT parameter of ``MODEL_OUTPUT_PARAMS``)."""
    model_names: set[str] = set()
    for name in MODEL_OUTPUT_PARAMS:
        model_names.update(s.strip() for s in meta.get_strings("POINT", name) if s.strip())
    return np.array([lab.strip() in model_names for lab in raw_labels], dtype=bool)


def read_c3d(path: str | Path, *, default_units: str = "mm") -> Markers:
    """Read the marker trajectories of a C3D file (any processor, integer or float storage).

    Parameters
    ----------
    path : the .c3d file.
    default_units : units assumed when POINT:UNITS is absent.

    Returns
    -------
    Markers in millimetres, NaN at gaps; ``first_frame`` is the header's first frame. Points listed as model
    outputs are left out of ``xyz`` and named in ``model_outputs``.

    Raises
    ------
    InputError : for any file that cannot be read (missing, truncated, malformed, no frames).
    """
    return read_c3d_info(path, default_units=default_units)[0]


def write_c3d(path: str | Path, markers: Markers) -> None:
    """Write markers to a float C3D file (POINT:UNITS mm; gaps as residual -1 at (0, 0, 0)).

    The first frame and the rate are preserved. Model outputs are not written (``Markers`` holds no data for
    them).
    """
    import ezc3d

    p = Path(path)
    xyz = np.asarray(markers.xyz, dtype=np.float64)
    valid = np.asarray(markers.valid, dtype=bool) & np.isfinite(xyz).all(axis=2)
    t, m = valid.shape
    if t == 0:
        raise InputError(p, "cannot write a C3D file without frames")
    if not 1 <= markers.first_frame <= 65535 or markers.first_frame + t - 1 > 65535:
        raise InputError(p, f"first frame {markers.first_frame} and {t} frames do not fit a C3D header")
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = np.array([float(markers.rate_hz)])
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(markers.labels)
    c["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = tuple("" for _ in markers.labels)
    pts = np.ones((4, m, t))
    pts[:3] = np.where(valid[..., None], xyz, 0.0).transpose(2, 1, 0)
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = np.where(valid, 0.0, -1.0).T[None, :, :]
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, m, t), dtype=bool)
    c.add_parameter("POINT", "UNITS", "mm")
    c["header"]["points"]["first_frame"] = int(markers.first_frame) - 1  # ezc3d counts from 0
    try:
        c.write(str(p))
    except Exception as e:
        raise InputError(p, f"cannot write C3D file ({e})") from None


class FilledC3D(NamedTuple):
    """What :func:`write_filled_c3d` wrote: samples written, filled samples written as gaps (beyond the file's
    16-bit integers), and the measured samples a reader cannot tell from a filled one (their fourth word gives
    no residual or no camera, as a filled sample's 0 does: then only a sidecar can list the filled samples)."""

    written: int
    wide: int
    unmarked_measured: int


def write_filled_c3d(src: str | Path, dest: str | Path, markers: Markers, *, removed: np.ndarray | None = None,
                     original: Markers | None = None, default_units: str = "mm") -> FilledC3D:
    """Write ``dest`` as a copy of the C3D file ``src`` in which only the samples that ``markers`` fills (or
    ``removed`` takes out) are changed (:class:`FilledC3D` says how many, and whether the file's own residuals
    mark them).

    ``markers`` must be what :func:`read_c3d` returns for ``src`` (same markers, same order), with gaps
    filled: each sample that is a gap in ``src`` and valid in ``markers``, or marked in ``removed`` (T, M) and
    valid in ``markers``, gets its coordinates (in the file's units, storage and processor format) and a fourth
    word of 0 (residual 0, no cameras: C3D's mark of a point that was not reconstructed from cameras, as a
    filled one); a sample marked in ``removed`` and invalid in ``markers`` becomes a gap (zeros, residual -1).
    Every other byte (header, parameters, analog data, events, model outputs, measured samples and their
    residuals) is kept as it is.

    ``original``: what :func:`read_c3d` returned for ``src`` (read again when not given).

    Raises :class:`InputError` (naming ``src``) when ``markers`` does not match the file.
    """
    p = Path(src)
    orig = read_c3d(p, default_units=default_units) if original is None else original
    data = p.read_bytes()
    meta = parse_c3d_meta(data)
    lay = meta.layout(len(data))
    try:
        write, valid = filled_samples(orig, markers, removed)
    except ValueError as e:
        raise InputError(p, str(e)) from None
    unmarked = _unmarked_measured(data, lay, meta, valid & ~write & orig.valid)
    if not write.any():
        Path(dest).write_bytes(data)
        return FilledC3D(0, 0, unmarked)
    marker_idx = np.flatnonzero(~_model_points(meta, meta.point_labels(lay.n_points)))
    to_mm = unit_scale_to_mm(orig.units, default_units)
    t_idx, m_idx = np.nonzero(write)
    filled = valid[t_idx, m_idx]
    values = np.where(filled[:, None], markers.xyz[t_idx, m_idx] / to_mm, 0.0)  # (n, 3) in the file's units
    # fourth word: 0 (residual 0, no cameras) for a filled sample, -1 for a gap
    word4 = np.where(filled, 0.0, -1.0)[:, None]
    # the four words of each sample, in the file's encoding
    n_wide = 0
    if lay.is_float:
        quad = np.concatenate([values, word4], axis=1)
        if lay.processor == "dec":  # DEC floats: 4x the IEEE value, 16-bit halves swapped
            words = (quad * 4.0).astype("<f4").view("<u2").reshape(-1, 2)[:, ::-1]
            raw = np.ascontiguousarray(words).astype("<u2").tobytes()
        else:
            raw = quad.astype(">f4" if lay.processor == "mips" else "<f4").tobytes()
    else:
        ints = np.rint(values / abs(lay.scale))
        # a position beyond ±32767 steps cannot be stored: that sample is written as a gap
        wide = ~(np.abs(ints) <= 32767).all(axis=1)
        ints[wide] = 0.0
        word4[wide] = -1.0
        n_wide = int(wide.sum())
        quad = np.concatenate([ints, word4], axis=1)
        raw = quad.astype(">i2" if lay.processor == "mips" else "<i2").tobytes()
    sample_bytes = 4 * lay.word_bytes
    offsets = lay.data_offset + (t_idx * lay.frame_words + 4 * marker_idx[m_idx]) * lay.word_bytes
    out = np.frombuffer(data, dtype=np.uint8).copy()
    out[offsets[:, None] + np.arange(sample_bytes)] = np.frombuffer(raw, dtype=np.uint8).reshape(-1, sample_bytes)
    Path(dest).write_bytes(out.tobytes())
    return FilledC3D(int(write.sum()) - n_wide, n_wide, unmarked)


def _unmarked_measured(data: bytes, lay: Layout, meta: C3DMeta, measured: np.ndarray) -> int:
    """How many of the ``measured`` (T, M) marker samples have a fourth word with a zero residual byte (low) or
    camera byte (high): a filled sample's word is 0, so some reader (the C3D manual's byte order, or ezc3d's
    swapped one) cannot tell them apart."""
    if not measured.any():
        return 0
    marker_idx = np.flatnonzero(~_model_points(meta, meta.point_labels(lay.n_points)))
    t_idx, m_idx = np.nonzero(measured)
    offsets = lay.data_offset + (t_idx * lay.frame_words + 4 * marker_idx[m_idx] + 3) * lay.word_bytes
    if lay.is_float:
        if lay.processor == "dec":
            pairs = np.frombuffer(data, dtype="<u2")[(offsets[:, None] // 2) + np.array([1, 0])]
            word = np.ascontiguousarray(pairs).view("<f4").reshape(-1).astype(np.float64) / 4.0
        else:
            word = np.frombuffer(data, dtype=">f4" if lay.processor == "mips" else "<f4")[offsets // 4]
        ok = np.isfinite(word) & (word >= 0) & (word < 2.0**31)
        as_int = np.where(ok, word, 0).astype(np.int64) & 0xFFFF
    else:
        as_int = np.frombuffer(data, dtype=">i2" if lay.processor == "mips" else "<i2")[offsets // 2]
        as_int = as_int.astype(np.int64) & 0xFFFF
    return int(np.count_nonzero(((as_int & 0xFF) == 0) | ((as_int >> 8) == 0)))
