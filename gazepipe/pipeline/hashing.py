"""Content hashes of input files, cached by (size, mtime, inode) so unchanged files are not re-read."""

from __future__ import annotations

import hashlib
import json
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gazepipe.errors import InputError


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


def sha256_json(obj: Any) -> str:
    """Hash of a JSON-able object in canonical form (sorted keys, no spaces)."""
    raw = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(raw.encode()).hexdigest()


class HashCache:
    """sha256 of files keyed by absolute path, trusted while size, mtime (ns) and inode are unchanged.

    The cache is a JSON file; :meth:`save` writes it back only when something changed. Beside it (``code.json``)
    :attr:`code` keeps what the stages' source files gave, keyed by hashes of their contents
    (:func:`gazepipe.pipeline.codehash.code_of`'s memo).
    """

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path else None
        self._entries: dict[str, list] = _read_dict(self.path)
        self._dirty = False
        self.code: dict[str, Any] = _read_dict(self.code_path)
        self._code_seen = len(self.code)

    @property
    def code_path(self) -> Path | None:
        return self.path.with_name("code.json") if self.path else None

    def hash(self, path: str | Path, check: Callable[[Path], None] | None = None) -> str:
        """The file's sha256; ``check(path)`` is called first when it must be read (not cached)."""
        p = os.path.abspath(path)
        try:
            st = os.stat(p)
        except FileNotFoundError:
            raise InputError(p, "file not found") from None
        except OSError as exc:
            raise InputError(p, f"cannot read ({exc.strerror})") from None
        if not stat.S_ISREG(st.st_mode):   # a folder, a FIFO (reading it would wait for ever), a device
            raise InputError(p, "not a file")
        key = [st.st_size, st.st_mtime_ns, st.st_ino]
        entry = self._entries.get(p)
        if entry and entry[:3] == key:
            return entry[3]
        if check is not None:
            check(Path(p))
        try:
            digest = sha256_file(p)
        except OSError as exc:
            raise InputError(p, f"cannot read ({exc.strerror})") from None
        self._entries[p] = [*key, digest]
        self._dirty = True
        return digest

    def save(self, write_bytes) -> None:
        """Persist through ``write_bytes(path, data)`` (an atomic writer) when anything changed."""
        if self.path and self._dirty:
            write_bytes(self.path, json.dumps(self._entries, sort_keys=True).encode())
            self._dirty = False
        if self.code_path and len(self.code) != self._code_seen:
            write_bytes(self.code_path, json.dumps(self.code, sort_keys=True).encode())
            self._code_seen = len(self.code)


def _read_dict(path: Path | None) -> dict[str, Any]:
    """The JSON object in the file at ``path``; empty when there is none or it cannot be read."""
    if path is None or not path.is_file():
        return {}
    try:
        got = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return got if isinstance(got, dict) else {}
