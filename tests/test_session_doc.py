"""docs/session-format.md: every key the readers accept is documented there, every TOML example in it is valid
(each snippet in a session or markerset the readers accept), the complete example is a first session that runs
from the page alone, and an error naming a key links to a section of the page that exists."""

from __future__ import annotations

import re
import shutil
import tomllib
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.io import markerset_toml, session_toml
from gazepipe.io.markerset_toml import validate_markerset
from gazepipe.io.session_toml import validate_session
from tests.helpers import REPO, SAMPLE

DOC = REPO / "docs" / "session-format.md"
TEXT = DOC.read_text()
BLOCKS = re.findall(r"```toml\n(.*?)```", TEXT, flags=re.S)
MARKERSET_KEYS = set(markerset_toml._MARKERSET_TOP) - {"schema"}


def _example(name: str) -> str:
    """The complete example's file ``name`` (its block starts with ``# name``)."""
    found = [b for b in BLOCKS if b.startswith(f"# {name}\n")]
    assert len(found) == 1, name
    return found[0]


def slugs() -> set[str]:
    """The anchors GitHub makes of the page's headings (lower case, punctuation but ``-`` and ``_`` dropped,
    spaces to ``-``)."""
    heads = re.findall(r"^#+ (.+)$", TEXT, flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in heads}


def test_every_key_the_readers_accept_is_documented() -> None:
    keys = (set(session_toml._SESSION_TOP) | set(session_toml._SESSION_KEYS) | set(session_toml._DEFAULT_KEYS)
            | set(session_toml._TAKE_KEYS) | set(session_toml.TAKE_KINDS) | {"yaw_deg", "pitch_deg"}
            | set(markerset_toml._MARKERSET_TOP) | {"markers", "parent", "segments", "rotation"})
    forms = ("`{}`", "### {}\n", "`[{}]`", "`[[{}]]`", "`[{}.")     # a key, its section, a table of it
    missing = sorted(k for k in keys if not any(f.format(k) in TEXT for f in forms))
    assert missing == []
    # each of the markerset's top-level keys has its own section, and the links in the page land on sections
    assert {"up_axis", "units", "root", "target", "clapper", "head_centre", "eye_offset_mm", "segmentsname", "lod",
            "camera", "session", "defaults", "takes", "schema"} <= slugs()
    assert set(re.findall(r"\]\(#([\w-]+)\)", TEXT)) <= slugs()


def _dump(doc: dict[str, Any]) -> str:
    """TOML text of a markerset document (strings, numbers, arrays of them, tables of those)."""
    def value(v: Any) -> str:
        if isinstance(v, str):
            return '"' + v + '"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)
    lines = [f"{k} = {value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for k, v in doc.items():
        if isinstance(v, dict):
            for name, table in (v.items() if k == "segments" else [(None, v)]):
                lines.append(f"[{k}.{name}]" if name else f"[{k}]")
                lines += [f"{a} = {value(b)}" for a, b in table.items()]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("block", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_every_example_of_the_page_is_valid(block: str, tmp_path: Path) -> None:
    """A markerset snippet in the complete example's markerset (its keys replacing those), a session snippet in
    a session around it (a [session] and a take where it has none): the readers find no problem."""
    doc = tomllib.loads(block)
    base = tomllib.loads(_example("markerset.toml"))
    if set(doc) & MARKERSET_KEYS:
        merged = {**base, **doc}
        if "segments" in doc and "lod" not in doc:
            merged.pop("lod", None)
        (tmp_path / "markerset.toml").write_text(_dump(merged))
        assert [e.one_line() for e in validate_markerset(tmp_path / "markerset.toml")] == []
        return
    (tmp_path / "markerset.toml").write_text(_dump(base))
    text = block
    if "session" not in doc:      # TOML tables come in any order: after the snippet's own keys and tables
        text += '\n[session]\nsubject = "p01"\nmarkerset = "markerset.toml"\n'
    if "takes" not in doc:
        text += '\n[[takes]]\nid = "n"\nkind = "neutral"\nmocap = "mocap/neutral.c3d"\n'
    (tmp_path / "session.toml").write_text(text)
    assert [e.one_line() for e in validate_session(tmp_path)] == []


def test_the_complete_example_is_a_first_session_that_runs(tmp_path: Path) -> None:
    """The page's two files beside the capture files they name (the sample session's): `gazepipe run` builds
    every take and the four datasets, and the QC gate passes."""
    folder = tmp_path / "first"
    folder.mkdir()
    session, markerset = _example("session.toml"), _example("markerset.toml")
    (folder / "session.toml").write_text(session)
    (folder / "markerset.toml").write_text(markerset)
    takes = tomllib.loads(session)["takes"]
    for t in takes:
        for key in ("mocap", "video", "eyes", "tracked", "clean"):
            if key in t:
                (folder / t[key]).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(SAMPLE / t[key], folder / t[key])
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["run", str(folder), "--out", str(out), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code == 0, res.output[-3000:]
    assert sorted(p.name for p in (out / "takes" / "first").iterdir()) == sorted(t["id"] for t in takes)
    assert sorted(p.name for p in (out / "datasets").iterdir()) == ["face_clean", "gaze_map", "gaze_rnn",
                                                                     "gaze_rnn_lod"]
    res = CliRunner().invoke(cli, ["validate", str(out), "--fail-on", "fail", "--no-plots"])
    assert res.exit_code == 0, res.output


@pytest.mark.parametrize("file, edit, key, anchor", [
    ("session.toml", lambda t: t.replace('rate_hz = 60\n', ''), "takes[6].rate_hz", "takes"),
    ("session.toml", lambda t: t.replace('[defaults]\npose = "standing"', '[defaults]\npose = "standing"\nsplit = "dev"'),
     "defaults.split", "defaults"),
    ("session.toml", lambda t: t.replace('subject = "p01"\n', ''), "session.subject", "session"),
    ("session.toml", lambda t: t.replace("schema = 1", "schema = 2"), "schema", "schema"),
    ("markerset.toml", lambda t: t.replace('up_axis = "z"', 'up_axis = "x"'), "up_axis", "up_axis"),
    ("markerset.toml", lambda t: t.replace('parent = "neck3"', 'parent = "neck9"'), "segments.head.parent",
     "segmentsname"),
    ("markerset.toml", lambda t: t.replace('"chest", "head"]', '"chest", "hed"]'), "lod.segments[2]", "lod"),
    ("markerset.toml", lambda t: t.replace("rotation = [0.1735", "rotation = [0.5"), "camera.rotation", "camera"),
    ("markerset.toml", lambda t: t.replace('clapper = ["CLAP1", "CLAP2"]\n', ''), "clapper", "clapper"),
])
def test_an_error_naming_a_key_links_to_its_section(file, edit, key, anchor, tmp_path: Path) -> None:
    """One line naming the file and the key, ending with the page's section on that key (which exists)."""
    (tmp_path / "session.toml").write_text(_example("session.toml"))
    (tmp_path / "markerset.toml").write_text(_example("markerset.toml"))
    (tmp_path / file).write_text(edit((tmp_path / file).read_text()))
    errors = validate_session(tmp_path)
    assert len(errors) == 1, [e.one_line() for e in errors]
    line = errors[0].one_line()
    assert f"{tmp_path / file}: {key}: " in line and line.endswith(f"(see docs/session-format.md#{anchor})"), line
    assert anchor in slugs()
    res = CliRunner().invoke(cli, ["run", str(tmp_path), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and res.stderr.strip() == f"error: {line}"


def test_a_markerset_without_lod_asks_for_no_lod_dataset(tmp_path: Path) -> None:
    """[lod] is optional: the sample session without it plans gaze_rnn from its gaze_follow takes, and neither
    rows of gaze_rnn_lod nor its build (which would fail on every take for want of the segments)."""
    folder = tmp_path / "nolod"
    shutil.copytree(SAMPLE, folder, ignore=shutil.ignore_patterns("truth"))
    ms = (folder / "markerset.toml").read_text()
    assert "[lod]\n" in ms
    (folder / "markerset.toml").write_text(ms[:ms.index("[lod]\n")])
    res = CliRunner().invoke(cli, ["run", str(folder), "--out", str(tmp_path / "out"), "--dry-run",
                                   "--log-format", "text"])
    assert res.exit_code == 0, res.output[-3000:]
    assert "dataset gaze_rnn: would build" in res.output
    assert "gaze_rnn_lod" not in res.output
