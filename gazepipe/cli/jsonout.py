"""JSON the commands print, with every float rounded to what it means (``inspect --json``, ``status --json``).

A float's meaning comes from its key's unit suffix, the project's naming rule:

==========================  ===================================  =====================================
key                         quantity                             rounded to
==========================  ===================================  =====================================
``*_hz``, ``*_fps``         a rate                               6 significant digits (29.97, 59.9401)
``*_s``                     seconds                              1 µs (6 decimals)
``*_mm``                    millimetres                          0.001 mm
``*_deg``                   degrees                              0.001°
``*_share``, ``*_fraction`` a share of rows or samples in [0, 1]  1e-6
anything else               (counts are integers already)        6 significant digits
==========================  ===================================  =====================================

A float under a key without a known suffix (in a list, or an object such as ``{"yaw": …}``) takes the rule
of the nearest key above it that has one. Only what is printed is
rounded; the pipeline's files keep their full precision.

Errors under ``--json`` (:func:`error_line`): one line on stderr holding one JSON object, so that stdout holds
the command's result and nothing else (empty when it fails: read the exit code, then stderr's last line); the
exit codes are those of the text errors::

    {"error": {"message": "take t1: a.c3d: truncated …", "kind": "InputError", "exit_code": 1,
               "file": "a.c3d", "key": null, "take": "t1"}}

``kind`` is the error's class (``InputError``, ``ConfigError``, ``UsageError`` …, ``InternalError`` for a bug,
``OSError`` for a refusal of the file system, ``Interrupted``); ``file``, ``key`` and ``take`` are null when
the error names none. When a command found several problems (a session.toml's), ``errors`` lists the others'
messages, in order, before the one in ``error``.
"""

from __future__ import annotations

import json
import math
from typing import Any

#: (key suffixes, ("sig", significant digits) or ("dec", decimals)), the first matching suffix wins
RULES: tuple[tuple[tuple[str, ...], tuple[str, int]], ...] = (
    (("_hz", "_fps"), ("sig", 6)),
    (("_s",), ("dec", 6)),
    (("_mm",), ("dec", 3)),
    (("_deg",), ("dec", 3)),
    (("_share", "_fraction"), ("dec", 6)),
)
DEFAULT: tuple[str, int] = ("sig", 6)


def rule_for(key: str | None, inherited: tuple[str, int] = DEFAULT) -> tuple[str, int]:
    """The rounding rule of a value under ``key`` (see the module's table); ``inherited`` (the rule of the key
    above) when ``key`` has no known suffix."""
    for suffixes, rule in RULES:
        if key and key.endswith(suffixes):
            return rule
    return inherited


def round_float(x: float, rule: tuple[str, int]) -> float:
    """``x`` rounded by ``rule``; non-finite values unchanged, ``-0.0`` as ``0.0``."""
    if not math.isfinite(x) or x == 0:
        return 0.0 if x == 0 else x
    how, n = rule
    if how == "sig":
        n = n - 1 - math.floor(math.log10(abs(x)))
    return round(x, n) + 0.0


def rounded(obj: Any, rule: tuple[str, int] = DEFAULT) -> Any:
    """A copy of ``obj`` (dicts, lists, tuples, scalars) with every float rounded by its key's rule (``rule``
    for a bare float)."""
    if isinstance(obj, bool) or obj is None:
        return obj
    if isinstance(obj, float):
        return round_float(obj, rule)
    if isinstance(obj, dict):
        return {k: rounded(v, rule_for(k if isinstance(k, str) else None, rule)) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [rounded(v, rule) for v in obj]
    return obj


def dumps(obj: Any) -> str:
    """``obj`` as indented JSON, floats rounded (:func:`rounded`); other objects as their ``str``."""
    return json.dumps(rounded(obj), indent=1, default=str)


def error_line(message: str, exit_code: int, *, kind: str, file: str | None = None, key: str | None = None,
               take: str | None = None, others: tuple[str, ...] | list[str] = ()) -> str:
    """The one-line JSON object that ``--json`` prints for an error (see the module's docstring)."""
    obj: dict[str, Any] = {"error": {"message": message, "kind": kind, "exit_code": int(exit_code), "file": file,
                                     "key": key, "take": take}}
    if others:
        obj["errors"] = list(others)
    return json.dumps(obj, ensure_ascii=False, default=str)
