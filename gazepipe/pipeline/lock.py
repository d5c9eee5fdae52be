"""The output folder's lock: one run at a time per ``OUT``; a second exits 75 at once.

The lock is an exclusive ``flock`` on ``OUT/.gazepipe/lock``; while it is held the file names its holder (a JSON
object: ``pid``, ``started`` as UTC ISO 8601, ``host``, ``command``), and it is emptied when the holder lets go.
A holder killed outright loses the ``flock`` with its process but leaves its name in the file: a *stale* lock,
which the next run simply takes over (:func:`lock_state` tells the two apart for ``gazepipe status``).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from gazepipe.errors import LockedError

#: the most bytes of the lock file read back (its holder's description)
_MAX_BYTES = 4096


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or held) an output folder's lock.

    Attributes
    ----------
    pid : the holder's process id (``None`` when the file does not say).
    started : when it took the lock, UTC ISO 8601 (``""`` when unknown: a lock written by an older gazepipe).
    host : the machine it runs on (``""`` when unknown).
    command : its command line, shortened (``""`` when unknown).
    state : ``"held"`` (the holder runs and holds the lock) or ``"stale"`` (the holder is gone; the next run
        takes the lock over).
    """

    pid: int | None
    started: str = ""
    host: str = ""
    command: str = ""
    state: str = "held"

    def describe(self) -> str:
        """``pid 123, started 2025-01-31T09:15:02Z`` (the parts that are known)."""
        parts = [f"pid {self.pid}" if self.pid is not None else "pid unknown"]
        if self.host and self.host != socket.gethostname():
            parts.append(f"on {self.host}")
        if self.started:
            parts.append(f"started {self.started}")
        return ", ".join(parts)

    def to_dict(self) -> dict[str, object]:
        return {"state": self.state, "pid": self.pid, "started": self.started or None, "host": self.host or None,
                "command": self.command or None}


def _holder_record() -> bytes:
    command = " ".join([os.path.basename(sys.argv[0]), *sys.argv[1:]]) if sys.argv and sys.argv[0] else ""
    return json.dumps({"pid": os.getpid(), "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                       "host": socket.gethostname(), "command": command[:200]}).encode()


def _parse_holder(text: str, state: str) -> LockHolder | None:
    """The holder a lock file names (JSON, or a bare pid as older versions wrote); ``None`` when empty."""
    text = text.strip()
    if not text:
        return None
    try:
        rec = json.loads(text)
    except ValueError:
        rec = None
    if isinstance(rec, int) and not isinstance(rec, bool):
        rec = {"pid": rec}
    if not isinstance(rec, dict):
        return LockHolder(None, state=state)
    pid = rec.get("pid")
    pid = pid if isinstance(pid, int) and not isinstance(pid, bool) else None
    return LockHolder(pid, str(rec.get("started") or ""), str(rec.get("host") or ""),
                      str(rec.get("command") or ""), state)


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` of this machine exists (another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # another user's process
        return True
    return True


class OutputLock:
    """An exclusive ``flock`` on ``OUT/.gazepipe/lock``, released when the process ends, even by SIGKILL."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd: int | None = None

    def __enter__(self) -> OutputLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _parse_holder(os.read(fd, _MAX_BYTES).decode(errors="replace"), "held")
            os.close(fd)
            who = f" ({holder.describe()})" if holder else ""
            raise LockedError(self.path.parent.parent, f"another gazepipe run holds this output folder{who}") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, _holder_record(), 0)
        self._fd = fd
        return self

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, 0)   # an empty file: nobody holds it (a killed holder leaves its name)
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None


def lock_state(path: Path) -> LockHolder | None:
    """Who holds the lock at ``path`` now (state ``held``), who left it without letting go (``stale``: the
    process is gone), or ``None`` when nobody does (an empty file, or the bare pid of a finished run of a
    gazepipe from before the lock named its start time).

    Decided from the file's pid, on this machine; only when a live process has that pid is the ``flock`` itself
    tried (a shared lock, let go at once; it fails at once while the holder has it) to tell a reused pid apart.
    A holder on another machine is reported as ``held``."""
    try:
        with open(path, "rb") as fh:
            text = fh.read(_MAX_BYTES).decode(errors="replace")
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        return None
    holder = _parse_holder(text, "held")
    if holder is None:
        return None
    if not holder.started and holder.pid is not None and not pid_alive(holder.pid):
        return None   # a bare pid: what every run of an older gazepipe left when it ended, not a killed run
    same_host = not holder.host or holder.host == socket.gethostname()
    if holder.pid is not None and same_host and not pid_alive(holder.pid):
        return LockHolder(holder.pid, holder.started, holder.host, holder.command, "stale")
    if holder.pid is not None and same_host and not _flock_held(path):
        # a live process with that pid that does not hold the lock: the pid was reused after the holder died
        return LockHolder(holder.pid, holder.started, holder.host, holder.command, "stale")
    return holder


def _flock_held(path: Path) -> bool:
    """Whether some process holds the ``flock`` on ``path`` (tried with a shared lock, let go at once)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return True   # cannot tell: say held, the safe answer
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    finally:
        os.close(fd)
