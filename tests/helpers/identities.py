"""What identifies each unit of the sample session's run (its fingerprint and code identity) beside a digest of
what it wrote: ``tests/data/sample_identities.json`` keeps them as a run made them, so a later run can show that
outputs never change under an unchanged identity (an output folder would otherwise keep them as up to date).

Refresh the record after a deliberate change of the sample's outputs (or of the code, to keep it judging every
unit): ``python -m tests.helpers.identities`` (runs the sample, about a minute).
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

RECORD = Path(__file__).resolve().parents[1] / "data" / "sample_identities.json"


def _files_digest(files: list[Path]) -> str:
    h = hashlib.sha256()
    for path in files:
        h.update(f"{path.name}\0{hashlib.sha256(path.read_bytes()).hexdigest()}\n".encode())
    return h.hexdigest()


def unit_identities(out: Path) -> dict[str, dict[str, Any]]:
    """For every unit and dataset record of the output folder ``out``: ``identity`` (the unit's fingerprint and
    code identity; a dataset's fingerprint, which covers its code and its takes' code) and ``outputs`` (sha256
    over the bytes of the files its record lists)."""
    state = out / ".gazepipe"
    got: dict[str, dict[str, Any]] = {}
    for rec_path in sorted((state / "units").glob("*/*/*.json")):
        rec = json.loads(rec_path.read_text())
        folder = out / "takes" / rec["session"] / rec["take"]
        got[f"{rec['session']}/{rec['take']}/{rec['stage']}"] = {
            "identity": [rec["fingerprint"], rec.get("code")],
            "outputs": _files_digest([folder / n for n in sorted(rec.get("outputs", {}))])}
    for rec_path in sorted((state / "session_units").glob("*/*.json")):
        rec = json.loads(rec_path.read_text())
        folder = out / "sessions" / rec["session"]
        got[f"{rec['session']}/*/{rec['stage']}"] = {
            "identity": [rec["fingerprint"], rec.get("code")],
            "outputs": _files_digest([folder / n for n in sorted(rec.get("outputs", {}))])}
    for rec_path in sorted((state / "datasets").glob("*.json")):
        rec = json.loads(rec_path.read_text())
        folder = out / "datasets" / rec["dataset"]
        got[f"dataset/{rec['dataset']}"] = {
            "identity": [rec["fingerprint"]],
            "outputs": _files_digest([folder / n for n in sorted(rec.get("outputs", {}))])}
    return got


def main() -> None:
    from click.testing import CliRunner

    from gazepipe.cli.main import cli
    from tests.helpers import SAMPLE

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        res = CliRunner().invoke(cli, ["run", str(SAMPLE), "--out", str(out), "--executor", "serial"])
        if res.exit_code != 0:
            sys.exit(res.output[-3000:])
        RECORD.write_text(json.dumps(unit_identities(out), indent=1, sort_keys=True) + "\n")
    print(f"wrote {RECORD}")


if __name__ == "__main__":
    main()
