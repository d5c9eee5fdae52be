"""The JSON log (the default off a terminal: cron, CI) carries one line per failure; the traceback behind it only
with --debug, as on a terminal."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from gazepipe.cli.main import cli
from tests.helpers import session_copy


def _events(tmp_path: Path, *extra: str) -> list[dict]:
    session = tmp_path / "session"
    if not session.exists():
        session_copy(session, {"neutral": None, "shift_y036_p12": None})
        # a capture that lacks a marker of the markerset: each take fails in its ingest unit
        ms = session / "markerset.toml"
        ms.write_text(ms.read_text().replace('markers = ["', 'markers = ["NOPE", "', 1))
    res = CliRunner().invoke(cli, [*extra, "ingest", str(session), "--out", str(tmp_path / f"out{len(extra)}"),
                                   "--executor", "serial", "--log-format", "json"])
    assert res.exit_code == 1, res.output
    return [json.loads(line) for line in res.stderr.splitlines() if line.startswith("{")]


def test_the_json_log_has_no_traceback_without_debug(tmp_path: Path) -> None:
    events = _events(tmp_path)
    failed = [e for e in events if e.get("status") == "failed" and e["event"] == "unit"]
    assert failed and all("NOPE" in e["message"] for e in failed)
    assert not any("traceback" in e for e in events)
    assert all("\n" not in e["message"] for e in events)


def test_debug_puts_the_traceback_in_the_json_log(tmp_path: Path) -> None:
    events = _events(tmp_path, "--debug")
    failed = [e for e in events if e.get("status") == "failed" and e["event"] == "unit"]
    assert failed and all(e.get("traceback", "").startswith("Traceback") for e in failed)
