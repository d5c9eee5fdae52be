"""Run events: readable lines on a terminal, JSON lines for batch jobs (``--log-format auto|text|json``)."""

from __future__ import annotations

import json
import sys
import time
from typing import Any, TextIO

from gazepipe.errors import STDERR_LOCK

LEVELS = ("debug", "info", "warning", "error")


class EventLog:
    """Writes one event per line to ``stream`` (stderr by default).

    JSON lines carry ``time`` (UTC ISO 8601), ``level``, ``event``, ``run_id`` and the event's fields (``stage``,
    ``take``, ``status``, ``duration_s`` …). Text lines are for people and omit the bookkeeping. A
    ``traceback`` field is written only with ``debug`` (``--debug``): a log read by people and batch tools
    carries one line per failure, as the terminal does.
    """

    def __init__(self, fmt: str = "auto", stream: TextIO | None = None, run_id: str = "",
                 quiet: bool = False, debug: bool = False) -> None:
        self.stream = stream or sys.stderr
        if fmt == "auto":
            fmt = "text" if _isatty(self.stream) else "json"
        self.fmt = fmt
        self.run_id = run_id
        self.quiet = quiet
        self.debug = debug
        self._bar = False   # a progress bar is on the terminal's last line

    @property
    def interactive(self) -> bool:
        return self.fmt == "text" and _isatty(self.stream)

    def emit(self, level: str, event: str, message: str = "", **fields: Any) -> None:
        if self.quiet and level in ("debug", "info"):
            return
        if self.fmt == "json":
            rec = {"time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime()) + "Z", "level": level,
                   "event": event, "run_id": self.run_id}
            rec.update({k: v for k, v in fields.items() if v is not None and (k != "traceback" or self.debug)})
            if message:
                rec["message"] = message
            line = json.dumps(rec, default=str, sort_keys=False)
        else:
            if level == "debug" or (self.interactive and event == "unit" and fields.get("status") == "ok"):
                return  # on a terminal the progress bar stands for the units that went well
            prefix = {"warning": "warning: ", "error": "error: "}.get(level, "")
            line = prefix + (message or event)
            if self._bar:
                line = "\r\033[K" + line
                self._bar = False
        with STDERR_LOCK:  # not inside a capture of a native library's output
            print(line, file=self.stream, flush=True)

    def progress(self, done: int, total: int, what: str = "takes") -> None:
        """Redraw a one-line progress bar (terminals only; nothing in logs)."""
        if not self.interactive or total <= 0:
            return
        width = 30
        full = int(width * done / total)
        bar = "#" * full + "-" * (width - full)
        end = "\n" if done >= total else ""
        with STDERR_LOCK:
            print(f"\r\033[K[{bar}] {done}/{total} {what}", end=end, file=self.stream, flush=True)
        self._bar = done < total


def _isatty(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False
