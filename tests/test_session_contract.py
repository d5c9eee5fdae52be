"""The session contract: session.toml / markerset.toml loading, validation and capture label mapping."""

from __future__ import annotations

import copy
import json
import math
import os
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gazepipe.errors import ConfigError, InputError
from gazepipe.io.session_toml import (
    check_capture_labels,
    load_markerset,
    load_session,
    validate_markerset,
    validate_session,
)

SESSION_TOML = """\
schema = 1
[session]
id = "s01"
subject = "p01"
markerset = "markerset.toml"

[defaults]
pose = "standing"

[[takes]]
id = "follow_standing_01"
kind = "gaze_follow"
pose = "sitting"
mocap = "mocap/follow_standing_01.c3d"
video = "video/follow_standing_01.mp4"
eyes = "eyes/follow_standing_01.csv"
split = "val"

[[takes]]
id = "shift_y036_p12"
kind = "gaze_shift"
mocap = "mocap/shift_y036_p12.c3d"
target = { yaw_deg = 36.0, pitch_deg = -12 }

[[takes]]
id = "face_01"
kind = "face"
tracked = "face/face_01_tracked.csv"
clean = "face/face_01_clean.csv"
rate_hz = 59.94

[[takes]]
id = "neutral"
kind = "neutral"
mocap = "mocap/neutral.c3d"
"""

MARKERSET_TOML = """\
schema = 1
up_axis = "z"
units = "mm"
root = "SACR"
target = "POLE"
clapper = ["CLAP1", "CLAP2"]
eye_offset_mm = [0, -60, 90.5]

[segments.pelvis]
markers = ["PEL1", "PEL2", "PEL3"]
[segments.spine]
markers = ["SPN1", "SPN2", "SPN3"]
parent = "pelvis"
[segments.neck]
markers = ["NCK1", "NCK2", "NCK3"]
parent = "spine"
[segments.head]
markers = ["HFL", "HFR", "HBL", "HBR", "HTOP"]
parent = "neck"

[lod]
segments = ["pelvis", "head"]

[camera]
rotation = [0.7071, 0.0, 0.7071, 0.0]
"""

DATA_FILES = ("mocap/follow_standing_01.c3d", "video/follow_standing_01.mp4", "eyes/follow_standing_01.csv",
              "mocap/shift_y036_p12.c3d", "face/face_01_tracked.csv", "face/face_01_clean.csv",
              "mocap/neutral.c3d")


def make_session(base: Path, session_text: str = SESSION_TOML, markerset_text: str = MARKERSET_TOML) -> Path:
    root = base / "s01"
    for rel in DATA_FILES:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(b"placeholder")
    (root / "session.toml").write_text(session_text, encoding="utf-8")
    (root / "markerset.toml").write_text(markerset_text, encoding="utf-8")
    return root


# ------------------------------------------------------------------------------------- a tiny TOML writer for tests

def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_value(str(k))} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def dump_toml(doc: dict) -> str:
    """Every top-level key as ``key = <inline value>`` (valid TOML 1.0)."""
    return "".join(f"{_toml_value(str(k))} = {_toml_value(v)}\n" for k, v in doc.items())


def test_writer_round_trips():
    for text in (SESSION_TOML, MARKERSET_TOML):
        doc = tomllib.loads(text)
        assert tomllib.loads(dump_toml(doc)) == doc


# ------------------------------------------------------------------------------------------------ the valid session

def test_valid_session_loads(tmp_path):
    root = make_session(tmp_path)
    assert validate_session(root) == []
    s = load_session(root)
    assert load_session(root / "session.toml") == s
    assert s.root == str(root.resolve()) and s.path == str(root.resolve() / "session.toml")
    assert (s.id, s.subject) == ("s01", "p01")
    assert [t.id for t in s.takes] == ["follow_standing_01", "shift_y036_p12", "face_01", "neutral"]
    follow, shift, face, neutral = s.takes
    assert [t.kind for t in s.takes] == ["gaze_follow", "gaze_shift", "face", "neutral"]
    assert follow.pose == "sitting"  # the take's own pose beats [defaults]
    assert shift.pose == face.pose == neutral.pose == "standing"
    assert follow.split == "val" and shift.split is None
    for t in s.takes:
        for f in t.files:
            assert os.path.isabs(f) and Path(f).is_file() and Path(f).is_relative_to(s.root)
    assert follow.files == tuple(str((root / r).resolve()) for r in DATA_FILES[:3])
    assert face.tracked == str((root / "face/face_01_tracked.csv").resolve())
    assert (shift.target_yaw_deg, shift.target_pitch_deg) == (36.0, -12.0)
    assert follow.target_yaw_deg is None
    assert face.rate_hz == 60000 / 1001  # 59.94 is NTSC 60
    assert face.timecode_fps == 60.0 and follow.rate_hz is None

    ms = s.markerset
    assert ms is not None and ms.path == str(root.resolve() / "markerset.toml")
    assert (ms.up_axis, ms.units, ms.root, ms.target) == ("z", "mm", "SACR", "POLE")
    assert ms.clapper == ("CLAP1", "CLAP2") and ms.head_centre is None
    assert ms.eye_offset_mm == (0.0, -60.0, 90.5)
    assert [g.name for g in ms.segments] == ["pelvis", "spine", "neck", "head"]
    assert [g.parent for g in ms.segments] == [None, "pelvis", "spine", "neck"]
    assert ms.root_segment.name == "pelvis" and ms.segment("head").markers == ("HFL", "HFR", "HBL", "HBR", "HTOP")
    assert ms.lod_segments == ("pelvis", "head")
    q = ms.camera_rotation
    assert q is not None and math.isclose(math.fsum(c * c for c in q), 1.0, abs_tol=1e-12)
    assert q[0] == pytest.approx(math.sqrt(0.5), abs=1e-12) and q[1] == 0.0
    assert load_markerset(root / "markerset.toml") == ms


def test_defaults_and_absolute_paths(tmp_path):
    doc = tomllib.loads(SESSION_TOML)
    del doc["defaults"], doc["session"]["id"]
    doc["takes"] = [doc["takes"][2], doc["takes"][3]]
    root = make_session(tmp_path, dump_toml(doc))
    doc["takes"][1]["mocap"] = str(root / "mocap" / "neutral.c3d")  # absolute but inside: fine
    (root / "session.toml").write_text(dump_toml(doc))
    s = load_session(root)
    assert s.id == "s01"  # the folder's name
    assert [t.pose for t in s.takes] == ["unspecified", "unspecified"]
    assert s.takes[1].mocap == str((root / "mocap/neutral.c3d").resolve())
    # no mocap take and no markerset: still valid
    doc["takes"] = doc["takes"][:1]
    del doc["session"]["markerset"]
    (root / "session.toml").write_text(dump_toml(doc))
    assert load_session(root).markerset is None


# ----------------------------------------------------------------------------------------- one problem, one error

Mut = Callable[[dict, dict, Path], None]


def _set(path: str, value) -> Mut:
    """Mutation setting a dotted path (``takes.1.kind``) in the session (``S.``) or markerset (``M.``) doc."""
    which, *keys = path.split(".")

    def mut(sdoc: dict, mdoc: dict, root: Path) -> None:
        d = sdoc if which == "S" else mdoc
        for k in keys[:-1]:
            d = d[int(k)] if isinstance(d, list) else d[k]
        last = int(keys[-1]) if isinstance(d, list) else keys[-1]
        if value is _DELETE:
            del d[last]
        else:
            d[last] = value(root) if callable(value) else value
    return mut


_DELETE = object()


def _both(*muts: Mut) -> Mut:
    def mut(sdoc, mdoc, root):
        for m in muts:
            m(sdoc, mdoc, root)
    return mut


def _outside(root: Path) -> str:
    p = root.parent / "outside.c3d"
    p.write_bytes(b"x")
    return str(p)


def _symlink_out(root: Path) -> str:
    link = root / "mocap" / "link.c3d"
    link.symlink_to(_outside(root))
    return "mocap/link.c3d"


def _txt(root: Path) -> str:
    (root / "mocap" / "a.txt").write_text("x")
    return "mocap/a.txt"


def _swap_first_segments(sdoc, mdoc, root):
    seg = mdoc["segments"]
    mdoc["segments"] = {"spine": seg["spine"], "pelvis": seg["pelvis"], "neck": seg["neck"], "head": seg["head"]}


S, M = "session.toml", "markerset.toml"
CASES = [
    # (name, mutation, file, key, words)
    ("schema", _set("S.schema", 2), S, "schema", ["unsupported schema"]),
    ("schema_ms", _set("M.schema", "1"), M, "schema", ["unsupported schema"]),
    ("top_unknown", _set("S.sesion", {}), S, "sesion", ["unknown key", "'session'"]),
    ("kind", _set("S.takes.1.kind", "gaze_shfit"), S, "takes[1].kind", ["unknown take kind", "gaze_shift"]),
    ("pose_empty", _set("S.takes.0.pose", ""), S, "takes[0].pose", ["bad pose"]),
    ("pose_type", _set("S.takes.0.pose", 3), S, "takes[0].pose", ["must be a string", "integer"]),
    ("pose_missing", _set("S.defaults.pose", _DELETE), S, "takes[1].pose", ["missing", "defaults"]),
    ("dup_id", _set("S.takes.1.id", "follow_standing_01"), S, "takes[1].id", ["duplicate take id", "takes[0]"]),
    ("bad_id", _set("S.takes.0.id", "a b"), S, "takes[0].id", ["bad take id", "letters"]),
    ("dotdot", _set("S.takes.0.mocap", "../outside.c3d"), S, "takes[0].mocap", ["escapes the session folder"]),
    ("abs_out", _set("S.takes.0.mocap", _outside), S, "takes[0].mocap", ["escapes the session folder"]),
    ("symlink", _set("S.takes.3.mocap", _symlink_out), S, "takes[3].mocap", ["escapes the session folder"]),
    ("suffix", _set("S.takes.3.mocap", _txt), S, "takes[3].mocap", ["unsupported mocap file type"]),
    ("follow_no_mocap", _set("S.takes.0.mocap", _DELETE), S, "takes[0].mocap", ["missing", "gaze_follow"]),
    ("neutral_no_mocap", _set("S.takes.3.mocap", _DELETE), S, "takes[3].mocap", ["missing", "neutral"]),
    ("face_no_clean", _set("S.takes.2.clean", _DELETE), S, "takes[2].clean", ["missing", "face"]),
    ("face_no_rate", _set("S.takes.2.rate_hz", _DELETE), S, "takes[2].rate_hz", ["missing", "face"]),
    ("face_rate_0", _set("S.takes.2.rate_hz", 0), S, "takes[2].rate_hz", ["> 0"]),
    ("face_rate_str", _set("S.takes.2.rate_hz", "60"), S, "takes[2].rate_hz", ["number", "string"]),
    ("shift_no_target", _set("S.takes.1.target", _DELETE), S, "takes[1].target", ["missing", "gaze_shift"]),
    ("target_str", _set("S.takes.1.target.yaw_deg", "36"), S, "takes[1].target.yaw_deg", ["number"]),
    ("target_nopitch", _set("S.takes.1.target.pitch_deg", _DELETE), S, "takes[1].target.pitch_deg",
     ["missing"]),
    ("target_not_table", _set("S.takes.1.target", [36, 12]), S, "takes[1].target", ["must be a table"]),
    ("split", _set("S.takes.0.split", "validation"), S, "takes[0].split", ["bad split", "train"]),
    ("typo_key", _set("S.takes.0.vidoe", "x"), S, "takes[0].vidoe", ["unknown key", "did you mean 'video'"]),
    ("wrong_kind_key", _set("S.takes.2.target", {"yaw_deg": 1, "pitch_deg": 2}), S, "takes[2].target",
     ["does not apply", "face"]),
    ("subject_type", _set("S.session.subject", 5), S, "session.subject", ["must be a string"]),
    ("subject_missing", _set("S.session.subject", _DELETE), S, "session.subject", ["missing"]),
    ("no_markerset", _set("S.session.markerset", _DELETE), S, "session.markerset", ["missing", "mocap"]),
    ("markerset_out", _set("S.session.markerset", "../ms.toml"), S, "session.markerset", ["escapes"]),
    ("takes_empty", _set("S.takes", []), S, "takes", ["no [[takes]]"]),
    ("takes_str", _set("S.takes", "x"), S, "takes", ["array of tables"]),
    ("take_not_table", _set("S.takes.3", 7), S, "takes[3]", ["must be a table"]),
    ("up_axis", _set("M.up_axis", "x"), M, "up_axis", ["\"y\" or \"z\""]),
    ("units", _set("M.units", "furlong"), M, "units", ["unknown units"]),
    ("root_type", _set("M.root", 5), M, "root", ["marker name"]),
    ("root_missing", _set("M.root", _DELETE), M, "root", ["missing"]),
    ("target_empty", _set("M.target", ""), M, "target", ["bad marker name"]),
    ("target_missing", _set("M.target", _DELETE), M, "target", ["missing", "gaze_follow"]),
    ("target_on_segment", _set("M.target", "HTOP"), M, "target", ["also on segment", "head"]),
    ("target_is_root", _set("M.target", "SACR"), M, "target", ["also the root marker"]),
    ("clapper_is_head_centre", _set("M.head_centre", "CLAP2"), M, "clapper[1]", ["also the head centre"]),
    ("clapper_one", _set("M.clapper", ["CLAP1"]), M, "clapper", ["two marker names"]),
    ("clapper_missing", _set("M.clapper", _DELETE), M, "clapper", ["missing", "video"]),
    ("head_centre", _set("M.head_centre", 1), M, "head_centre", ["marker name"]),
    ("two_markers", _set("M.segments.spine.markers", ["SPN1", "SPN2"]), M, "segments.spine.markers",
     ["at least 3"]),
    ("unknown_parent", _set("M.segments.spine.parent", "pelvsi"), M, "segments.spine.parent",
     ["unknown parent", "did you mean 'pelvis'"]),
    ("cycle", _set("M.segments.pelvis.parent", "head"), M, "segments.pelvis.parent",
     ["parent cycle", "pelvis -> head"]),
    ("self_parent", _set("M.segments.head.parent", "head"), M, "segments.head.parent", ["parent cycle"]),
    ("two_roots", _set("M.segments.neck.parent", _DELETE), M, "segments.neck.parent",
     ["only one segment may lack a parent", "pelvis"]),
    ("order", _swap_first_segments, M, "segments.spine.parent", ["comes after", "root to the head"]),
    ("dup_marker", _set("M.segments.spine.markers", ["PEL1", "SPN2", "SPN3"]), M, "segments.spine.markers[0]",
     ["already on segment 'pelvis'"]),
    ("seg_typo", _set("M.segments.head.parnet", "neck"), M, "segments.head.parnet",
     ["unknown key", "did you mean 'parent'"]),
    ("lod", _set("M.lod.segments", ["pelvis", "chest"]), M, "lod.segments[1]", ["is not a segment"]),
    ("rot_len", _set("M.camera.rotation", [1, 0, 0]), M, "camera.rotation", ["4 finite numbers"]),
    ("rot_norm", _set("M.camera.rotation", [0.5, 0, 0, 0]), M, "camera.rotation", ["not a unit quaternion"]),
    ("eye_offset", _set("M.eye_offset_mm", [0, -60]), M, "eye_offset_mm", ["3 finite numbers"]),
    ("eye_offset_type", _set("M.eye_offset_mm", [0, "a", 1]), M, "eye_offset_mm", ["3 finite numbers"]),
]


@pytest.mark.parametrize("mutation,file,key,words", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_each_problem_is_one_error(tmp_path, mutation, file, key, words):
    root = make_session(tmp_path)
    sdoc, mdoc = tomllib.loads(SESSION_TOML), tomllib.loads(MARKERSET_TOML)
    mutation(sdoc, mdoc, root)
    (root / "session.toml").write_text(dump_toml(sdoc), encoding="utf-8")
    (root / "markerset.toml").write_text(dump_toml(mdoc), encoding="utf-8")
    errors = validate_session(root)
    assert len(errors) == 1, [str(e) for e in errors]
    err = errors[0]
    assert isinstance(err, ConfigError) and err.exit_code == 2
    assert err.key == key
    text = str(err)
    fpath = root.resolve() / file
    assert "\n" not in text
    assert text.startswith(f"{fpath}: ") or text.startswith(f"take {err.take}: {fpath}: "), text
    for w in words:
        assert w.lower() in text.lower(), text
    if key.startswith("takes[") and "." in key and not key.endswith(".id"):
        take_id = sdoc["takes"][int(key[6:key.index("]")])]["id"]
        assert err.take == take_id and text.startswith(f"take {take_id}: ")
    with pytest.raises(ConfigError) as info:
        load_session(root)
    assert str(info.value) == text


def test_second_neutral_take(tmp_path):
    doc = tomllib.loads(SESSION_TOML)
    doc["takes"].append({"id": "neutral2", "kind": "neutral", "mocap": "mocap/neutral.c3d"})
    root = make_session(tmp_path, dump_toml(doc))
    (err,) = validate_session(root)
    assert err.key == "takes[4].kind" and "second neutral take" in str(err) and "takes[3]" in str(err)


def test_syntax_error_names_line(tmp_path):
    root = make_session(tmp_path, SESSION_TOML.replace('subject = "p01"', "subject = p01"))
    (err,) = validate_session(root)
    assert str(err).startswith(str(root.resolve() / "session.toml")) and "TOML syntax error" in str(err)
    assert "line 4" in str(err)


@pytest.mark.parametrize("content,words", [(b"\xff\xfe\x00garbage", "not UTF-8"), (b"[[takes]\n", "line 1")])
def test_not_toml(tmp_path, content, words):
    root = make_session(tmp_path)
    (root / "session.toml").write_bytes(content)
    (err,) = validate_session(root)
    assert words in str(err) and err.key is None


def test_missing_files(tmp_path):
    (err,) = validate_session(tmp_path)
    assert "file not found" in str(err) and str(tmp_path) in str(err)
    (err,) = validate_markerset(tmp_path)
    assert "is a directory" in str(err)


def test_all_problems_are_collected(tmp_path):
    doc = tomllib.loads(SESSION_TOML)
    doc["takes"][0]["split"] = "nope"
    doc["takes"][2]["rate_hz"] = -1
    mdoc = tomllib.loads(MARKERSET_TOML)
    mdoc["up_axis"] = "q"
    root = make_session(tmp_path, dump_toml(doc), dump_toml(mdoc))
    keys = [e.key for e in validate_session(root)]
    assert keys == ["takes[0].split", "takes[2].rate_hz", "up_axis"]


def test_unusual_key_names_stay_on_one_line(tmp_path):
    doc = tomllib.loads(SESSION_TOML)
    doc["takes"][0]["a\nb"] = 1
    root = make_session(tmp_path, dump_toml(doc))
    (err,) = validate_session(root)
    assert "\n" not in str(err) and err.key == 'takes[0]."a\\nb"'


# ------------------------------------------------------------------------------------------------- capture labels

def _markerset(tmp_path) -> object:
    p = tmp_path / "markerset.toml"
    p.write_text(MARKERSET_TOML)
    return load_markerset(p)


def test_capture_labels_exact_and_prefixed(tmp_path):
    ms = _markerset(tmp_path)
    names = list(ms.all_markers)
    labels = ["junk", *reversed(names)]
    got = check_capture_labels(ms, labels, "a.c3d", "t")
    assert got == {n: labels.index(n) for n in names}
    vicon = [f"p01:{n}" for n in names[:-3]] + [f"Pole:{n}" for n in names[-3:]]
    assert check_capture_labels(ms, vicon, "a.c3d", "t") == {n: i for i, n in enumerate(names)}
    # an exact label wins over a prefixed one
    mixed = [f"p01:{names[0]}", *names]
    assert check_capture_labels(ms, mixed, "a.c3d", "t")[names[0]] == 1


def test_capture_labels_missing(tmp_path):
    ms = _markerset(tmp_path)
    names = list(ms.all_markers)
    with pytest.raises(InputError) as info:
        check_capture_labels(ms, names[7:], "/data/a.c3d", "t1")
    msg = str(info.value)
    assert msg.startswith("take t1: /data/a.c3d: ") and "\n" not in msg
    assert ", ".join(names[:5]) + " and 2 more" in msg and names[5] not in msg
    # only the required ones matter
    got = check_capture_labels(ms, names[1:], "a.c3d", "t", required=names[1:])
    assert names[0] not in got and len(got) == len(names) - 1


def test_capture_labels_ambiguous_prefix(tmp_path):
    ms = _markerset(tmp_path)
    labels = [*ms.all_markers[1:], "a:SACR", "b:SACR"]
    with pytest.raises(InputError, match="ambiguous"):
        check_capture_labels(ms, labels, "a.c3d", "t")


# ----------------------------------------------------------------------------------------------------------- fuzzing

@pytest.fixture(scope="module")
def fuzz_root(tmp_path_factory) -> Path:
    return make_session(tmp_path_factory.mktemp("fuzz"))


def _check_outcome(root: Path) -> None:
    """Either a valid session or one-line ConfigErrors naming session.toml or markerset.toml; nothing else."""
    errors = validate_session(root)
    files = (str(root.resolve() / "session.toml"), str(root.resolve() / "markerset.toml"))
    for e in errors:
        assert isinstance(e, ConfigError)
        text = str(e)
        assert "\n" not in text and "\r" not in text
        assert any(text.startswith(f) or f"take {e.take}: {f}" in text for f in files), text
    if errors:
        with pytest.raises(ConfigError) as info:
            load_session(root)
        assert str(info.value) == str(errors[0])
    else:
        s = load_session(root)
        for t in s.takes:
            assert all(Path(f).is_relative_to(s.root) for f in t.files)


_FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture],
                 derandomize=True)


@_FUZZ
@given(st.binary(max_size=300))
def test_fuzz_random_bytes(fuzz_root, data):
    (fuzz_root / "session.toml").write_bytes(data)
    _check_outcome(fuzz_root)


@_FUZZ
@given(st.sampled_from(["session", "markerset"]), st.integers(0, 10_000))
def test_fuzz_truncated(fuzz_root, which, cut):
    (fuzz_root / "session.toml").write_text(SESSION_TOML)
    text = SESSION_TOML if which == "session" else MARKERSET_TOML
    (fuzz_root / f"{which}.toml").write_text(text[: cut % (len(text) + 1)])
    try:
        _check_outcome(fuzz_root)
    finally:
        (fuzz_root / "markerset.toml").write_text(MARKERSET_TOML)


_names = st.sampled_from(["id", "kind", "pose", "mocap", "video", "target", "yaw_deg", "segments", "parent",
                          "markers", "pelvis", "head", "rotation", "root", "x", "", "a b", "\n", "é"])
_scalars = (st.booleans() | st.integers(-(10**20), 10**20) | st.floats() | st.text(max_size=8)
            | st.sampled_from(["gaze_shift", "face", "neutral", "../x", "/etc/passwd", "mocap/neutral.c3d",
                               "pelvis", "head", "y", "z", "mm", "train", "SACR", "HTOP", ".", "mocap"]))
_values = st.recursive(_scalars, lambda ch: st.lists(ch, max_size=4) | st.dictionaries(_names, ch, max_size=3),
                       max_leaves=8)


def _paths(doc, prefix=()):
    """Every (container, key) location in a parsed TOML document."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc)
    for k, v in list(items):
        yield doc, k
        if isinstance(v, dict | list):
            yield from _paths(v, (*prefix, k))


def _containers(doc):
    yield doc
    for c, k in _paths(doc):
        if isinstance(c[k], dict | list):
            yield c[k]


@st.composite
def _mutated(draw, text):
    doc = copy.deepcopy(tomllib.loads(text))
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["delete", "replace", "insert"]))
        if op == "insert":
            c = draw(st.sampled_from(list(_containers(doc))))
            if isinstance(c, dict):
                c[draw(_names)] = draw(_values)
            else:
                c.insert(draw(st.integers(0, len(c))), draw(_values))
            continue
        locs = list(_paths(doc))
        if not locs:
            continue
        c, k = draw(st.sampled_from(locs))
        if op == "delete":
            del c[k]
        else:
            c[k] = draw(_values)
    return dump_toml(doc)


@_FUZZ
@given(_mutated(SESSION_TOML))
def test_fuzz_session_mutations(fuzz_root, text):
    (fuzz_root / "session.toml").write_text(text, encoding="utf-8")
    _check_outcome(fuzz_root)


@_FUZZ
@given(_mutated(MARKERSET_TOML))
def test_fuzz_markerset_mutations(fuzz_root, text):
    (fuzz_root / "session.toml").write_text(SESSION_TOML)
    (fuzz_root / "markerset.toml").write_text(text, encoding="utf-8")
    try:
        _check_outcome(fuzz_root)
        errors = validate_markerset(fuzz_root / "markerset.toml")
        assert all(str(e).startswith(str(fuzz_root / "markerset.toml")) for e in errors)
    finally:
        (fuzz_root / "markerset.toml").write_text(MARKERSET_TOML)


@pytest.mark.parametrize("i,k", [(0, "mocap"), (0, "video"), (0, "eyes"), (2, "tracked"), (2, "clean")])
def test_a_missing_take_file_is_not_a_session_error(tmp_path, i, k):
    """A take's file that is missing is that take's failure when the run plans it, not the session's
    (tests/test_missing_files.py): the session still validates."""
    root = make_session(tmp_path)
    sdoc = tomllib.loads(SESSION_TOML)
    _set(f"S.takes.{i}.{k}", f"{k}/nope" + (".c3d" if k == "mocap" else ".bin"))(sdoc, tomllib.loads(MARKERSET_TOML),
                                                                                root)
    (root / "session.toml").write_text(dump_toml(sdoc), encoding="utf-8")
    assert validate_session(root) == []
