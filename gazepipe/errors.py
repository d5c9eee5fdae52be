"""Errors that reach users as one line naming the file and the problem.

Every failure a user can cause (a bad file, a bad setting) is raised as a subclass of
:class:`GazepipeError`; the command line prints ``str(err)`` and no traceback unless ``--debug``.
"""

from __future__ import annotations

from pathlib import Path


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
        return f"{take}{where}{self.problem}"


class ConfigError(GazepipeError):
    """session.toml / markerset.toml / parameter problems (exit 2)."""

    exit_code = 2


class InputError(GazepipeError):
    """A capture file that is missing, malformed, truncated or inconsistent."""


class StageError(GazepipeError):
    """A stage could not produce its output for a take (a QC failure, not a crash)."""


class SchemaError(GazepipeError):
    """A table does not match its Arrow schema on write or on read."""


class LockedError(GazepipeError):
    """Another run holds the output folder's lock (exit 75)."""

    exit_code = 75
