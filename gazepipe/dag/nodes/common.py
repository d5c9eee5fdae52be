"""What the stages' runs share: their context types, which takes each stage applies to, the session's subject
captures, and notes naming the file they are about."""

from __future__ import annotations

import functools
import os
import stat as stat_mode
from pathlib import Path
from typing import TypeVar

from gazepipe.errors import GazepipeError, printable
from gazepipe.io.session_toml import session_labels
from gazepipe.model import Markers, MarkerSet, Session, Take
from gazepipe.pipeline.registry import SessionContext, UnitContext
from gazepipe.stages.ingest_qc import required_markers

#: what a take stage's unit and a session stage's unit are given, with gazepipe's own session and take types
TakeContext = UnitContext[Session, Take]
SessionUnitContext = SessionContext[Session]

X = TypeVar("X")


def given(value: X | None, what: str) -> X:
    """A setting the stage's ``applies`` guarantees its takes have (a capture path, the markerset)."""
    if value is None:
        raise RuntimeError(f"{what} is missing, yet the stage applies")
    return value


def file_notes(session: Session, path: str, notes: list[str]) -> list[str]:
    """A reader's notes on ``path``, each starting with the file's path in the session folder."""
    rel = os.path.relpath(path, session.root)
    return [f"{printable(rel)}: {n}" for n in notes]


# ------------------------------------------------------------------------------ which takes a stage applies to

def has_mocap(session: Session, take: Take) -> bool:
    return take.mocap is not None


def subject_take(session: Session, take: Take) -> bool:
    return take.mocap is not None and session.markerset is not None and take.kind != "face"


def frames_take(session: Session, take: Take) -> bool:
    return subject_take(session, take) and take.kind in ("gaze_follow", "gaze_shift")


def face_take(session: Session, take: Take) -> bool:
    return take.kind == "face" and take.tracked is not None and take.clean is not None


def sync_take(session: Session, take: Take) -> bool:
    ms = session.markerset
    return subject_take(session, take) and take.video is not None and ms is not None and len(ms.clapper) == 2


def eyes_take(session: Session, take: Take) -> bool:
    return frames_take(session, take) and take.eyes is not None


def has_subject(session: Session) -> bool:
    return session.markerset is not None and any(subject_take(session, t) for t in session.takes)


def has_frames(session: Session) -> bool:
    return any(frames_take(session, t) for t in session.takes)


def neutral_take(session: Session) -> Take | None:
    return next((t for t in session.takes if t.kind == "neutral" and t.mocap), None)


# ------------------------------------------------------------------------------------------- raw inputs

def markerset_file(session: Session) -> list[str]:
    return [session.markerset.path] if session.markerset else []


def read_capture(take: Take, ms: MarkerSet) -> Markers:
    """A take's capture with the markerset's names (as its ingest unit reads it)."""
    from gazepipe.io.capture import read_markers

    mocap = given(take.mocap, "mocap")
    raw = read_markers(mocap, rate_hz=take.rate_hz, default_units=ms.units)
    need = required_markers(ms, take.kind, take.video is not None)
    raw.labels = session_labels(ms, raw.labels, mocap, take.id, required=need)[0]
    return raw


def file_id(path: str) -> tuple[int, int, int]:
    """Size, mtime (ns) and inode of a file, stat'ed on every call (never cached: a file rewritten in the same
    process gets a new id), so a changed file is looked at again by :func:`usable_capture`."""
    st = os.stat(path)
    return st.st_size, st.st_mtime_ns, st.st_ino


@functools.lru_cache(maxsize=1024)
def usable_capture(path: str, file_id: tuple[int, int, int]) -> bool:
    """Whether the capture at ``path`` (identified by ``file_id``, :func:`file_id`) is a regular file that
    passes :func:`gazepipe.dag.store.check_source`."""
    from gazepipe.dag.store import check_source

    if not stat_mode.S_ISREG(os.stat(path).st_mode):
        return False
    try:
        check_source(Path(path))
    except GazepipeError:
        return False
    return True


def subject_captures(session: Session) -> list[Take]:
    """The session's subject takes whose capture is a regular file that passes the engine's look at an input
    (:func:`gazepipe.dag.store.check_source`): the subject's marker geometry comes from all of them. A broken
    capture fails its own take's units only; the others go on without it (and re-run once it is mended: it then
    joins their sources)."""
    out = []
    for t in session.takes:
        if subject_take(session, t) and t.mocap:
            try:
                if usable_capture(t.mocap, file_id(t.mocap)):
                    out.append(t)
            except OSError:
                continue
    return out


def subject_files(session: Session) -> list[str]:
    return [t.mocap for t in subject_captures(session) if t.mocap]

