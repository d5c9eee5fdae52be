"""Errors under ``--json`` (issue 46): one JSON object on one line of stderr, stdout left empty, the same exit
code as the text error."""

from __future__ import annotations

import json
import sys

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli, main
from tests.helpers import CORPUS


def _run(*args: str):
    return CliRunner().invoke(cli, list(args))


def _error(stderr: str) -> dict:
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    return json.loads(lines[0])


@pytest.mark.parametrize(("args", "kind", "code"), [
    (["inspect", "{tmp}/missing.c3d"], "InputError", 1),
    (["inspect", str(CORPUS / "openface" / "PROVENANCE.md")], "InputError", 1),
    (["fill", str(CORPUS / "c3d" / "Eb015pi.c3d"), "{tmp}/no/such/folder/x.c3d"], "ConfigError", 2),
    (["status", "{tmp}"], "ConfigError", 2),
])
def test_json_errors_are_one_json_line_with_the_text_errors_exit_code(tmp_path, args, kind, code):
    args = [a.format(tmp=tmp_path) for a in args]
    text = _run(*args)
    res = _run(*args, "--json")
    assert text.exit_code == res.exit_code == code
    assert text.stderr.startswith("error: ")
    assert res.stdout == ""
    err = _error(res.stderr)["error"]
    assert err["kind"] == kind and err["exit_code"] == code
    assert err["message"] == text.stderr.strip().removeprefix("error: ")
    assert set(err) == {"message", "kind", "exit_code", "file", "key", "take"}


def test_a_json_error_names_the_file_and_key(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("Trajectories\nfast\n,,A,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n1,0,1,2,3\n")
    err = _error(_run("inspect", str(p), "--json").stderr)["error"]
    assert err["file"] == str(p) and "rate line reads 'fast'" in err["message"] and err["take"] is None


def test_several_problems_are_one_json_object(tmp_path):
    """``status`` with two unknown parameters: the text prints two error lines; ``--json`` one object with both."""
    out = tmp_path / "out"
    (out / ".gazepipe").mkdir(parents=True)
    text = _run("status", str(out), "--param", "clean.nope=1", "--param", "eyes.nada=2")
    res = _run("status", str(out), "--param", "clean.nope=1", "--param", "eyes.nada=2", "--json")
    assert text.exit_code == res.exit_code == 2 and len(text.stderr.splitlines()) == 2
    obj = _error(res.stderr)
    assert "eyes.nada" in obj["error"]["message"] and len(obj["errors"]) == 1 and "clean.nope" in obj["errors"][0]


@pytest.mark.parametrize(("argv", "code"), [(["inspect", "--json", "--rate-hz", "-5", "x.c3d"], 2),
                                            (["inspect", "--json", "--bogus", "x.c3d"], 2),
                                            (["inspect", "--json"], 2)])
def test_usage_errors_under_json_are_json_too(monkeypatch, capsys, argv, code):
    """Errors click finds before the command runs (a bad option or value, a missing argument): a JSON line under
    ``--json`` as well, with click's exit code."""
    monkeypatch.setattr(sys, "argv", ["gazepipe", *argv])
    with pytest.raises(SystemExit) as ex:
        main()
    assert ex.value.code == code
    out = capsys.readouterr()
    assert out.out == ""
    err = _error(out.err)["error"]
    assert err["exit_code"] == code and err["kind"] in ("BadParameter", "NoSuchOption", "MissingParameter")


def test_json_success_and_help_are_unchanged(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["gazepipe", "inspect", "--json", str(CORPUS / "c3d" / "Eb015pi.c3d")])
    with pytest.raises(SystemExit) as ex:
        main()
    assert ex.value.code == 0
    assert json.loads(capsys.readouterr().out)["format"] == "c3d"
    monkeypatch.setattr(sys, "argv", ["gazepipe", "inspect", "--json", "--help"])
    with pytest.raises(SystemExit) as ex:
        main()
    assert ex.value.code == 0 and "Summarise a capture file" in capsys.readouterr().out
