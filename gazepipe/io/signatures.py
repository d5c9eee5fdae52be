"""Telling a capture file from other files by its first bytes (images, documents, archives, videos), so that a
command given one says "not a capture file (a PNG image)" rather than what a C3D reader makes of it."""

from __future__ import annotations

from pathlib import Path

__all__ = ["SIGNATURES", "not_a_capture"]

#: the first bytes of common files that are not captures → what they are
SIGNATURES: tuple[tuple[bytes, str], ...] = (
    (b"\x89PNG\r\n\x1a\n", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"), (b"GIF8", "a GIF image"),
    (b"%PDF", "a PDF document"), (b"PK\x03\x04", "a ZIP archive (or an Office document)"),
    (b"\x1f\x8b", "a gzip archive"), (b"BM", "a BMP image"), (b"II*\x00", "a TIFF image"),
    (b"MM\x00*", "a TIFF image"), (b"\x7fELF", "a program"), (b"PAR1", "a Parquet file"),
    (b"\x1a\x45\xdf\xa3", "a Matroska/WebM video"), (b"RIFF", "a RIFF file (AVI video or WAV audio)"),
    (b"\x93NUMPY", "a NumPy array"), (b"\x89HDF", "an HDF5 file"),
)
_C3D_BLOCK = 512


def _looks_c3d(head: bytes, fh) -> bool:
    """The C3D signature: header byte 2 is 0x50 and byte 1 points at a parameter block whose fourth byte names
    a processor type (84 + 1, 2 or 3)."""
    if len(head) < 2 or head[1] != 0x50 or head[0] < 1:
        return False
    fh.seek((head[0] - 1) * _C3D_BLOCK)
    block = fh.read(4)
    return len(block) == 4 and 85 <= block[3] <= 87


def not_a_capture(path: str | Path) -> str | None:
    """Why ``path`` is not a capture file ``gazepipe`` reads (``a PNG image``, ``binary data ...``), from
    its first bytes; ``None`` when it may be one (its reader then says what is wrong, if anything)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
            if not head:
                return None
            for magic, what in SIGNATURES:
                if head.startswith(magic):
                    return what
            if head[:4] == b"\x00\x00\x00" + head[3:4] and head[4:8] == b"ftyp":
                return "an MP4/MOV video"
            if _looks_c3d(head, fh) or head.startswith((b"\xff\xfe", b"\xfe\xff")):
                return None   # a C3D, or text saved as UTF-16, which the text readers name as such
    except OSError:
        return None   # the reader says why it cannot be read
    if Path(path).suffix.lower() == ".c3d":
        return None   # a damaged C3D: its reader names the fault
    if b"\x00" in head:
        return "binary data, neither a C3D file nor a text export"
    return None
