"""Run state under ``OUT/.gazepipe/``: one JSON record per unit of work, the hash cache, temporaries, runs.

Layout::

    OUT/takes/<session>/<take>/<table>.parquet       outputs of take stages
    OUT/sessions/<session>/<table>.parquet           outputs of session stages
    OUT/.gazepipe/units/<session>/<take>/<stage>.json  unit records (fingerprint, status, QC, error, timing)
    OUT/.gazepipe/session_units/<session>/<stage>.json records of session stages' units
    OUT/.gazepipe/sessions.json                      session id -> session folder, for `gazepipe status`
    OUT/.gazepipe/hashes.json                        input hash cache
    OUT/.gazepipe/runs/<run id>.json                 what each run did
    OUT/.gazepipe/tmp/                               temporaries of atomic writes
    OUT/.gazepipe/datasets/<name>.json               dataset build records
    OUT/.gazepipe/report_plots/                      the QC report's figures, reused while their inputs hold
    OUT/.gazepipe/lock                               the output folder's lock (pid and start of the run holding it)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gazepipe.pipeline.atomic import atomic_write_bytes

STATE_DIRNAME = ".gazepipe"


@dataclass(frozen=True)
class OutLayout:
    """Paths inside an output folder."""

    root: Path

    @property
    def state(self) -> Path:
        return self.root / STATE_DIRNAME

    @property
    def tmp(self) -> Path:
        return self.state / "tmp"

    @property
    def lock(self) -> Path:
        return self.state / "lock"

    @property
    def hashes(self) -> Path:
        return self.state / "hashes.json"

    @property
    def sessions(self) -> Path:
        return self.state / "sessions.json"

    def runs(self) -> Path:
        return self.state / "runs"

    def take_dir(self, session: str, take: str) -> Path:
        return self.root / "takes" / session / take

    def table(self, session: str, take: str, name: str) -> Path:
        return self.take_dir(session, take) / f"{name}.parquet"

    def record(self, session: str, take: str, stage: str) -> Path:
        return self.state / "units" / session / take / f"{stage}.json"

    def session_table(self, session: str, name: str) -> Path:
        return self.root / "sessions" / session / f"{name}.parquet"

    def session_record(self, session: str, stage: str) -> Path:
        return self.state / "session_units" / session / f"{stage}.json"

    def write_bytes(self, path: Path, data: bytes) -> None:
        atomic_write_bytes(path, data, self.tmp)

    def write_json(self, path: Path, obj: Any) -> None:
        self.write_bytes(path, (json.dumps(obj, indent=1, sort_keys=True, default=str) + "\n").encode())


def read_json(path: Path) -> Any | None:
    """A JSON file's content, or ``None`` when it is absent or unreadable (a record is then treated as stale)."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def all_records(layout: OutLayout) -> list[dict[str, Any]]:
    """Every unit record under the output folder, sorted by session, take and stage name. A record whose
    ``session``, ``take`` and ``stage`` are not where it lies (``units/<session>/<take>/<stage>.json``: a take
    that is a path, ``x/../../escaped``) is not the engine's and is left out, so no path is made from it."""
    base = layout.state / "units"
    recs = []
    if base.is_dir():
        for p in sorted(base.glob("*/*/*.json")):
            rec = read_json(p)
            if isinstance(rec, dict) and (rec.get("session"), rec.get("take"), rec.get("stage")) == \
                    (p.parent.parent.name, p.parent.name, p.stem):
                recs.append(rec)
    return recs


def outputs_fingerprint(layout: OutLayout) -> str:
    """A hash of what the output folder holds: every unit's and dataset's fingerprint and status.

    The QC report records it, so a run can tell whether the report describes the current outputs (a run killed
    after its units but before its report leaves a report that no longer does).
    """
    import hashlib

    h = hashlib.sha256()
    for p in (sorted(layout.state.glob("session_units/*/*.json")) + sorted(layout.state.glob("units/*/*/*.json"))
              + sorted(layout.state.glob("datasets/*.json"))):
        rec = read_json(p) or {}
        h.update(f"{p.relative_to(layout.state)}\0{rec.get('fingerprint')}\0{rec.get('status')}\n".encode())
    return h.hexdigest()
