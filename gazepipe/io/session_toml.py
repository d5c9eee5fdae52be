"""Read and validate a session's ``session.toml`` and its ``markerset.toml`` (SPEC §1).

Every problem is a :class:`~gazepipe.errors.ConfigError` naming the file, the key (TOML dotted form, array
entries 0-based: ``takes[3].kind``, ``segments.head.markers[1]``) and what is wrong, on one line.
:func:`validate_session` and :func:`validate_markerset` return every problem found; :func:`load_session` and
:func:`load_markerset` raise the first one.

Choices where SPEC §1 is silent:

- ``schema`` missing means 1; any other value than the integer 1 is an error.
- ``[session] subject`` is required (it names the output partition ``subject=<s>``); ``id`` defaults to the
  folder's name. Both, take ids and poses must be letters, digits, ``_`` and ``-``.
- ``pose`` is required for ``gaze_follow`` and ``gaze_shift`` takes (from the take or ``[defaults]``); ``face``
  and ``neutral`` takes without one get ``"unspecified"``.
- Unknown keys are errors everywhere (with the closest known key suggested); a known take key that does not
  belong to the take's kind (``target`` on a ``face`` take) is an error too.
- ``markerset`` is required when any take has mocap; ``target`` is required when there is a ``gaze_follow``
  take; a two-marker ``clapper`` is required when a take has ``video``.
- In markerset.toml, segments are listed from the root to the head: a segment's parent must come before it, so
  the first segment is the root and is the only one without a parent.
- ``rate_hz`` and ``timecode_fps`` are snapped with :func:`gazepipe.timebase.snap_rate`.
"""

from __future__ import annotations

import difflib
import json
import math
import re
import tomllib
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from gazepipe.errors import ConfigError, InputError
from gazepipe.model import SPLITS, TAKE_KINDS, MarkerSet, Segment, Session, Take
from gazepipe.timebase import snap_rate, unit_scale_to_mm

__all__ = ["load_session", "validate_session", "load_markerset", "validate_markerset", "check_capture_labels"]

_WORD = re.compile(r"[A-Za-z0-9_-]+")
_CTRL = re.compile(r"[\x00-\x1f\x7f]")
UNSPECIFIED_POSE = "unspecified"
MOCAP_SUFFIXES = (".c3d", ".csv", ".tsv")

_SESSION_TOP = ("schema", "session", "defaults", "takes")
_SESSION_KEYS = ("id", "subject", "markerset")
_DEFAULT_KEYS = ("pose", "split", "rate_hz", "timecode_fps")
_FILE_KEYS = ("mocap", "video", "eyes", "tracked", "clean")
#: the keys each kind of take accepts, beyond id, kind, pose and split
_KIND_KEYS: dict[str, tuple[str, ...]] = {
    "gaze_follow": ("mocap", "video", "eyes", "rate_hz"),
    "gaze_shift": ("mocap", "video", "eyes", "rate_hz", "target"),
    "neutral": ("mocap", "rate_hz"),
    "face": ("tracked", "clean", "rate_hz", "timecode_fps"),
}
_KIND_REQUIRED: dict[str, tuple[str, ...]] = {
    "gaze_follow": ("mocap",), "gaze_shift": ("mocap", "target"), "neutral": ("mocap",),
    "face": ("tracked", "clean", "rate_hz"),
}
_TAKE_KEYS = ("id", "kind", "pose", "split", *dict.fromkeys(k for ks in _KIND_KEYS.values() for k in ks))
_MARKERSET_TOP = ("schema", "up_axis", "units", "root", "target", "clapper", "head_centre", "eye_offset_mm",
                  "segments", "lod", "camera")


# ----------------------------------------------------------------------------------------------------------- helpers

def _k(name: Any) -> str:
    """A TOML key as it would be written: bare when possible, else quoted (always one line)."""
    s = str(name)
    return s if _WORD.fullmatch(s) else json.dumps(s)


def _show(value: Any) -> str:
    """Short one-line rendering of a value for messages."""
    r = repr(value)
    return r if len(r) <= 40 else r[:37] + "..."


def _type_name(value: Any) -> str:
    return {bool: "boolean", int: "integer", float: "number", str: "string", list: "array",
            dict: "table"}.get(type(value), type(value).__name__)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _suggest(key: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class _Collector:
    """Gathers the problems of one file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.errors: list[ConfigError] = []
        self.take: str | None = None  # the take id problems are attributed to, while reading a take

    def add(self, key: str | None, problem: str, take: str | None = None) -> None:
        self.errors.append(ConfigError(self.path, problem, key=key, take=take or self.take))

    def unknown_keys(self, table: dict, known: Sequence[str], prefix: str, what: str = "key") -> None:
        for name in table:
            if name not in known:
                self.add(f"{prefix}{_k(name)}", f"unknown {what} {name!r}{_suggest(str(name), known)}")

    def table(self, value: Any, key: str) -> dict | None:
        if isinstance(value, dict):
            return value
        self.add(key, f"must be a table, got {_type_name(value)}")
        return None

    def string(self, table: dict, name: str, key: str, *, required: bool = False) -> str | None:
        if name not in table:
            if required:
                self.add(key, "missing (a string is required)")
            return None
        value = table[name]
        if not isinstance(value, str):
            self.add(key, f"must be a string, got {_type_name(value)} {_show(value)}")
            return None
        return value

    def word(self, table: dict, name: str, key: str, what: str, *, required: bool = False) -> str | None:
        value = self.string(table, name, key, required=required)
        if value is not None and not _WORD.fullmatch(value):
            self.add(key, f"bad {what} {_show(value)}: use only letters, digits, '_' and '-'")
            return None
        return value

    def number(self, table: dict, name: str, key: str, *, positive: bool = False) -> float | None:
        if name not in table:
            return None
        value = table[name]
        if not _is_number(value):
            self.add(key, f"must be a finite number, got {_type_name(value)} {_show(value)}")
            return None
        if positive and value <= 0:
            self.add(key, f"must be > 0, got {_show(value)}")
            return None
        return float(value)

    def marker_name(self, value: Any, key: str) -> str | None:
        if not isinstance(value, str):
            self.add(key, f"must be a marker name (string), got {_type_name(value)} {_show(value)}")
            return None
        if not value or value != value.strip() or _CTRL.search(value):
            self.add(key, f"bad marker name {_show(value)}: empty, padded or with control characters")
            return None
        return value

    def schema(self, doc: dict) -> None:
        if "schema" in doc and (type(doc["schema"]) is not int or doc["schema"] != 1):
            self.add("schema", f"unsupported schema {_show(doc['schema'])} (this version reads schema = 1)")


def _read_toml(path: Path, col: _Collector) -> dict | None:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        col.add(None, "file not found")
        return None
    except IsADirectoryError:
        col.add(None, "is a directory, not a TOML file")
        return None
    except OSError as exc:
        col.add(None, f"cannot read: {exc.strerror or exc}")
        return None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        col.add(None, f"not TOML: not UTF-8 text (byte {exc.start})")
        return None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        col.add(None, f"TOML syntax error: {exc}")
        return None


def _resolve_inside(root: Path, value: str, key: str, col: _Collector, take: str | None = None,
                    must_exist: bool = True) -> str | None:
    """Absolute path of ``value`` (relative to ``root``), or ``None`` after reporting why it is unusable."""
    if not value or _CTRL.search(value):
        col.add(key, f"bad path {_show(value)}: empty or with control characters", take)
        return None
    try:
        p = (root / value).resolve()
        inside = p == root or p.is_relative_to(root)
        if not inside:
            col.add(key, f"path {_show(value)} escapes the session folder {root}", take)
            return None
        if must_exist and not p.is_file():
            col.add(key, f"{'not a file' if p.exists() else 'file not found'}: {p}", take)
            return None
    except (OSError, RuntimeError, ValueError) as exc:
        col.add(key, f"bad path {_show(value)}: {exc}", take)
        return None
    return str(p)


# --------------------------------------------------------------------------------------------------------- markerset

def validate_markerset(path: str | Path) -> list[ConfigError]:
    """Every problem in a markerset.toml (empty when it is valid)."""
    return _parse_markerset(Path(path).absolute())[1]


def load_markerset(path: str | Path) -> MarkerSet:
    """Read and validate ``markerset.toml``; raises the first :class:`ConfigError` found."""
    ms, errors = _parse_markerset(Path(path).absolute())
    if errors:
        raise errors[0]
    assert ms is not None
    return ms


def _parse_markerset(path: Path) -> tuple[MarkerSet | None, list[ConfigError]]:
    col = _Collector(path)
    doc = _read_toml(path, col)
    if doc is None:
        return None, col.errors
    col.schema(doc)
    col.unknown_keys(doc, _MARKERSET_TOP, "")

    up_axis = col.string(doc, "up_axis", "up_axis", required=True)
    if up_axis is not None and up_axis.strip().lower() not in ("y", "z"):
        col.add("up_axis", f"must be \"y\" or \"z\", got {_show(up_axis)}")
        up_axis = None
    units = col.string(doc, "units", "units") or "mm"
    try:
        unit_scale_to_mm(units)
    except KeyError:
        col.add("units", f"unknown units {_show(units)} (expected mm, cm, m, dm or in)")
    root = col.marker_name(doc["root"], "root") if "root" in doc else None
    if "root" not in doc:
        col.add("root", "missing (the marker at the base of the spine)")
    target = col.marker_name(doc["target"], "target") if "target" in doc else None
    head_centre = col.marker_name(doc["head_centre"], "head_centre") if "head_centre" in doc else None

    clapper: tuple[str, ...] = ()
    if "clapper" in doc:
        value = doc["clapper"]
        if not isinstance(value, list) or len(value) != 2:
            col.add("clapper", f"must be an array of two marker names, got {_show(value)}")
        else:
            names = [col.marker_name(v, f"clapper[{i}]") for i, v in enumerate(value)]
            if None not in names:
                if names[0] == names[1]:
                    col.add("clapper", f"the two clapper markers are the same ({names[0]!r})")
                else:
                    clapper = tuple(names)  # type: ignore[arg-type]

    eye_offset = _vector(doc, "eye_offset_mm", 3, col)
    segments = _segments(doc, col)
    seg_names = [s.name for s in segments]

    # the target and the clapper are not on the subject: they must not share a name with its markers
    seen: dict[str, str] = {}
    for s in segments:
        for m in s.markers:
            seen.setdefault(m, f"on segment {s.name!r}")
    if root is not None:
        seen.setdefault(root, "the root marker")
    if head_centre is not None:
        seen.setdefault(head_centre, "the head centre")
    for name, key in ((target, "target"), *((c, f"clapper[{i}]") for i, c in enumerate(clapper))):
        if name is not None and name in seen:
            col.add(key, f"marker {name!r} is also {seen[name]}")
    if target is not None and target in clapper:
        col.add("target", f"marker {target!r} is also a clapper marker")

    lod: tuple[str, ...] = ()
    if "lod" in doc and (table := col.table(doc["lod"], "lod")) is not None:
        col.unknown_keys(table, ("segments",), "lod.")
        value = table.get("segments", [])
        if not isinstance(value, list):
            col.add("lod.segments", f"must be an array of segment names, got {_type_name(value)}")
        else:
            names = []
            for i, v in enumerate(value):
                if not isinstance(v, str) or v not in seg_names:
                    col.add(f"lod.segments[{i}]", f"{_show(v)} is not a segment{_suggest(str(v), seg_names)}")
                elif v in names:
                    col.add(f"lod.segments[{i}]", f"segment {v!r} listed twice")
                else:
                    names.append(v)
            lod = tuple(names)

    rotation = None
    if "camera" in doc and (table := col.table(doc["camera"], "camera")) is not None:
        col.unknown_keys(table, ("rotation",), "camera.")
        q = _vector(table, "rotation", 4, col, prefix="camera.")
        if q is not None:
            norm = math.sqrt(sum(c * c for c in q))
            if abs(norm - 1.0) > 1e-3:
                col.add("camera.rotation", f"not a unit quaternion (w, x, y, z): norm {norm:.6g}")
            else:
                rotation = tuple(c / norm for c in q)

    if col.errors:
        return None, col.errors
    assert up_axis is not None and root is not None
    return MarkerSet(path=str(path), up_axis=up_axis.strip().lower(), units=units.strip().lower(), root=root,
                     target=target, clapper=clapper, segments=tuple(segments), head_centre=head_centre,
                     eye_offset_mm=eye_offset, lod_segments=lod, camera_rotation=rotation), []  # type: ignore[arg-type]


def _vector(table: dict, name: str, n: int, col: _Collector, prefix: str = "") -> tuple[float, ...] | None:
    if name not in table:
        return None
    value = table[name]
    if not isinstance(value, list) or len(value) != n or not all(_is_number(v) for v in value):
        col.add(f"{prefix}{name}", f"must be an array of {n} finite numbers, got {_show(value)}")
        return None
    return tuple(float(v) for v in value)


def _segments(doc: dict, col: _Collector) -> list[Segment]:
    """The ``[segments.*]`` tables in file order; reports every structural problem."""
    if "segments" not in doc:
        col.add("segments", "missing (at least the root segment is required)")
        return []
    table = col.table(doc["segments"], "segments")
    if table is None:
        return []
    if not table:
        col.add("segments", "no segments defined")
        return []
    order = list(table)
    parents: dict[str, Any] = {}
    segments: list[Segment] = []
    owner: dict[str, str] = {}
    bad_parent: set[str] = set()
    for name in order:
        key = f"segments.{_k(name)}"
        seg = col.table(table[name], key)
        if seg is None:
            continue
        col.unknown_keys(seg, ("markers", "parent"), f"{key}.")
        markers: list[str] = []
        value = seg.get("markers")
        if value is None:
            col.add(f"{key}.markers", "missing (three or more marker names)")
        elif not isinstance(value, list):
            col.add(f"{key}.markers", f"must be an array of marker names, got {_type_name(value)}")
        else:
            for i, v in enumerate(value):
                m = col.marker_name(v, f"{key}.markers[{i}]")
                if m is None:
                    continue
                if m in markers:
                    col.add(f"{key}.markers[{i}]", f"marker {m!r} listed twice")
                elif m in owner:
                    col.add(f"{key}.markers[{i}]", f"marker {m!r} is already on segment {owner[m]!r}")
                else:
                    markers.append(m)
                    owner[m] = name
            if len(value) < 3:
                col.add(f"{key}.markers", f"a segment needs at least 3 markers, got {len(value)}")
        parent = seg.get("parent")
        if parent is not None and not isinstance(parent, str):
            col.add(f"{key}.parent", f"must be a segment name (string), got {_type_name(parent)}")
            bad_parent.add(name)
            parent = None
        parents[name] = parent
        segments.append(Segment(name=str(name), markers=tuple(markers), parent=parent))

    roots = [n for n in parents if parents[n] is None and n not in bad_parent]
    for extra in roots[1:]:
        col.add(f"segments.{_k(extra)}.parent",
                f"missing: only one segment may lack a parent (the root is {roots[0]!r})")
    reported_cycle: set[str] = set()
    for idx, name in enumerate(order):
        parent = parents.get(name)
        if parent is None or name not in parents:
            continue
        key = f"segments.{_k(name)}.parent"
        if parent not in table:
            col.add(key, f"unknown parent {parent!r}{_suggest(parent, order)}")
            continue
        # walk up the chain: a cycle returns to this segment
        chain, cur = [name], parent
        while cur is not None and cur not in chain and cur in parents:
            chain.append(cur)
            cur = parents[cur]
        if cur == name:
            if name not in reported_cycle:
                col.add(key, "parent cycle: " + " -> ".join([*chain, name]))
                reported_cycle.update(chain)
        elif cur is None and order.index(parent) > idx:
            col.add(key, f"parent {parent!r} comes after {name!r}: list segments from the root to the head")
    return segments


# ----------------------------------------------------------------------------------------------------------- session

def validate_session(path: str | Path) -> list[ConfigError]:
    """Every problem in a session (session.toml and its markerset.toml); empty when it is valid."""
    return _parse_session(path)[1]


def load_session(path: str | Path) -> Session:
    """Read and validate a session.

    Parameters
    ----------
    path : the session folder or its ``session.toml``.

    Returns a :class:`~gazepipe.model.Session` whose paths are all absolute and inside the session folder.
    Raises the first :class:`ConfigError` found (see :func:`validate_session` for all of them).
    """
    session, errors = _parse_session(path)
    if errors:
        raise errors[0]
    assert session is not None
    return session


def _parse_session(path: str | Path) -> tuple[Session | None, list[ConfigError]]:
    p = Path(path).absolute()
    toml_path = p / "session.toml" if p.is_dir() else p
    try:
        root = toml_path.parent.resolve()
    except (OSError, RuntimeError) as exc:
        return None, [ConfigError(toml_path, f"cannot resolve the session folder: {exc}")]
    col = _Collector(toml_path)
    doc = _read_toml(toml_path, col)
    if doc is None:
        return None, col.errors
    col.schema(doc)
    col.unknown_keys(doc, _SESSION_TOP, "")

    sess = col.table(doc.get("session", {}), "session") or {}
    col.unknown_keys(sess, _SESSION_KEYS, "session.")
    if "id" in sess:
        sid = col.word(sess, "id", "session.id", "session id")
    else:
        sid = root.name
        if not _WORD.fullmatch(sid):
            col.add("session.id", f"missing, and the folder name {_show(sid)} is not a valid id: set it")
            sid = None
    subject = col.word(sess, "subject", "session.subject", "subject", required=True)
    ms_rel = col.string(sess, "markerset", "session.markerset")
    ms_path = _resolve_inside(root, ms_rel, "session.markerset", col) if ms_rel is not None else None

    defaults = col.table(doc.get("defaults", {}), "defaults") or {}
    col.unknown_keys(defaults, _DEFAULT_KEYS, "defaults.")
    d_pose = col.word(defaults, "pose", "defaults.pose", "pose")
    d_split = _split(defaults, "defaults.split", col)
    d_rate = col.number(defaults, "rate_hz", "defaults.rate_hz", positive=True)
    d_tc = col.number(defaults, "timecode_fps", "defaults.timecode_fps", positive=True)

    takes: list[Take] = []
    raw_takes = doc.get("takes")
    if raw_takes is None or raw_takes == []:
        col.add("takes", "no [[takes]] in the session")
        raw_takes = []
    elif not isinstance(raw_takes, list):
        col.add("takes", f"must be an array of tables ([[takes]]), got {_type_name(raw_takes)}")
        raw_takes = []
    ids: dict[str, int] = {}
    neutral_at: int | None = None
    for i, raw in enumerate(raw_takes):
        take = _take(raw, i, root, col, ids, d_pose, d_split, d_rate, d_tc)
        if take is None:
            continue
        if take.kind == "neutral":
            if neutral_at is not None:
                col.add(f"takes[{i}].kind", f"a second neutral take (the first is takes[{neutral_at}])", take.id)
            neutral_at = i
        takes.append(take)

    ms: MarkerSet | None = None
    needs_ms = any(isinstance(t, dict) and t.get("kind") in ("gaze_follow", "gaze_shift", "neutral")
                   for t in raw_takes)
    if ms_path is not None:
        ms, ms_errors = _parse_markerset(Path(ms_path))
        col.errors.extend(ms_errors)
        if ms is not None:
            if ms.target is None and any(t.kind == "gaze_follow" for t in takes):
                col.errors.append(ConfigError(ms_path, "missing (gaze_follow takes need the target marker)",
                                              key="target"))
            if not ms.clapper and any(t.video for t in takes):
                col.errors.append(ConfigError(ms_path, "missing (takes with video need the two clapper markers)",
                                              key="clapper"))
    elif ms_rel is None and needs_ms:
        col.add("session.markerset", "missing (takes with mocap need a markerset.toml)")

    if col.errors:
        return None, col.errors
    assert sid is not None and subject is not None
    return Session(root=str(root), path=str(toml_path), id=sid, subject=subject, markerset=ms,
                   takes=tuple(takes)), []


def _split(table: dict, key: str, col: _Collector, take: str | None = None) -> str | None:
    value = table.get(key.rsplit(".", 1)[-1])
    if value is None:
        return None
    if value not in SPLITS:
        col.add(key, f"bad split {_show(value)} (expected {', '.join(SPLITS)})", take)
        return None
    return value


def _take(raw: Any, i: int, root: Path, col: _Collector, ids: dict[str, int], d_pose: str | None,
          d_split: str | None, d_rate: float | None, d_tc: float | None) -> Take | None:
    """One ``[[takes]]`` entry, or ``None`` after reporting its problems."""
    key = f"takes[{i}]"
    t = col.table(raw, key)
    if t is None:
        return None
    n_before = len(col.errors)
    tid = col.word(t, "id", f"{key}.id", "take id", required=True)
    col.take = tid
    try:
        return _take_fields(t, i, tid, root, col, ids, n_before, d_pose, d_split, d_rate, d_tc)
    finally:
        col.take = None


def _take_fields(t: dict, i: int, tid: str | None, root: Path, col: _Collector, ids: dict[str, int],
                 n_before: int, d_pose: str | None, d_split: str | None, d_rate: float | None,
                 d_tc: float | None) -> Take | None:
    key = f"takes[{i}]"
    if tid is not None:
        if tid in ids:
            col.add(f"{key}.id", f"duplicate take id {tid!r} (also takes[{ids[tid]}])", tid)
        else:
            ids[tid] = i
    kind = col.string(t, "kind", f"{key}.kind", required=True)
    if kind is not None and kind not in TAKE_KINDS:
        col.add(f"{key}.kind", f"unknown take kind {_show(kind)}{_suggest(kind, TAKE_KINDS)}"
                f" (expected {', '.join(TAKE_KINDS)})", tid)
        kind = None
    for name in t:
        if name not in _TAKE_KEYS:
            col.add(f"{key}.{_k(name)}", f"unknown key {name!r}{_suggest(str(name), _TAKE_KEYS)}", tid)
        elif kind is not None and name not in ("id", "kind", "pose", "split") and name not in _KIND_KEYS[kind]:
            col.add(f"{key}.{name}", f"{name!r} does not apply to {kind} takes", tid)
    if kind is not None:
        for name in _KIND_REQUIRED[kind]:
            if name not in t and not (name == "rate_hz" and d_rate is not None):
                col.add(f"{key}.{name}", f"missing: {kind} takes need {name!r}", tid)

    pose = col.word(t, "pose", f"{key}.pose", "pose") if "pose" in t else d_pose
    if pose is None and kind in ("gaze_follow", "gaze_shift") and "pose" not in t:
        col.add(f"{key}.pose", "missing (set it on the take or in [defaults])", tid)
    split = _split(t, f"{key}.split", col, tid) if "split" in t else d_split

    files: dict[str, str | None] = {}
    for name in _FILE_KEYS:
        if name in t and (kind is None or name in _KIND_KEYS[kind]):
            value = col.string(t, name, f"{key}.{name}")
            files[name] = None if value is None else _resolve_inside(root, value, f"{key}.{name}", col, tid)
    mocap = files.get("mocap")
    if mocap is not None and Path(mocap).suffix.lower() not in MOCAP_SUFFIXES:
        col.add(f"{key}.mocap", f"unsupported mocap file type {_show(Path(mocap).suffix)} "
                f"(expected {', '.join(MOCAP_SUFFIXES)})", tid)

    rate = col.number(t, "rate_hz", f"{key}.rate_hz", positive=True) if "rate_hz" in t else d_rate
    tc = col.number(t, "timecode_fps", f"{key}.timecode_fps", positive=True) if "timecode_fps" in t else d_tc

    yaw = pitch = None
    if "target" in t and kind == "gaze_shift" and (tgt := col.table(t["target"], f"{key}.target")) is not None:
        col.unknown_keys(tgt, ("yaw_deg", "pitch_deg"), f"{key}.target.")
        for name in ("yaw_deg", "pitch_deg"):
            if name not in tgt:
                col.add(f"{key}.target.{name}", "missing (a number of degrees)", tid)
        yaw = col.number(tgt, "yaw_deg", f"{key}.target.yaw_deg")
        pitch = col.number(tgt, "pitch_deg", f"{key}.target.pitch_deg")
        if yaw is not None and abs(yaw) > 180:
            col.add(f"{key}.target.yaw_deg", f"out of range [-180, 180]: {_show(yaw)}", tid)
        if pitch is not None and abs(pitch) > 90:
            col.add(f"{key}.target.pitch_deg", f"out of range [-90, 90]: {_show(pitch)}", tid)

    if len(col.errors) > n_before:
        return None
    assert tid is not None and kind is not None
    return Take(id=tid, kind=kind, pose=pose or UNSPECIFIED_POSE, mocap=mocap, video=files.get("video"),
                eyes=files.get("eyes"), tracked=files.get("tracked"), clean=files.get("clean"), split=split,
                target_yaw_deg=yaw, target_pitch_deg=pitch,
                rate_hz=None if rate is None else snap_rate(rate),
                timecode_fps=60.0 if tc is None else snap_rate(tc))


# -------------------------------------------------------------------------------------------------- capture labels

def check_capture_labels(markerset: MarkerSet, labels: Sequence[str], path: str | Path, take_id: str | None,
                         required: Iterable[str] | None = None) -> dict[str, int]:
    """Map markerset names onto a capture's columns.

    Parameters
    ----------
    markerset : the session's markerset.
    labels : the capture's marker labels, in column order.
    path : the capture file (for the error message).
    take_id : the take (for the error message).
    required : the names that must be present (default: every marker of the markerset).

    Returns ``{markerset name: column index in labels}`` for every present markerset marker. A label equal to the
    name wins; otherwise Vicon's ``Subject:Marker`` matches ``Marker`` when the markerset's name has no prefix.
    Raises :class:`InputError` naming the missing markers (at most five, then "and N more"), or when a name
    matches two prefixed labels.
    """
    exact = {lab: j for j, lab in reversed(list(enumerate(labels)))}
    stripped: dict[str, list[int]] = {}
    for j, lab in enumerate(labels):
        if ":" in lab:
            stripped.setdefault(lab.rsplit(":", 1)[1], []).append(j)
    mapping: dict[str, int] = {}
    for name in markerset.all_markers:
        if name in exact:
            mapping[name] = exact[name]
        elif ":" not in name and name in stripped:
            cols = stripped[name]
            if len(cols) > 1:
                raise InputError(path, f"marker {name!r} is ambiguous: labels "
                                 + ", ".join(repr(labels[j]) for j in cols[:5]), take=take_id)
            mapping[name] = cols[0]
    need = markerset.all_markers if required is None else tuple(required)
    missing = [n for n in need if n not in mapping]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise InputError(path, f"markers of the markerset missing from the capture: {shown}", take=take_id)
    return mapping
