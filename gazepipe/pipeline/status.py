"""`gazepipe status`: the state of every unit in an output folder, compared with its inputs now."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from gazepipe.errors import GazepipeError
from gazepipe.pipeline.builds import plan_datasets
from gazepipe.pipeline.engine import plan_run
from gazepipe.pipeline.hashing import HashCache
from gazepipe.pipeline.registry import SessionLike
from gazepipe.pipeline.runner import SESSION_UNIT
from gazepipe.pipeline.state import OutLayout, all_records, read_json


def collect_status(out: Path, load_session: Callable[[str], SessionLike],
                   params: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """One row per unit: session, take, stage, state (ok | failed | stale | pending), detail, duration; a
    dataset's row also has ``dataset`` (its name; session ``-``, take ``dataset NAME``). Units are compared
    with ``params`` (stage -> name -> value overrides; default: every default). Each session the output folder
    remembers is loaded again with ``load_session(path)`` (a :class:`GazepipeError` makes its row stale)."""
    layout = OutLayout(out)
    records = {(r.get("session"), r.get("take"), r.get("stage")): r for r in all_records(layout)}
    rows: list[dict[str, Any]] = []
    seen: set[tuple] = set()
    sessions = []
    for sid, path in sorted((read_json(layout.sessions) or {}).items()):
        try:
            sessions.append(load_session(path))
        except GazepipeError as exc:
            rows.append({"session": sid, "take": "-", "stage": "-", "state": "stale",
                         "detail": f"session cannot be read now: {exc.one_line()}"})
    planned = plan_run(sessions, out, params=params, hashes=HashCache(layout.hashes))
    failures, plans = planned.failures, planned.plans
    for f in failures:
        rows.append({"session": f.session, "take": f.take, "stage": f.stage, "state": "failed", "detail": f.error})
        seen.add((f.session, f.take, f.stage))
    for p in plans:
        key = (p.session, p.take, p.stage)
        seen.add(key)
        rec = (read_json(layout.session_record(p.session, p.stage)) if p.take == SESSION_UNIT
               else records.get(key))
        row: dict[str, Any] = {"session": p.session, "take": p.take, "stage": p.stage}
        if rec is None:
            row.update(state="pending", detail="never ran")
        elif rec.get("status") == "failed":
            row.update(state="failed", detail=rec.get("error", ""))
        elif p.run:
            row.update(state="stale", detail=p.reason)
        else:
            row.update(state="ok", detail="")
        if rec is not None:
            row["duration_s"] = rec.get("duration_s")
        rows.append(row)
    datasets = {d.name: d for d in plan_datasets(sessions, layout, plans, {})}
    for path in sorted((layout.state / "datasets").glob("*.json")):
        rec = read_json(path) or {}
        name = path.stem
        row = {"session": "-", "take": f"dataset {name}", "stage": "build", "dataset": name,
               "duration_s": rec.get("duration_s")}
        if rec.get("status") == "failed":
            row.update(state="failed", detail=rec.get("error", ""))
        elif name in datasets and datasets[name].run:
            row.update(state="stale", detail=datasets[name].reason)
        else:
            row.update(state="ok", detail="")
        rows.append(row)
    for rec_key, rec in sorted(records.items(), key=lambda kv: tuple(map(str, kv[0]))):
        if rec_key not in seen:
            rows.append({"session": rec_key[0], "take": rec_key[1], "stage": rec_key[2],
                         "state": "failed" if rec.get("status") == "failed" else "ok",
                         "detail": "no longer in its session", "duration_s": rec.get("duration_s")})
    return rows
