"""The formats ``gazepipe validate`` writes: ``qc/report.json`` (the source of truth) and ``qc/takes.parquet``.

``report.json`` (schema version :data:`REPORT_SCHEMA_VERSION`)::

    {
      "schema": "gazepipe.qc_report", "schema_version": 1, "gazepipe_version": "...",
      "gate": {"fail_on": "fail", "passed": true, "hit": [...check refs...]},
      "summary": {"takes": n, "datasets": n, "checks": {"pass": n, "warning": n, ...},
                  "takes_by_severity": {...}, "failing": [{"scope", "target", "id", "severity", "message"}]},
      "thresholds": {...every threshold...},
      "takes": [{"session", "take", "kind", "pose", "severity", "stages": {stage: status},
                 "checks": [{"id", "severity", "message", "value", "threshold", "details"}]}],
      "datasets": [{"name", "severity", "schema_hash", "counts", "checks": [...]}],
      "output_checks": [...],
      "notes": [...]
    }

:data:`REPORT_JSON_SCHEMA` is the JSON Schema (draft 2020-12) of that object; :func:`validate_report` checks an
object against it (the subset of JSON Schema used here: type, enum, const, required, properties,
additionalProperties, items, minimum).

``takes.parquet``: one row per take (:data:`TAKES_SCHEMA`), the numbers a person would sort or filter on.
"""

from __future__ import annotations

from typing import Any

import pyarrow as pa

from gazepipe.report.checks import SEVERITIES
from gazepipe.schemas.base import with_identity

REPORT_SCHEMA_VERSION = 1
TAKES_SCHEMA_VERSION = 1

_NUM = {"type": ["number", "null"]}
_CHECK = {
    "type": "object",
    "required": ["id", "severity", "message", "value", "threshold", "details"],
    "additionalProperties": False,
    "properties": {
        "id": {"type": "string"},
        "severity": {"enum": list(SEVERITIES)},
        "message": {"type": "string"},
        "value": {"type": ["number", "string", "null"]},
        "threshold": {"type": ["object", "null"]},
        "details": {"type": "object"},
    },
}
_REF = {
    "type": "object",
    "required": ["scope", "target", "id", "severity", "message"],
    "properties": {"scope": {"enum": ["take", "dataset", "output"]}, "target": {"type": "string"},
                   "id": {"type": "string"}, "severity": {"enum": list(SEVERITIES)}, "message": {"type": "string"}},
}
REPORT_JSON_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "gazepipe QC report",
    "type": "object",
    "required": ["schema", "schema_version", "gazepipe_version", "gate", "summary", "thresholds", "takes",
                 "datasets", "output_checks", "notes"],
    "additionalProperties": False,
    "properties": {
        "schema": {"const": "gazepipe.qc_report"},
        "schema_version": {"const": REPORT_SCHEMA_VERSION},
        "gazepipe_version": {"type": "string"},
        "gate": {"type": "object", "required": ["fail_on", "passed", "hit"], "additionalProperties": False,
                 "properties": {"fail_on": {"enum": ["warning", "fail"]}, "passed": {"type": "boolean"},
                                "hit": {"type": "array", "items": _REF}}},
        "summary": {"type": "object", "required": ["takes", "datasets", "checks", "takes_by_severity", "failing"],
                    "properties": {"takes": {"type": "integer", "minimum": 0},
                                   "datasets": {"type": "integer", "minimum": 0},
                                   "checks": {"type": "object"}, "takes_by_severity": {"type": "object"},
                                   "failing": {"type": "array", "items": _REF}}},
        "thresholds": {"type": "object"},
        "takes": {"type": "array", "items": {
            "type": "object", "required": ["session", "take", "kind", "pose", "severity", "stages", "checks"],
            "additionalProperties": False,
            "properties": {"session": {"type": "string"}, "take": {"type": "string"}, "kind": {"type": "string"},
                           "pose": {"type": "string"}, "severity": {"enum": list(SEVERITIES)},
                           "stages": {"type": "object"}, "checks": {"type": "array", "items": _CHECK}}}},
        "datasets": {"type": "array", "items": {
            "type": "object", "required": ["name", "severity", "schema_hash", "counts", "checks"],
            "additionalProperties": False,
            "properties": {"name": {"type": "string"}, "severity": {"enum": list(SEVERITIES)},
                           "schema_hash": {"type": ["string", "null"]}, "counts": {"type": "object"},
                           "checks": {"type": "array", "items": _CHECK}}}},
        "output_checks": {"type": "array", "items": _CHECK},
        "notes": {"type": "array", "items": {"type": "string"}},
    },
}

_TYPES = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}


def _is(value: Any, t: str) -> bool:
    if t == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if t == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    return isinstance(value, _TYPES[t])


def validate_report(obj: Any, schema: dict[str, Any] | None = None, where: str = "report") -> list[str]:
    """Problems of ``obj`` against :data:`REPORT_JSON_SCHEMA` (empty list: valid)."""
    s = REPORT_JSON_SCHEMA if schema is None else schema
    problems: list[str] = []
    if "const" in s and obj != s["const"]:
        problems.append(f"{where}: expected {s['const']!r}, got {obj!r}")
    if "enum" in s and obj not in s["enum"]:
        problems.append(f"{where}: {obj!r} is not one of {s['enum']}")
    if "type" in s:
        types = s["type"] if isinstance(s["type"], list) else [s["type"]]
        if not any(_is(obj, t) for t in types):
            return problems + [f"{where}: expected {'/'.join(types)}, got {type(obj).__name__}"]
    if "minimum" in s and _is(obj, "number") and obj < s["minimum"]:
        problems.append(f"{where}: {obj} < {s['minimum']}")
    if isinstance(obj, dict):
        for k in s.get("required", []):
            if k not in obj:
                problems.append(f"{where}: missing {k!r}")
        props = s.get("properties", {})
        if s.get("additionalProperties") is False:
            problems.extend(f"{where}: unexpected {k!r}" for k in obj if k not in props)
        for k, sub in props.items():
            if k in obj:
                problems.extend(validate_report(obj[k], sub, f"{where}.{k}"))
    if isinstance(obj, list) and "items" in s:
        for i, x in enumerate(obj):
            problems.extend(validate_report(x, s["items"], f"{where}[{i}]"))
    return problems


_TAKES_FIELDS: list[pa.Field] = [
    pa.field("session", pa.string(), nullable=False),
    pa.field("take", pa.string(), nullable=False),
    pa.field("kind", pa.string(), nullable=False),
    pa.field("pose", pa.string(), nullable=False),
    pa.field("severity", pa.string(), nullable=False),
    pa.field("n_fail", pa.int32(), nullable=False),         # checks at fail or error
    pa.field("n_warning", pa.int32(), nullable=False),
    pa.field("failing", pa.string(), nullable=False),       # ids of the checks at warning or worse, worst first
    pa.field("stages_failed", pa.string(), nullable=False),
    pa.field("frames", pa.int64()),                         # frames of the capture
    pa.field("rate_hz", pa.float64()),
    pa.field("kept_frames", pa.int64()),
    pa.field("crop_start", pa.int64()),
    pa.field("crop_stop", pa.int64()),
    pa.field("gap_share_max", pa.float64()),                # worst marker, at ingest
    pa.field("longest_gap_s", pa.float64()),
    pa.field("fill_error_max_mm", pa.float64()),
    pa.field("filled_share", pa.float64()),                 # kept samples filled by any method
    pa.field("unfilled_share_max", pa.float64()),           # worst marker, kept frames
    pa.field("spikes_removed", pa.int64()),
    pa.field("invalid_frames_share", pa.float64()),
    pa.field("clap_offset_s", pa.float64()),
    pa.field("clock_drift_ppm", pa.float64()),
    pa.field("clap_confidence_min", pa.float64()),
    pa.field("frames_without_video_share", pa.float64()),
    pa.field("eye_gated_share", pa.float64()),
    pa.field("camera_residual_deg", pa.float64()),
]
TAKES_SCHEMA = with_identity(pa.schema(_TAKES_FIELDS), "qc_takes", TAKES_SCHEMA_VERSION)
