"""C3D reader and writer.

Reading happens in three steps:

1. :func:`parse_c3d_meta` decodes the header and the parameter section with bounded, pure-Python code and
   checks that the data section the header describes fits in the file. Nothing else touches a file that
   fails this step, so ezc3d (C++) never sees a truncated or malformed header or parameter section: on
   mutated files ezc3d was seen to hang (a description overrunning its record), to crash with SIGSEGV
   (ANALOG:SCALE or ANALOG:OFFSET missing or short) and to read truncated files without error.
2. The point block is decoded with numpy straight from the validated layout (``_decode_points``). This
   always provides the fourth word of every sample (residual and camera byte), which ezc3d does not
   return faithfully (it decodes integer residual words from the camera byte and hides 65535.0 words).
3. The coordinates are taken from ezc3d when the file's parameters agree with its header (Intel/DEC
   processors, ``ANALOG:RATE`` consistent with the header's analog word count), else from the pure-Python
   ``c3d`` package when its own view of the layout agrees, else from the numpy decode alone. Whichever
   library is used, its coordinates are compared with the numpy decode and discarded on disagreement.

Gap rule (SPEC §1): a sample is invalid when its residual is negative, when any coordinate is NaN (or
infinite), when the residual word read as an unsigned 16-bit integer is 0xFFFF, or when it lies at exactly
(0, 0, 0) in a marker that has a non-zero valid sample elsewhere.
"""

from __future__ import annotations

import hashlib
import math
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gazepipe.errors import InputError
from gazepipe.model import Markers
from gazepipe.timebase import snap_rate, unit_scale_to_mm

#: POINT parameters listing model outputs (angles, forces, …): those points are not markers.
#: ``MODELED_MARKERS`` is deliberately absent: modelled markers (joint centres) are positions in mm.
MODEL_OUTPUT_PARAMS: tuple[str, ...] = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS")

#: largest coordinate difference (mm) tolerated between a library's decode and the numpy decode
_AGREE_MM = 1e-3


class MetaError(Exception):
    """The header or parameter section cannot be decoded (message: short phrase, no path)."""


_PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
_PARAM_TYPES = {-1: 1, 1: 1, 2: 2, 4: 4}  # type code -> bytes per element


@dataclass(frozen=True)
class _Param:
    type: int
    dims: tuple[int, ...]
    raw: bytes


@dataclass(frozen=True)
class Layout:
    """Where the point data lives and how it is stored (all checked against the file size)."""

    processor: str          # intel | dec | mips
    is_float: bool
    scale: float            # POINT:SCALE (negative for float storage)
    n_points: int
    n_frames: int
    first_frame: int        # header first frame (1-based in most files)
    rate_hz: float          # point rate, not snapped
    analog_words: int       # analog words per point frame (header word 3)
    analog_channels: int
    data_offset: int        # byte offset of the first frame
    ezc3d_safe: bool        # parameters agree with the header the way ezc3d needs
    notes: tuple[str, ...] = ()  # layout findings worth a warning

    @property
    def word_bytes(self) -> int:
        return 4 if self.is_float else 2

    @property
    def frame_words(self) -> int:
        return 4 * self.n_points + self.analog_words


@dataclass
class C3DMeta:
    """Decoded header words and parameters of a C3D file."""

    processor: str
    header: dict[str, float]
    params: dict[tuple[str, str], _Param] = field(default_factory=dict)
    irregular: bool = False  # the parameter chain needed leniency (then ezc3d is not trusted with the file)

    def _e(self) -> str:
        return ">" if self.processor == "mips" else "<"

    def get(self, group: str, name: str) -> _Param | None:
        return self.params.get((group.upper(), name.upper()))

    def get_numbers(self, group: str, name: str, *, unsigned: bool = False) -> np.ndarray | None:
        """All elements of a numeric parameter as float64, or None if absent or not numeric."""
        prm = self.get(group, name)
        if prm is None or prm.type == -1:
            return None
        if prm.type == 1:
            return np.frombuffer(prm.raw, dtype=np.uint8 if unsigned else np.int8).astype(np.float64)
        if prm.type == 2:
            return np.frombuffer(prm.raw, dtype=self._e() + ("u2" if unsigned else "i2")).astype(np.float64)
        return _floats(prm.raw, self.processor).astype(np.float64)

    def get_number(self, group: str, name: str, *, unsigned: bool = False) -> float | None:
        v = self.get_numbers(group, name, unsigned=unsigned)
        return None if v is None or v.size == 0 else float(v[0])

    def get_strings(self, group: str, name: str) -> list[str]:
        """A character parameter as a list of strings (trailing blanks and NULs removed); [] if absent."""
        prm = self.get(group, name)
        if prm is None or prm.type != -1:
            return []
        text = prm.raw.decode("latin-1")
        if len(prm.dims) <= 1:
            return [text.rstrip(" \x00")]
        width = prm.dims[0]
        if width == 0:
            return [""] * int(np.prod(prm.dims[1:]))
        return [text[i: i + width].rstrip(" \x00") for i in range(0, len(text), width)]

    def get_str(self, group: str, name: str) -> str | None:
        s = self.get_strings(group, name)
        return s[0] if s else None

    def point_labels(self, n_points: int) -> list[str]:
        """POINT:LABELS, LABELS2, LABELS3 … concatenated, cut or padded (with '') to ``n_points``."""
        labels = list(self.get_strings("POINT", "LABELS"))
        k = 2
        while len(labels) < n_points and self.get("POINT", f"LABELS{k}") is not None:
            labels.extend(self.get_strings("POINT", f"LABELS{k}"))
            k += 1
        labels = labels[:n_points]
        return labels + [""] * (n_points - len(labels))

    def _count(self, group: str, name: str, ptype: int) -> int:
        """Number of entries of a parameter of the given type (strings for type -1); -1 if absent or mistyped."""
        prm = self.get(group, name)
        if prm is None or (prm.type != ptype and not (ptype == 4 and prm.type == 2)):
            return -1
        if ptype == -1:
            return len(self.get_strings(group, name))
        return int(np.prod(prm.dims, dtype=np.int64)) if prm.dims else 1

    def _ezc3d_params_ok(self, n_points: int, n_analog: int) -> bool:
        """Whether the parameters ezc3d indexes per point and per channel exist with the right type and size.

        ezc3d was seen to crash (SIGSEGV) on files whose ANALOG:SCALE or ANALOG:OFFSET was missing or short,
        so a file is only handed to it when these hold.
        """
        need = [("POINT", "USED", 2, 1), ("POINT", "SCALE", 4, 1), ("POINT", "RATE", 4, 1)]
        if n_points:
            need.append(("POINT", "LABELS", -1, 1))
        if n_analog:
            need += [("ANALOG", "USED", 2, 1), ("ANALOG", "RATE", 4, 1), ("ANALOG", "GEN_SCALE", 4, 1),
                     ("ANALOG", "SCALE", 4, n_analog), ("ANALOG", "OFFSET", 2, n_analog),
                     ("ANALOG", "LABELS", -1, 1)]
        for group, name, ptype, at_least in need:
            if self._count(group, name, ptype) < at_least:
                return False
        for group, name in (("POINT", "DESCRIPTIONS"), ("POINT", "UNITS"), ("ANALOG", "DESCRIPTIONS"),
                            ("ANALOG", "UNITS"), ("ANALOG", "FORMAT")):
            prm = self.get(group, name)
            if prm is not None and prm.type != -1:
                return False
        # ezc3d crashed on character parameters without dimensions (a parameter whose type byte was
        # changed to -1, a char array whose dimension count was zeroed)
        return all(len(prm.dims) <= 7 and (prm.type != -1 or len(prm.dims) >= 1) for prm in self.params.values())

    def layout(self, file_size: int) -> Layout:
        """Check the header against the parameters and the file size; raise MetaError when they disagree."""
        h = self.header
        n_points = int(h["points"])
        used = self.get_number("POINT", "USED", unsigned=True)
        if used is not None and int(used) != n_points:
            raise MetaError(f"header says {n_points} points but POINT:USED says {int(used)}")
        scale = self.get_number("POINT", "SCALE")
        if scale is None:
            scale = h["scale"]
        if not math.isfinite(scale):
            raise MetaError("POINT:SCALE is not a number")
        rate = self.get_number("POINT", "RATE")
        if rate is None or not (math.isfinite(rate) and rate > 0):
            rate = h["rate"]
        if not (math.isfinite(rate) and rate > 0):
            raise MetaError("no valid point rate in POINT:RATE or the header")
        first, last = int(h["first_frame"]), int(h["last_frame"])
        n_frames = last - first + 1
        end_field = self.get_numbers("TRIAL", "ACTUAL_END_FIELD", unsigned=True)
        start_field = self.get_numbers("TRIAL", "ACTUAL_START_FIELD", unsigned=True)
        if last == 65535 and end_field is not None and end_field.size >= 2:
            # more frames than a 16-bit header word holds: the TRIAL fields carry 32-bit frame numbers
            end = int(end_field[0]) + 65536 * int(end_field[1])
            start = first
            if start_field is not None and start_field.size >= 2:
                start = int(start_field[0]) + 65536 * int(start_field[1])
            n_frames = max(n_frames, end - start + 1)
        if n_frames < 0:
            raise MetaError(f"last frame {last} before first frame {first}")
        data_offset = (int(h["data_start"]) - 1) * 512
        if data_offset < 512:
            raise MetaError(f"data section starts at block {int(h['data_start'])}")
        is_float = scale < 0
        word = 4 if is_float else 2
        a_used = self.get_number("ANALOG", "USED", unsigned=True)
        a_used = int(a_used) if a_used is not None else 0
        a_rate = self.get_number("ANALOG", "RATE")
        ratio = (a_rate / rate) if a_rate is not None and math.isfinite(a_rate) and a_rate > 0 else 0.0
        per_frame = round(ratio) if abs(ratio - round(ratio)) <= 1e-6 else 0
        notes: list[str] = []

        def spare(aw: int) -> int:
            return file_size - data_offset - n_frames * (4 * n_points + aw) * word

        # the header's analog word count decides the frame size, unless it leaves whole blocks unread (or
        # runs past the end) while the ANALOG parameters fill the file exactly (the last block padded)
        analog_words = int(h["analog_words"])
        from_params = a_used * per_frame
        if from_params != analog_words and not 0 <= spare(analog_words) < 512 and 0 <= spare(from_params) < 512:
            notes.append(f"header says {analog_words} analog words per frame, ANALOG:USED/RATE say "
                         f"{from_params}: the file size agrees with the parameters")
            analog_words = from_params
        if spare(analog_words) < 0:
            raise MetaError(f"truncated: {n_frames} frames need {file_size - spare(analog_words)} bytes, "
                            f"the file has {file_size}")
        if spare(analog_words) >= 512:
            notes.append(f"{spare(analog_words)} bytes after the data section")
        ezc3d_safe = self.processor != "mips" and not self.irregular and used is not None
        if (a_used or analog_words) and (per_frame < 1 or a_used * per_frame != analog_words):
            ezc3d_safe = False  # ezc3d derives the analog block from ANALOG:RATE and would misalign frames
        param_rate = self.get_number("POINT", "RATE")
        if param_rate is None or not math.isclose(param_rate, h["rate"], rel_tol=1e-6):
            ezc3d_safe = False
        ezc3d_safe = ezc3d_safe and self._ezc3d_params_ok(n_points, a_used)
        return Layout(processor=self.processor, is_float=is_float, scale=float(scale), n_points=n_points,
                      n_frames=n_frames, first_frame=first, rate_hz=float(rate), analog_words=analog_words,
                      analog_channels=a_used, data_offset=data_offset, ezc3d_safe=ezc3d_safe,
                      notes=tuple(notes))


def _floats(raw: bytes, processor: str) -> np.ndarray:
    """32-bit floats in the processor's format as float32 (DEC: word-swapped, exponent offset by 2)."""
    raw = raw[: len(raw) // 4 * 4]
    if processor == "dec":
        words = np.frombuffer(raw, dtype="<u2").reshape(-1, 2)[:, ::-1]
        return np.ascontiguousarray(words).view("<f4").reshape(-1) / np.float32(4.0)
    return np.frombuffer(raw, dtype=">f4" if processor == "mips" else "<f4")


def parse_c3d_meta(data: bytes) -> C3DMeta:
    """Decode the header and the parameter section of a C3D file held in ``data``.

    Every read is bounds-checked; any inconsistency raises :class:`MetaError`. The data section is not
    touched.
    """
    if len(data) < 512:
        raise MetaError(f"only {len(data)} bytes, shorter than a C3D header")
    if data[1] != 0x50:
        raise MetaError("header key byte is not 0x50")
    start = (data[0] - 1) * 512
    if start < 512 or start + 4 > len(data):
        raise MetaError(f"parameter section at block {data[0]} is outside the file")
    n_blocks, proc_byte = data[start + 2], data[start + 3]
    processor = _PROCESSORS.get(proc_byte)
    if processor is None:
        raise MetaError(f"unknown processor type {proc_byte}")
    end = start + max(n_blocks, 1) * 512
    if end > len(data):
        raise MetaError("parameter section truncated")
    e = ">" if processor == "mips" else "<"
    w = struct.unpack(e + "BBHHHHH", data[:12])
    words = struct.unpack(e + "HHHHHH", data[12:16] + data[16:18] + data[18:20] + data[20:24])
    scale = float(_floats(data[12:16], processor)[0])
    rate = float(_floats(data[20:24], processor)[0])
    header = {"points": w[2], "analog_words": w[3], "first_frame": w[4], "last_frame": w[5],
              "max_gap": w[6], "scale": scale, "data_start": words[2], "analog_per_frame": words[3],
              "rate": rate}
    meta = C3DMeta(processor=processor, header=header)

    groups: dict[int, str] = {}
    raw_params: list[tuple[int, str, _Param]] = []
    seen_names: set[tuple[int, str]] = set()
    p = start + 4
    while p + 2 <= end:
        nlen = struct.unpack_from("b", data, p)[0]
        gid = struct.unpack_from("b", data, p + 1)[0]
        if nlen == 0 or gid == 0:
            break
        name_end = p + 2 + abs(nlen)
        if name_end + 2 > end:
            raise MetaError("parameter section truncated inside a name")
        name = data[p + 2: name_end].decode("latin-1").strip().upper()
        offset = struct.unpack_from(e + "h", data, name_end)[0]
        nxt = name_end + offset
        if gid < 0:
            if -gid in groups or name in groups.values():
                meta.irregular = True
            groups.setdefault(-gid, name)
            desc_at = name_end + 2
        else:
            q = name_end + 2
            if q + 2 > end:
                raise MetaError(f"parameter {name} truncated")
            ptype = struct.unpack_from("b", data, q)[0]
            ndim = data[q + 1]
            if ptype not in _PARAM_TYPES:
                raise MetaError(f"parameter {name} has unknown type {ptype}")
            dims = tuple(data[q + 2: q + 2 + ndim])
            size = _PARAM_TYPES[ptype] * (math.prod(dims) if ndim else 1)  # Python ints: no overflow
            if len(dims) != ndim or q + 2 + ndim + size > end:
                raise MetaError(f"parameter {name} runs past the parameter section")
            raw = bytes(data[q + 2 + ndim: q + 2 + ndim + size])
            raw_params.append((gid, name, _Param(ptype, dims, raw)))
            desc_at = q + 2 + ndim + size
        # the description must end inside its record, and its length byte must be below 128: ezc3d reads
        # it as a signed byte and hangs or crashes (SIGSEGV) on a "negative" length
        record_end = nxt if offset > 0 else end
        if desc_at >= end or data[desc_at] >= 128 or desc_at + 1 + data[desc_at] > min(record_end, end):
            meta.irregular = True
        if offset == 0:
            break
        if nxt <= p or nxt > end:
            # a broken chain pointer: keep what was read, but do not hand the file to ezc3d
            meta.irregular = True
            break
        p = nxt
    for gid, name, prm in raw_params:
        gname = groups.get(gid)
        if gname is None:
            meta.irregular = True
            continue
        if (gid, name) in seen_names:
            meta.irregular = True
        seen_names.add((gid, name))
        meta.params.setdefault((gname, name), prm)
    if not all(_printable(n) for n in [*groups.values(), *(n for _, n, _ in raw_params)]):
        meta.irregular = True
    return meta


def _printable(name: str) -> bool:
    return bool(name) and all(32 < ord(ch) < 127 for ch in name)


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
    finite = np.isfinite(xyz).all(axis=2)
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
    zero = finite & (xyz == 0).all(axis=2)
    nonzero_elsewhere = (~gap & ~zero).any(axis=0)
    gap |= zero & nonzero_elsewhere[None, :]
    return gap


def _decode_points(data: bytes, lay: Layout) -> tuple[np.ndarray, np.ndarray]:
    """Decode the point block of every frame: (T, P, 3) float64 coordinates and (T, P) fourth words."""
    n = lay.n_frames * lay.frame_words
    buf = memoryview(data)[lay.data_offset: lay.data_offset + n * lay.word_bytes]
    if lay.is_float:
        if lay.processor == "dec":
            words = np.frombuffer(buf, dtype="<u2").reshape(-1, 2)[:, ::-1]
            arr = np.ascontiguousarray(words).view("<f4").reshape(-1) / np.float32(4.0)
        else:
            arr = np.frombuffer(buf, dtype=">f4" if lay.processor == "mips" else "<f4")
    else:
        arr = np.frombuffer(buf, dtype=">i2" if lay.processor == "mips" else "<i2")
    arr = arr.reshape(lay.n_frames, lay.frame_words)[:, : 4 * lay.n_points].reshape(lay.n_frames, lay.n_points, 4)
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


def _read_ezc3d(path: Path) -> np.ndarray:
    import ezc3d

    c = ezc3d.c3d(str(path))
    pts = np.asarray(c["data"]["points"], dtype=np.float64)
    return np.transpose(pts[:3], (2, 1, 0))


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

    The dict holds ``reader`` (``ezc3d``, ``c3d`` or ``numpy``), ``processor`` (intel, dec, mips),
    ``storage`` (int, float), ``units`` (as found, None if absent), ``n_points`` (markers + model outputs)
    and ``analog_channels``.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputError(p, "file not found") from None
    except OSError as e:
        raise InputError(p, f"cannot read file ({e.strerror or e})") from None
    try:
        meta = parse_c3d_meta(data)
        lay = meta.layout(len(data))
    except MetaError as e:
        raise InputError(p, f"not a readable C3D file: {e}") from None
    if lay.n_frames <= 0:
        raise InputError(p, "C3D file has no frames")
    if lay.n_points <= 0:
        raise InputError(p, "C3D file has no 3D points")
    try:
        return _assemble(p, data, meta, lay, default_units)
    except InputError:
        raise
    except (MetaError, ValueError, KeyError, IndexError, OverflowError) as e:
        raise InputError(p, f"not a readable C3D file: {e}") from None


def _assemble(p: Path, data: bytes, meta: C3DMeta, lay: Layout, default_units: str) -> tuple[Markers, dict]:
    notes: list[str] = list(lay.notes)
    own_xyz, word4 = _decode_points(data, lay)
    gap = gap_mask(own_xyz, word4, lay.is_float)

    xyz = None
    reader = "numpy"
    if lay.ezc3d_safe:
        try:
            lib = _read_ezc3d(p)
        except Exception as e:  # ezc3d raises RuntimeError/OSError/…; any failure means "use another reader"
            notes.append(f"ezc3d could not read the file ({type(e).__name__}); used another reader")
            lib = None
        if lib is not None and _agrees(lib, own_xyz, gap):
            xyz, reader = lib, "ezc3d"
        elif lib is not None:
            notes.append("ezc3d misread the data section; used another reader")
    if xyz is None:
        try:
            lib = _read_pyc3d(p, lay)
        except Exception:  # the pure-Python package fails on some valid files (e.g. odd TRIAL fields)
            lib = None
        if lib is not None and _agrees(lib, own_xyz, gap):
            xyz, reader = lib, "c3d"
        else:
            xyz, reader = own_xyz, "numpy"
            notes.append("ezc3d and c3d disagree with the header's data layout (check ANALOG:RATE, "
                         "POINT:USED); decoded from the header layout")

    units = meta.get_str("POINT", "UNITS")
    units = units.strip() if units and units.strip() else None
    try:
        to_mm = unit_scale_to_mm(units, default_units)
    except KeyError:
        raise InputError(p, f"unknown point units {units!r}", key="POINT:UNITS") from None

    raw_labels = meta.point_labels(lay.n_points)
    model_names = set()
    for name in MODEL_OUTPUT_PARAMS:
        model_names.update(s.strip() for s in meta.get_strings("POINT", name) if s.strip())
    is_model = np.array([lab.strip() in model_names for lab in raw_labels], dtype=bool)
    marker_idx = np.flatnonzero(~is_model)

    labels, renamed = make_unique([raw_labels[i] for i in marker_idx])
    if renamed:
        notes.append(_list_note("empty or duplicate labels renamed",
                                [f"{old!r} -> {new}" for _, old, new in renamed]))
    model_outputs = [raw_labels[i].strip() for i in np.flatnonzero(is_model)]

    valid = ~gap[:, marker_idx]
    out = xyz[:, marker_idx, :] * to_mm
    out[~valid] = np.nan
    at_origin = valid.any(axis=0) & ~(valid[..., None] & (out != 0)).any(axis=(0, 2))
    if at_origin.any():
        notes.append(_list_note("markers at exactly (0, 0, 0) in every valid sample (never seen?)",
                                [labels[i] for i in np.flatnonzero(at_origin)]))
    if valid.size and not valid.any():
        notes.append("every marker sample is invalid (100 % gaps)")
    elif valid.size and valid.all():
        notes.append("no marker sample is invalid (0 % gaps): check how this system writes gaps")

    markers = Markers(labels=labels, xyz=out, valid=valid, rate_hz=snap_rate(lay.rate_hz),
                      first_frame=lay.first_frame, units=units, source_format="c3d",
                      model_outputs=model_outputs, warnings=notes)
    dups = _duplicates(markers.xyz, markers.valid)
    if dups:
        notes.append(_list_note("groups of bit-identical trajectories",
                                ["=".join(labels[i] for i in g) for g in dups], limit=6))
    info = {"reader": reader, "processor": lay.processor, "storage": "float" if lay.is_float else "int",
            "units": units, "n_points": lay.n_points, "analog_channels": lay.analog_channels}
    return markers, info


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
