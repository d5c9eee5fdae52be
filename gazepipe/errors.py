"""Errors that reach users as one line naming the file and the problem.

Every failure a user can cause (a bad file, a bad setting) is raised as a subclass of
:class:`GazepipeError`; the command line prints ``str(err)`` and no traceback unless ``--debug``.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path

#: held by every writer of the process's stderr (the run's event log), and by a capture of what a native
#: library writes there (:func:`gazepipe.io.native_log.native_output`), so the two never mix
STDERR_LOCK = threading.RLock()

# C0 and C1 control characters, DEL, lone surrogates (the bytes of a file name that are not UTF-8), and the
# Unicode line separators and bidirectional overrides that would reorder or break a printed line
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u200e\u200f\u202a-\u202e\u2066-\u2069"
                          "\ud800-\udfff]")


def _escape_char(m: re.Match) -> str:
    ch = m.group()
    code = ord(ch)
    if 0xDC80 <= code <= 0xDCFF:        # a byte that did not decode (surrogateescape): show the byte
        return f"\\x{code - 0xDC00:02x}"
    if code < 0x100:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}"


def printable(text: object) -> str:
    """``str(text)`` safe to print on one line: control characters, undecodable bytes of file names and
    characters that reorder or break a line are written as escapes (``\\x00``, ``\\x1b``, ``\\u202e``).

    Strings taken from files (C3D parameter names, labels, cells, paths) go through this before they reach an
    error line or a summary; printable text, non-ASCII letters included, is left as it is.
    """
    return _UNPRINTABLE.sub(_escape_char, str(text))


class GazepipeError(Exception):
    """A problem a user can act on.

    Parameters
    ----------
    path : file the problem is in (or ``None`` when it concerns no file).
    problem : what is wrong, as a short phrase without trailing period.
    key : optional location inside the file (a TOML key, a column, a C3D parameter).
    take : optional take id the problem belongs to.
    """

    exit_code = 1

    def __init__(self, path: str | Path | None, problem: str, *, key: str | None = None,
                 take: str | None = None) -> None:
        self.path = None if path is None else str(path)
        self.problem = " ".join(str(problem).split())  # always one line
        self.key = key
        self.take = take
        super().__init__(self.one_line())

    def one_line(self) -> str:
        parts = []
        if self.path:
            parts.append(self.path)
        if self.key:
            parts.append(self.key)
        head = ": ".join(parts)
        where = f"{head}: " if head else ""
        take = f"take {self.take}: " if self.take else ""
        return printable(f"{take}{where}{self.problem}")


class ConfigError(GazepipeError):
    """session.toml / markerset.toml / parameter problems (exit 2)."""

    exit_code = 2


class InputError(GazepipeError):
    """A capture file that is missing, malformed, truncated or inconsistent."""


class StageError(GazepipeError):
    """A stage could not produce its output for a take (a QC failure, not a crash)."""


class ResourceError(GazepipeError):
    """The machine lacks what a unit needs (memory): not the inputs' fault, so a later run tries again."""

    retry = True


class SchemaError(GazepipeError):
    """A table does not match its Arrow schema on write or on read."""


class LockedError(GazepipeError):
    """Another run holds the output folder's lock (exit 75)."""

    exit_code = 75
