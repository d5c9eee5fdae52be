"""Read and validate a session's ``session.toml`` and its ``markerset.toml`` (SPEC §1; the markerset's own
rules are in :mod:`gazepipe.io.markerset_toml`).

Every problem is a :class:`~gazepipe.errors.ConfigError` naming the file, the key (TOML dotted form, array
entries 0-based: ``takes[3].kind``, ``segments.head.markers[1]``) and what is wrong, on one line, ending with the
section of ``docs/session-format.md`` that explains the key (every key of both files is documented there).
:func:`validate_session` and :func:`validate_markerset` return every problem found; :func:`load_session` and
:func:`load_markerset` raise the first one.

Choices where SPEC §1 is silent:

- ``schema`` missing means 1; any other value than the integer 1 is an error.
- ``[session] subject`` is required (it names the output partition ``subject=<s>``); ``id`` defaults to the
  folder's name. Both, take ids and poses must be letters, digits, ``_`` and ``-``, at most 100 characters
  (they name output folders and files: a longer name would fail every write).
- ``pose`` is required for ``gaze_follow`` and ``gaze_shift`` takes (from the take or ``[defaults]``); ``face``
  and ``neutral`` takes without one get ``"unspecified"``.
- Unknown keys are errors everywhere (with the closest known key suggested); a known take key that does not
  belong to the take's kind (``target`` on a ``face`` take) is an error too.
- ``markerset`` is required when any take has mocap; ``target`` is required when there is a ``gaze_follow``
  take; a two-marker ``clapper`` is required when a take has ``video``.
- In markerset.toml, segments are listed from the root to the head: a segment's parent must come before it, so
  the first segment is the root and is the only one without a parent.
- ``rate_hz`` and ``timecode_fps`` are taken as written (:func:`gazepipe.timebase.stated_rate`: an NTSC rate written
  rounded, such as 29.97, is exactly N·1000/1001 Hz; 69.9 stays 69.9 Hz).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from gazepipe.errors import ConfigError, InputError
from gazepipe.io.limits import MAX_ID_CHARS
from gazepipe.io.markerset_toml import _parse_markerset, load_markerset, validate_markerset
from gazepipe.io.toml_common import (
    WORD,
    Collector,
    doc_error,
    key_name,
    read_document,
    resolve_inside,
    show,
    suggest,
    too_long,
    type_name,
)
from gazepipe.model import SPLITS, TAKE_KINDS, MarkerSet, Session, Take
from gazepipe.timebase import stated_rate

__all__ = ["load_session", "validate_session", "load_markerset", "validate_markerset", "check_capture_labels",
           "session_labels"]

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


def _parse_session(path: str | Path) -> tuple[Session | None, list[ConfigError]]:  # noqa: C901
    p = Path(path).absolute()
    toml_path = p / "session.toml" if p.is_dir() else p
    try:
        root = toml_path.parent.resolve()
    except (OSError, RuntimeError) as exc:
        return None, [ConfigError(toml_path, f"cannot resolve the session folder: {exc}")]
    col = Collector(toml_path, doc="session")
    doc = read_document(toml_path, col, _SESSION_TOP)
    if doc is None:
        return None, col.errors

    sess = col.table(doc.get("session", {}), "session") or {}
    col.unknown_keys(sess, _SESSION_KEYS, "session.")
    if "id" in sess:
        sid = col.word(sess, "id", "session.id", "session id")
    else:
        sid = root.name
        if not WORD.fullmatch(sid):
            col.add("session.id", f"missing, and the folder name {show(sid)} is not a valid id: set it")
            sid = None
        elif len(sid) > MAX_ID_CHARS:
            col.add("session.id", f"missing, and the folder name is not a usable id: {too_long('it', sid)}")
            sid = None
    subject = col.word(sess, "subject", "session.subject", "subject", required=True)
    ms_rel = col.string(sess, "markerset", "session.markerset")
    ms_path = resolve_inside(root, ms_rel, "session.markerset", col) if ms_rel is not None else None

    defaults = col.table(doc.get("defaults", {}), "defaults") or {}
    col.unknown_keys(defaults, _DEFAULT_KEYS, "defaults.")
    d_pose = col.word(defaults, "pose", "defaults.pose", "pose")
    d_split = _split(defaults, "defaults.split", col)
    d_rate = col.rate(defaults, "rate_hz", "defaults.rate_hz")
    d_tc = col.rate(defaults, "timecode_fps", "defaults.timecode_fps")

    takes: list[Take] = []
    raw_takes = doc.get("takes")
    if raw_takes is None or raw_takes == []:
        col.add("takes", "no [[takes]] in the session")
        raw_takes = []
    elif not isinstance(raw_takes, list):
        col.add("takes", f"must be an array of tables ([[takes]]), got {type_name(raw_takes)}")
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
                col.errors.append(doc_error(ms_path, "missing (gaze_follow takes need the target marker)",
                                            key="target", doc="markerset"))
            if not ms.clapper and any(t.video for t in takes):
                col.errors.append(doc_error(ms_path, "missing (takes with video need the two clapper markers)",
                                            key="clapper", doc="markerset"))
    elif ms_rel is None and needs_ms:
        col.add("session.markerset", "missing (takes with mocap need a markerset.toml)")

    if col.errors:
        return None, col.errors
    assert sid is not None and subject is not None
    return Session(root=str(root), path=str(toml_path), id=sid, subject=subject, markerset=ms,
                   takes=tuple(takes)), []


def _split(table: dict, key: str, col: Collector, take: str | None = None) -> str | None:
    value = table.get(key.rsplit(".", 1)[-1])
    if value is None:
        return None
    if value not in SPLITS:
        col.add(key, f"bad split {show(value)} (expected {', '.join(SPLITS)})", take)
        return None
    return value


def _take(raw: Any, i: int, root: Path, col: Collector, ids: dict[str, int], d_pose: str | None,
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


def _take_fields(t: dict, i: int, tid: str | None, root: Path, col: Collector, ids: dict[str, int],
                 n_before: int, d_pose: str | None, d_split: str | None, d_rate: float | None,
                 d_tc: float | None) -> Take | None:
    key = f"takes[{i}]"
    if tid is not None:
        if tid in ids:
            col.add(f"{key}.id", f"duplicate take id {tid!r} (also takes[{ids[tid]}])", tid)
        else:
            ids[tid] = i
    kind = _take_kind(t, key, tid, col, d_rate)

    pose = col.word(t, "pose", f"{key}.pose", "pose") if "pose" in t else d_pose
    if pose is None and kind in ("gaze_follow", "gaze_shift") and "pose" not in t:
        col.add(f"{key}.pose", "missing (set it on the take or in [defaults])", tid)
    split = _split(t, f"{key}.split", col, tid) if "split" in t else d_split
    files = _take_files(t, key, tid, kind, root, col)
    rate = col.rate(t, "rate_hz", f"{key}.rate_hz") if "rate_hz" in t else d_rate
    tc = col.rate(t, "timecode_fps", f"{key}.timecode_fps") if "timecode_fps" in t else d_tc
    yaw, pitch = _target(t, key, tid, kind, col)

    if len(col.errors) > n_before:
        return None
    assert tid is not None and kind is not None
    return Take(id=tid, kind=kind, pose=pose or UNSPECIFIED_POSE, mocap=files.get("mocap"), video=files.get("video"),
                eyes=files.get("eyes"), tracked=files.get("tracked"), clean=files.get("clean"), split=split,
                target_yaw_deg=yaw, target_pitch_deg=pitch,
                rate_hz=None if rate is None else stated_rate(rate),
                timecode_fps=60.0 if tc is None else stated_rate(tc))


def _take_kind(t: dict, key: str, tid: str | None, col: Collector, d_rate: float | None) -> str | None:
    """The take's kind (None when missing or unknown), its keys checked against it."""
    kind = col.string(t, "kind", f"{key}.kind", required=True)
    if kind is not None and kind not in TAKE_KINDS:
        col.add(f"{key}.kind", f"unknown take kind {show(kind)}{suggest(kind, TAKE_KINDS)}"
                f" (expected {', '.join(TAKE_KINDS)})", tid)
        kind = None
    for name in t:
        if name not in _TAKE_KEYS:
            col.add(f"{key}.{key_name(name)}", f"unknown key {name!r}{suggest(str(name), _TAKE_KEYS)}", tid)
        elif kind is not None and name not in ("id", "kind", "pose", "split") and name not in _KIND_KEYS[kind]:
            col.add(f"{key}.{name}", f"{name!r} does not apply to {kind} takes", tid)
    if kind is not None:
        for name in _KIND_REQUIRED[kind]:
            if name not in t and not (name == "rate_hz" and d_rate is not None):
                col.add(f"{key}.{name}", f"missing: {kind} takes need {name!r}", tid)
    return kind


def _take_files(t: dict, key: str, tid: str | None, kind: str | None, root: Path,
                col: Collector) -> dict[str, str | None]:
    """The take's files by key: paths inside the session folder (else the session is refused); whether they
    exist and can be read is the take's own matter (a missing one fails that take when the run plans it)."""
    files: dict[str, str | None] = {}
    for name in _FILE_KEYS:
        if name in t and (kind is None or name in _KIND_KEYS[kind]):
            value = col.string(t, name, f"{key}.{name}")
            files[name] = None if value is None else resolve_inside(root, value, f"{key}.{name}", col, tid,
                                                                    must_exist=False)
    mocap = files.get("mocap")
    if mocap is not None and Path(mocap).suffix.lower() not in MOCAP_SUFFIXES:
        col.add(f"{key}.mocap", f"unsupported mocap file type {show(Path(mocap).suffix)} "
                f"(expected {', '.join(MOCAP_SUFFIXES)})", tid)
    return files


def _target(t: dict, key: str, tid: str | None, kind: str | None,
            col: Collector) -> tuple[float | None, float | None]:
    """A gaze_shift take's requested change (yaw, pitch), degrees; None where not given."""
    yaw = pitch = None
    if "target" in t and kind == "gaze_shift" and (tgt := col.table(t["target"], f"{key}.target")) is not None:
        col.unknown_keys(tgt, ("yaw_deg", "pitch_deg"), f"{key}.target.")
        for name in ("yaw_deg", "pitch_deg"):
            if name not in tgt:
                col.add(f"{key}.target.{name}", "missing (a number of degrees)", tid)
        yaw = col.number(tgt, "yaw_deg", f"{key}.target.yaw_deg")
        pitch = col.number(tgt, "pitch_deg", f"{key}.target.pitch_deg")
        if yaw is not None and abs(yaw) > 180:
            col.add(f"{key}.target.yaw_deg", f"out of range [-180, 180]: {show(yaw)}", tid)
        if pitch is not None and abs(pitch) > 90:
            col.add(f"{key}.target.pitch_deg", f"out of range [-90, 90]: {show(pitch)}", tid)
    return yaw, pitch


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


def session_labels(markerset: MarkerSet, labels: Sequence[str], path: str | Path, take_id: str | None,
                   required: Iterable[str] | None = None) -> tuple[list[str], list[str]]:
    """A capture's labels as the session names its markers: one name per marker across the session's takes,
    whatever program exported each take.

    When the markerset's names carry no ``Subject:`` prefix, the prefix is stripped from every label, listed in
    the markerset or not (Nexus writes ``p19:LSHO`` in a CSV export and may write ``LSHO`` in the same session's
    C3D files: both are ``LSHO``). Labels that would share a name after stripping (two subjects' markers, or
    ``p19:LSHO`` beside ``LSHO``) keep their names and are reported, never merged; a markerset marker among them
    is then the label equal to its name, or an error when only prefixed ones exist (:func:`check_capture_labels`).
    When the markerset's names have prefixes, labels are matched to them as :func:`check_capture_labels` does.

    Returns the new labels (in column order) and notes naming the collisions. Raises :class:`InputError` as
    :func:`check_capture_labels` does (missing or ambiguous markerset markers).
    """
    mapping = check_capture_labels(markerset, labels, path, take_id, required=required)
    new = list(labels)
    notes: list[str] = []
    if any(":" in name for name in markerset.all_markers):
        for name, j in mapping.items():
            new[j] = name
        return (new if len(set(new)) == len(new) else list(labels)), notes
    short = [lab.rsplit(":", 1)[-1] if ":" in lab else lab for lab in labels]
    groups: dict[str, list[int]] = {}
    for j, name in enumerate(short):
        groups.setdefault(name, []).append(j)
    for name, cols in groups.items():
        if len(cols) == 1:
            new[cols[0]] = name
        elif any(":" in labels[j] for j in cols):
            shown = ", ".join(repr(labels[j]) for j in cols[:4]) + (" …" if len(cols) > 4 else "")
            notes.append(f"labels {shown} would all be {name!r} without their subject prefix: kept as they are "
                         "(two subjects, or one marker under two names?)")
    for name, j in mapping.items():       # a markerset marker among colliding labels: the one equal to its name
        new[j] = name
    return (new if len(set(new)) == len(new) else list(labels)), notes
