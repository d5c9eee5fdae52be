"""C3D header and parameter section: a bounded, pure-Python parser (step 1 of :mod:`gazepipe.io.c3d`).

:func:`parse_c3d_meta` decodes the 512-byte header and the parameter blocks, checks every record against the
file's length and the data section the header describes against the file, and returns the parameters with
the point block's :class:`Layout`. Nothing else reads a file that fails here, so the C++ reader never sees a
malformed header (on mutated files it was seen to hang or crash).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import numpy as np

from gazepipe.io.limits import MAX_RATE_HZ, MIN_RATE_HZ
from gazepipe.timebase import implausible_rate, stated_rate

#: bytes that hold the header and the whole parameter section of any C3D file: the section starts at the
#: block the header's first byte names (at most 255) and has at most 255 blocks
HEAD_BYTES = 512 * 512


class MetaError(Exception):
    """The header or parameter section cannot be decoded (message: short phrase, no path; ``key``: the
    parameter at fault, when one is)."""

    def __init__(self, message: str, key: str | None = None) -> None:
        super().__init__(message)
        self.key = key


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
    rate_hz: float          # point rate as stored (a 4-byte real), not snapped: see stated_rate_hz
    analog_words: int       # analog words per point frame (header word 3)
    analog_channels: int
    data_offset: int        # byte offset of the first frame
    ezc3d_safe: bool        # parameters agree with the header the way ezc3d needs
    notes: tuple[str, ...] = ()  # layout findings worth a warning

    @property
    def stated_rate_hz(self) -> float:
        """The point rate the file states (:func:`gazepipe.timebase.stated_rate` of the 4-byte real: 69.9 is
        69.9 Hz, 29.97 is 30000/1001 Hz)."""
        return stated_rate(self.rate_hz, float32=True)

    @property
    def word_bytes(self) -> int:
        return 4 if self.is_float else 2

    @property
    def frame_words(self) -> int:
        return 4 * self.n_points + self.analog_words


def _rate_notes(rate: float) -> list[str]:
    """The note on a point rate implausible for a marker capture (none when it is plausible)."""
    odd = implausible_rate(stated_rate(rate, float32=True), "mocap")
    return [] if odd is None else [f"POINT:RATE: {odd}; check the file's rate"]


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

    def layout(self, file_size: int) -> Layout:  # noqa: C901
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
        key: str | None = "POINT:RATE"
        if rate is None or not (math.isfinite(rate) and rate > 0):
            rate, key = h["rate"], None     # POINT:RATE absent or unusable: the header's rate word
        if not (math.isfinite(rate) and rate > 0):
            raise MetaError("no valid point rate in POINT:RATE or the header")
        if not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
            what = "point rate" if key else "the header's point rate (POINT:RATE unusable)"
            raise MetaError(f"{what} {rate:.6g} Hz is outside {MIN_RATE_HZ:g} Hz - {MAX_RATE_HZ / 1000:g} kHz, "
                            "the range of a motion capture", key=key)
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
        notes.extend(_rate_notes(rate))
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

    ``data`` may be the whole file or only its first :data:`HEAD_BYTES` (or fewer when the file is shorter):
    the result is the same. Every read is bounds-checked; any inconsistency raises :class:`MetaError`. The
    data section is not touched.
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
    meta = C3DMeta(processor=processor, header=_header(data, processor))
    groups, raw_params = _records(data, start + 4, end, ">" if processor == "mips" else "<", meta)
    seen_names: set[tuple[int, str]] = set()
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


def _header(data: bytes, processor: str) -> dict[str, float]:
    """The header's counts, frames, scale, data start and rate."""
    e = ">" if processor == "mips" else "<"
    w = struct.unpack(e + "BBHHHHH", data[:12])
    words = struct.unpack(e + "HHHHHH", data[12:16] + data[16:18] + data[18:20] + data[20:24])
    scale = float(_floats(data[12:16], processor)[0])
    rate = float(_floats(data[20:24], processor)[0])
    return {"points": w[2], "analog_words": w[3], "first_frame": w[4], "last_frame": w[5],
            "max_gap": w[6], "scale": scale, "data_start": words[2], "analog_per_frame": words[3],
            "rate": rate}


def _records(data: bytes, p: int, end: int, e: str,
             meta: C3DMeta) -> tuple[dict[int, str], list[tuple[int, str, _Param]]]:
    """The group names by id and the parameters ``(group id, name, parameter)`` of the parameter records from
    byte ``p`` up to ``end`` (byte order ``e``), in file order; ``meta.irregular`` set where ezc3d must not be
    trusted with them."""
    groups: dict[int, str] = {}
    raw_params: list[tuple[int, str, _Param]] = []
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
            prm, desc_at = _parameter(data, name_end + 2, end, name)
            raw_params.append((gid, name, prm))
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
    return groups, raw_params


def _parameter(data: bytes, q: int, end: int, name: str) -> tuple[_Param, int]:
    """Parameter ``name``'s type, dimensions and bytes from its record at byte ``q`` (after its name and
    offset), and where its description starts."""
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
    return _Param(ptype, dims, raw), q + 2 + ndim + size


def _printable(name: str) -> bool:
    return bool(name) and all(32 < ord(ch) < 127 for ch in name)
