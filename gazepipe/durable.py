"""Durable file writes shared by the engine and the trainers: a file appears whole or not at all.

A temporary file is written next to its destination (or in a given folder on the same file system), fsynced,
renamed into place, and the folder fsynced, so a crash leaves either the old file or the new one. Files are
created with ``open`` (mode 0666 less the umask: 0644 under the usual 022), like every other output.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path


def fsync_dir(path: str | Path) -> None:
    """Make a rename in ``path`` durable (best effort: some file systems refuse)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def temporary_name(final: str | Path, tmp_dir: str | Path | None = None, suffix: str = "") -> Path:
    """A hidden temporary path for ``final``: in ``tmp_dir`` (default: ``final``'s folder), unique per process."""
    final = Path(final)
    where = Path(tmp_dir) if tmp_dir is not None else final.parent
    return where / f".{final.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.part{suffix}"


def write_bytes_atomic(final: str | Path, data: bytes, tmp_dir: str | Path | None = None) -> None:
    """Write ``data`` to ``final`` atomically (see the module's docstring)."""
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(final, tmp_dir)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    try:
        with open(tmp, "xb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, final)
        fsync_dir(final.parent)
    finally:
        tmp.unlink(missing_ok=True)
