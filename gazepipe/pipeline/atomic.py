"""Atomic file writes: a temporary file under ``OUT/.gazepipe/tmp``, fsync, then rename into place.

A reader never sees a half-written file at a final path: either the old bytes or the new ones.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path

from gazepipe.durable import fsync_dir, temporary_name

TMP_DIRNAME = "tmp"


@contextlib.contextmanager
def atomic_path(final: str | Path, tmp_dir: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path to write; on success it is fsynced and renamed to ``final``.

    ``tmp_dir`` must be on the same file system as ``final`` (it lives under the output folder). On any
    exception the temporary file is removed and ``final`` is untouched. ``suffix`` ends the temporary name, for
    writers that look at the extension.
    """
    final = Path(final)
    tmp_dir = Path(tmp_dir)
    tmp_dir.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(final, tmp_dir, suffix)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            fh.flush()
            os.fsync(fh.fileno())
        final.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, final)
        fsync_dir(final.parent)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


@contextlib.contextmanager
def atomic_paths(finals: Sequence[str | Path], tmp_dir: str | Path) -> Iterator[list[Path]]:
    """:func:`atomic_path` for several files written together (a unit's tables): yield one temporary path per
    final path; on success each is fsynced, all are renamed into place, then each folder they went to is fsynced
    once (not once per file). On any exception every temporary is removed and no final path is touched.

    Each file is replaced atomically, the set is not: a run killed between two renames leaves some new files
    beside old ones, which the unit's record (written after them) does not vouch for, so the unit runs again.
    """
    tmp_dir = Path(tmp_dir)
    tmp_dir.mkdir(parents=True, exist_ok=True)
    pairs = [(Path(final), temporary_name(Path(final), tmp_dir, "")) for final in finals]
    try:
        yield [tmp for _, tmp in pairs]
        for _, tmp in pairs:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
        folders: dict[Path, None] = {}
        for final, tmp in pairs:
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp, final)
            folders[final.parent] = None
        for folder in folders:
            fsync_dir(folder)
    finally:
        for _, tmp in pairs:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()


def atomic_write_bytes(final: str | Path, data: bytes, tmp_dir: str | Path) -> None:
    """Write ``data`` to ``final`` atomically."""
    with atomic_path(final, tmp_dir) as tmp:
        tmp.write_bytes(data)


def clear_stale_temporaries(tmp_dir: str | Path) -> int:
    """Delete temporary files and staging folders left by a killed run (call only while holding the output
    lock)."""
    n = 0
    d = Path(tmp_dir)
    if d.is_dir():
        for p in d.iterdir():
            if ".part" in p.name:
                with contextlib.suppress(OSError):
                    if p.is_dir() and not p.is_symlink():
                        shutil.rmtree(p)
                    else:
                        p.unlink()
                    n += 1
    return n
