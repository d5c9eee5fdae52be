"""The command line as the README teaches it: ``--debug`` before or after any command, the QC gate on
``run``'s last lines, ``params`` once per parameter, the stage commands' own help, ``inspect`` on C3D
storage and on files that are not captures."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli


def invoke(*args: str, **kw):
    return CliRunner().invoke(cli, list(args), **kw)


# ------------------------------------------------------------------------------------------------ --debug

def test_every_command_shows_and_accepts_debug():
    for name, command in cli.commands.items():
        text = invoke(name, "--help", terminal_width=200).output
        assert "--debug" in text and "Show tracebacks" in text, name
        assert sum(p.name == "debug" for p in command.params) == 1, name


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_before_or_after_the_command_shows_the_traceback(tmp_path, monkeypatch, where):
    import gazepipe.io.inspect_tracks as it

    def broken(*a, **k):
        raise RuntimeError("a bug")

    monkeypatch.setattr(it, "inspect_file", broken)
    f = tmp_path / "a.c3d"
    f.write_bytes(b"x")
    res = invoke("inspect", str(f))
    assert res.exit_code == 1
    assert res.stderr.strip() == "error: internal error: RuntimeError: a bug (run with --debug for the traceback)"
    args = ["--debug", "inspect", str(f)] if where == "before" else ["inspect", str(f), "--debug"]
    res = invoke(*args)
    assert res.exit_code == 1 and "Traceback (most recent call last)" in res.stderr
    assert "raise RuntimeError" in res.stderr and "run with --debug" not in res.stderr


def test_debug_after_a_stage_command_is_accepted(tmp_path):
    res = invoke("run", str(tmp_path / "none"), "--out", str(tmp_path / "o"), "--debug")
    assert "No such option" not in res.output
    res = invoke("run", "--debug", "--help")
    assert res.exit_code == 0
