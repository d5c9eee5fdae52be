"""``gazepipe status``: its table and its JSON, from the unit rows (:func:`gazepipe.dag.collect_status`) and the
output folder's lock (:func:`gazepipe.pipeline.lock.lock_state`)."""

from __future__ import annotations

from typing import Any

from gazepipe.pipeline.lock import LockHolder

STATES = ("ok", "failed", "stale", "pending")
HEADER = ("take or dataset", "stage", "state", "detail")


def _dataset(row: dict[str, Any]) -> str | None:
    """The dataset a row is about, else ``None``."""
    return row.get("dataset")


def what(row: dict[str, Any]) -> str:
    """What a row is about, plainly: ``session/take``, ``dataset NAME`` or ``session NAME``."""
    name = _dataset(row)
    if name is not None:
        return f"dataset {name}"
    if row.get("take") == "-":
        return f"session {row.get('session')}"
    return f"{row.get('session')}/{row.get('take')}"


def counts(rows: list[dict[str, Any]]) -> dict[str, int]:
    """The number of rows in each state."""
    return {s: sum(r["state"] == s for r in rows) for s in STATES}


def _count_line(rows: list[dict[str, Any]]) -> str:
    """``take units: 46 ok, 4 stale; datasets: 4 ok`` (the states there are)."""
    parts = []
    for label, part in (("take units", [r for r in rows if not _dataset(r)]),
                        ("datasets", [r for r in rows if _dataset(r)])):
        if part:
            parts.append(f"{label}: " + ", ".join(f"{k} {s}" for s, k in counts(part).items() if k))
    return "; ".join(parts)


def lock_line(holder: LockHolder | None) -> str | None:
    """One line about the lock: a run in progress, a stale lock, or ``None`` when nobody holds it."""
    if holder is None:
        return None
    if holder.state == "stale":
        return (f"stale lock: the run that held this output folder ({holder.describe()}) is gone; "
                "the next run takes the lock over")
    return f"a run is in progress ({holder.describe()}): the states below are from before it and change as it goes"


def table_lines(rows: list[dict[str, Any]], holder: LockHolder | None) -> list[str]:
    """The lines ``gazepipe status`` prints: the lock, a header, one row per unit and dataset, the counts."""
    lines = [line] if (line := lock_line(holder)) else []
    if not rows:
        return [*lines, "nothing has run in this output folder yet"]
    width = max(len(HEADER[0]), *(len(what(r)) for r in rows))
    stage = max(8, *(len(str(r["stage"])) for r in rows))
    lines.append(f"{HEADER[0]:<{width}}  {HEADER[1]:<{stage}} {HEADER[2]:<7} {HEADER[3]}".rstrip())
    for r in rows:
        lines.append(f"{what(r):<{width}}  {r['stage']:<{stage}} {r['state']:<7} {r.get('detail') or ''}".rstrip())
    lines.append(_count_line(rows))
    return lines


def status_json(out: str, rows: list[dict[str, Any]], holder: LockHolder | None) -> dict[str, Any]:
    """``status --json``: ``{"output", "lock", "units", "datasets", "counts"}``.

    ``lock`` is ``null`` or ``{"state": "held" | "stale", "pid", "started", "host", "command"}``; ``units`` has
    one object per take unit (``session``, ``take``, ``stage``, ``state``, ``detail``, ``duration_s``) and per
    session that cannot be read now (``take`` null); ``datasets`` one per dataset (``dataset``, ``state``,
    ``detail``, ``duration_s``); ``counts`` the number of each state, ``{"units": {...}, "datasets": {...}}``.
    """
    units, datasets = [], []
    for r in rows:
        name = _dataset(r)
        if name is None:
            units.append({**r, "take": None if r.get("take") == "-" else r.get("take"),
                          "stage": None if r.get("stage") == "-" else r.get("stage")})
        else:
            datasets.append({k: v for k, v in r.items() if k not in ("session", "take", "stage")})
    return {"output": out, "lock": holder.to_dict() if holder else None, "units": units, "datasets": datasets,
            "counts": {"units": counts(units), "datasets": counts(datasets)}}
