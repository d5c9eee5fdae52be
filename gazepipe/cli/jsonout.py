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
