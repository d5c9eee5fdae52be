"""What native libraries write straight to the process's stderr, caught so that it reaches the user as part of
one clean line.

FFmpeg (inside OpenCV) prints its own diagnostics to file descriptor 2: "moov atom not found" for a cut MP4,
"illegal dc vlc" for a damaged frame. Left alone they break a JSON log's one-event-per-line contract and say
nothing of which file they are about. :func:`native_output` points descriptor 2 at a private file for the
length of a call into the library and hands back the lines it wrote, for the caller to put in an error or a
warning that names the file.

Python's own writes to stderr from other threads of the process (the run's event log) hold
:data:`gazepipe.errors.STDERR_LOCK` while they write, so they wait for a capture to end rather than landing
in it.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager

from gazepipe.errors import STDERR_LOCK, printable

__all__ = ["STDERR_LOCK", "native_output", "summarise"]


#: at most this much of a library's output is read back (a damaged file can make FFmpeg print for ever)
_MAX_BYTES = 64 * 1024
_PREFIX = re.compile(r"^\[[^\]]*@ ?0x[0-9a-fA-F]+\]\s*")  # FFmpeg's "[mpeg4 @ 0x55d5…] "
_depth = 0


@contextmanager
def native_output() -> Iterator[list[str]]:
    """Catch what native code writes to descriptor 2 inside the ``with`` block.

    Yields a list that holds, once the block ends, the lines written (printable, FFmpeg's context prefix
    removed, repeats dropped, in order). Nested blocks yield empty lists: the outermost one catches everything.
    Where descriptor 2 cannot be redirected (closed, or not a descriptor), nothing is caught.
    """
    global _depth
    lines: list[str] = []
    with STDERR_LOCK:
        if _depth:
            yield lines
            return
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError, OSError):
            pass
        try:
            saved = os.dup(2)
        except OSError:
            yield lines
            return
        try:
            sink = tempfile.TemporaryFile()
        except OSError:   # no room for a temporary file: the library's lines go where they would have
            os.close(saved)
            yield lines
            return
        try:
            os.dup2(sink.fileno(), 2)
            _depth = 1
            try:
                yield lines
            finally:
                _depth = 0
                os.dup2(saved, 2)
                sink.seek(0)
                lines.extend(_lines(sink.read(_MAX_BYTES)))
        finally:
            os.close(saved)
            sink.close()


def _lines(data: bytes) -> list[str]:
    out: list[str] = []
    for raw in data.decode("utf-8", "replace").splitlines():
        text = printable(_PREFIX.sub("", raw.strip())).strip()
        if text and text not in out:
            out.append(text)
    return out


def summarise(lines: list[str], limit: int = 2) -> str:
    """``'first message'; 'second message' (+N more)`` for an error or a warning line; '' for none."""
    if not lines:
        return ""
    shown = "; ".join(f"'{s[:120]}'" for s in lines[:limit])
    more = len(lines) - limit
    return shown + (f" (+{more} more)" if more > 0 else "")
