"""gazepipe's take stages, registered with the engine in dependency order, and the table store they write with.

Each entry wires a pure function of :mod:`gazepipe.stages` to the engine: which takes it applies to, which raw
files it reads (through :mod:`gazepipe.io`), which tables it reads (``inputs``, ``session_inputs``: the engine
derives the stages it follows from them and refuses a load of any other) and which tables it returns.
Readers and stage functions are imported inside the ``run_*`` functions: planning needs only the parameter
defaults, so a run with nothing to do never pays for importing scipy.signal, pandas or OpenCV.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import pyarrow as pa

from gazepipe.errors import GazepipeError, ResourceError, SchemaError, StageError, printable
from gazepipe.io.parquet import count_rows, read_table, write_table
from gazepipe.io.session_toml import session_labels
from gazepipe.model import FILL_CODES, Markers, MarkerSet, Session, Take
from gazepipe.pipeline.registry import (
    SessionContext,
    SessionStage,
    Stage,
    TableStore,
    UnitContext,
    UnitResult,
    register,
    register_session_stage,
    rules_of,
    set_source_check,
    set_table_store,
)
from gazepipe.pipeline.state import OutLayout
from gazepipe.schemas import expected_schema
from gazepipe.schemas.base import attach_meta, check_table, read_meta
from gazepipe.schemas.face_table import face_to_table
from gazepipe.schemas.joints import fixed_list, joints_arrays, joints_schema, joints_to_table
from gazepipe.schemas.markers import (
    MARKERS_CLEAN,
    MARKERS_RAW,
    REST_SPEED,
    check_markers_meta,
    fill_errors,
    markers_to_table,
    rest_speed_to_table,
    table_to_markers,
)
from gazepipe.schemas.poses import (
    ARRAYS,
    MARKER_STACK,
    PoseSource,
    arrays_to_table,
    stack_to_table,
    table_to_arrays,
    table_to_stack,
)
from gazepipe.schemas.tracks import EYES, SYNC, face_schema
from gazepipe.stages.clean.stage import CleanParams
from gazepipe.stages.eyes.params import EyesParams
from gazepipe.stages.frames.stage import FramesParams
from gazepipe.stages.sync.stage import SyncParams

if TYPE_CHECKING:
    from gazepipe.stages.clean.swaps import SubjectReferences

#: what a take stage's unit and a session stage's unit are given, with gazepipe's own session and take types
TakeContext = UnitContext[Session, Take]
SessionUnitContext = SessionContext[Session]

#: tables in the long markers layout, whose metadata must agree with their rows
MARKERS_TABLES = ("markers_raw", "markers", "neutral")


def check_stored_table(table: pa.Table, path: Path, name: str) -> None:
    """Raise :class:`~gazepipe.errors.SchemaError` when a take's table ``name`` does not have the schema a table
    of that name must have (sized tables: from their metadata), or a markers table's metadata disagrees with
    its rows."""
    try:
        schema = expected_schema(name, table)
    except ValueError as exc:   # its metadata, read for its sizes, is not JSON
        raise SchemaError(str(path), f"table {name}: unreadable metadata ({exc})") from None
    if schema is not None:
        check_table(table, schema, path=str(path))
    if name in MARKERS_TABLES:
        check_markers_meta(table, str(path))


set_table_store(TableStore(write=write_table, read=read_table, check=check_stored_table))


def check_source(path: Path) -> None:
    """A look at an input before the engine hashes it: a C3D's declared layout against its size (a header
    that claims two million frames in a small file fails the take at once)."""
    if path.suffix.lower() == ".c3d":
        from gazepipe.io.c3d import check_c3d

        check_c3d(path)


set_source_check(check_source)


X = TypeVar("X")


def _given(value: X | None, what: str) -> X:
    """A setting the stage's ``applies`` guarantees its takes have (a capture path, the markerset)."""
    if value is None:
        raise RuntimeError(f"{what} is missing, yet the stage applies")
    return value


def _has_mocap(session: Session, take: Take) -> bool:
    return take.mocap is not None


def _markerset_file(session: Session) -> list[str]:
    return [session.markerset.path] if session.markerset else []


# ------------------------------------------------------------------------------------------------ ingest

def _required_markers(ms, take: Take) -> list[str]:
    """Markers a take of this kind cannot do without: the subject's, the target when the subject follows it,
    the clapper when a video must be synchronised."""
    names = list(ms.subject_markers)
    if take.kind == "gaze_follow" and ms.target:
        names.append(ms.target)
    if take.video and ms.clapper:
        names.extend(ms.clapper)
    return names


def _file_notes(ctx: TakeContext, path: str, notes: list[str]) -> list[str]:
    """A reader's notes on ``path``, each starting with the file's path in the session folder."""
    rel = os.path.relpath(path, ctx.session.root)
    return [f"{printable(rel)}: {n}" for n in notes]


def run_ingest(ctx: TakeContext) -> UnitResult:
    from gazepipe.io.capture import read_markers

    take, ms = ctx.take, ctx.session.markerset
    mocap = _given(take.mocap, "mocap")
    markers = read_markers(mocap, rate_hz=take.rate_hz, default_units=ms.units if ms else "mm")
    meta: dict = {}
    if ms is not None:
        labels, notes = session_labels(ms, markers.labels, mocap, take.id, required=_required_markers(ms, take))
        markers.warnings.extend(notes)
        if labels != markers.labels:
            meta["renamed_labels"] = {a: b for a, b in zip(markers.labels, labels, strict=True) if a != b}
            markers.labels = labels
    gap = markers.gap_fraction()
    qc = {
        "frames": markers.n_frames, "rate_hz": markers.rate_hz, "first_frame": markers.first_frame,
        "units_found": markers.units, "markers": markers.n_markers,
        "gap_fraction": {lab: round(float(g), 6) for lab, g in zip(markers.labels, gap, strict=True)},
        "model_outputs": len(markers.model_outputs),
    }
    table = markers_to_table(markers, meta=meta)
    return UnitResult(tables={"markers_raw": (table, MARKERS_RAW)}, qc=qc,
                      warnings=_file_notes(ctx, mocap, markers.warnings))


register(Stage(
    name="ingest", version="2", params={},
    outputs=("markers_raw",), applies=_has_mocap,
    sources=lambda s, t: [t.mocap, *_markerset_file(s)],
    run=run_ingest,
    help="read the take's capture files into canonical tables",
))



# ---------------------------------------------------------------------------------------- session stages

def _file_id(path: str) -> tuple[int, int, int]:
    """Size, mtime (ns) and inode of a file, stat'ed on every call (never cached: a file rewritten in the same
    process gets a new id), so a changed file is looked at again by :func:`_usable_capture`."""
    st = os.stat(path)
    return st.st_size, st.st_mtime_ns, st.st_ino


def _subject_captures(session: Session) -> list[Take]:
    """The session's subject takes whose capture is a regular file that passes the engine's look at an input
    (:func:`check_source`): the subject's marker geometry comes from all of them. A broken capture fails its
    own take's units only; the others go on without it (and re-run once it is mended: it then joins their
    sources)."""
    out = []
    for t in session.takes:
        if _subject_take(session, t) and t.mocap:
            try:
                if _usable_capture(t.mocap, _file_id(t.mocap)):
                    out.append(t)
            except OSError:
                continue
    return out


@functools.lru_cache(maxsize=1024)
def _usable_capture(path: str, file_id: tuple[int, int, int]) -> bool:
    """Whether the capture at ``path`` (identified by ``file_id``, :func:`_file_id`) is a regular file that
    passes :func:`check_source`."""
    import stat as stat_mode

    if not stat_mode.S_ISREG(os.stat(path).st_mode):
        return False
    try:
        check_source(Path(path))
    except GazepipeError:
        return False
    return True


def _subject_files(session: Session) -> list[str]:
    return [t.mocap for t in _subject_captures(session) if t.mocap]


def _has_subject(session: Session) -> bool:
    return session.markerset is not None and any(_subject_take(session, t) for t in session.takes)


def _read_capture(take: Take, ms: MarkerSet) -> Markers:
    """A take's capture with the markerset's names (as its ingest unit reads it)."""
    from gazepipe.io.capture import read_markers

    assert take.mocap is not None
    raw = read_markers(take.mocap, rate_hz=take.rate_hz, default_units=ms.units)
    raw.labels = session_labels(ms, raw.labels, take.mocap, take.id, required=_required_markers(ms, take))[0]
    return raw


#: frames of each take kept for the subject's references (they sample the stack evenly again)
_REFERENCE_FRAMES_PER_TAKE = 2000


def run_subject_geometry(ctx: SessionUnitContext) -> UnitResult:
    """The subject's marker geometry that each take's label swaps are judged against
    (:func:`gazepipe.stages.clean.swaps.pooled_references`), from evenly spread frames of every subject capture
    of the session. A capture that cannot be read is passed over (its own take fails)."""
    from gazepipe.stages.clean.swaps import even_rows, judged_columns, pooled_references

    ms = ctx.session.markerset
    assert ms is not None
    pooled, used = [], []
    for take in _subject_captures(ctx.session):
        try:
            raw = _read_capture(take, ms)
        except GazepipeError:
            continue
        rows = even_rows(raw.n_frames, _REFERENCE_FRAMES_PER_TAKE)
        pooled.append((raw.labels, raw.xyz[rows], raw.valid[rows]))
        used.append(take.id)
    meta: dict[str, Any] = {"takes": used, "labels": []}
    arrays: dict[str, np.ndarray] = {}
    if pooled:
        # every marker the captures carry, listed in the markerset or not, but the target, the clapper and
        # unlabeled trajectories: the markers the clean stage judges
        refs = pooled_references(pooled, markers={labels[i] for labels, _, _ in pooled
                                                  for i in judged_columns(labels, ms.target, ms.clapper)})
        meta["labels"] = list(refs.labels)
        arrays = {f.name: getattr(refs.references, f.name) for f in dataclasses.fields(refs.references)
                  if getattr(refs.references, f.name) is not None}
    return UnitResult(tables={"subject_geometry": (arrays_to_table(arrays, meta), ARRAYS)}, qc={"takes": len(used)})


def _subject_references(table: pa.Table) -> SubjectReferences | None:
    """The subject's marker geometry from the session's ``subject_geometry`` table; None when no capture could be
    read."""
    from gazepipe.stages.clean.swaps import References, SubjectReferences

    labels = read_meta(table).get("labels") or []
    if not labels:
        return None
    return SubjectReferences(tuple(labels), References(**table_to_arrays(table)))


register_session_stage(SessionStage(
    name="subject_geometry", version="2", uses=(), outputs=("subject_geometry",),
    applies=_has_subject, sources=lambda s: [*_markerset_file(s), *_subject_files(s)],
    run=run_subject_geometry,
    help="the subject's marker geometry from every subject capture of the session, that label swaps are judged "
         "against",
))


# ------------------------------------------------------------------------------------------------- clean

def _params_of(cls) -> dict:
    """A stage's parameter defaults from its parameters dataclass (tuples as lists, JSON-able)."""
    out = {}
    for f in dataclasses.fields(cls):
        v = getattr(cls(), f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def _build(cls, values: dict):
    kw = {}
    for f in dataclasses.fields(cls):
        if f.name in values:
            v = values[f.name]
            kw[f.name] = tuple(v) if isinstance(v, list) else v
    return cls(**kw)


def _subject_take(session: Session, take: Take) -> bool:
    return take.mocap is not None and session.markerset is not None and take.kind != "face"


def _load_markers(ctx: TakeContext, name: str, take_id: str | None = None) -> tuple[Markers, np.ndarray, dict]:
    markers, frames, _, meta = table_to_markers(ctx.load(name, take_id))
    return markers, frames, meta


def _load_measured(ctx: TakeContext, name: str, table: pa.Table | None = None
                   ) -> tuple[Markers, np.ndarray, dict, np.ndarray | None]:
    """A cleaned markers table (``markers``, ``neutral``; ``table`` when already loaded) and which of its samples
    were measured, (T, M) bool (fill code ``measured`` or ``swap_repaired``; None when the table has no fill
    codes)."""
    markers, frames, fill, meta = table_to_markers(ctx.load(name) if table is None else table)
    measured = None if fill is None else np.isin(fill, [FILL_CODES["measured"], FILL_CODES["swap_repaired"]])
    return markers, frames, meta, measured


def _bytes(n: int) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def run_clean(ctx: TakeContext) -> UnitResult:
    from gazepipe.pipeline.resources import available_memory_bytes
    from gazepipe.stages.clean.stage import clean_markers, clean_memory_bytes

    # the marker samples, from the table's footer: refused before anything is loaded, rather than killed (or
    # swapping) an hour in
    samples = count_rows(OutLayout(ctx.out_dir).table(ctx.session.id, ctx.take.id, "markers_raw"))
    need, free = clean_memory_bytes(samples or 0), available_memory_bytes()
    if free is not None and need > free:
        raise ResourceError(ctx.take.mocap, f"{samples:,} marker samples need about {_bytes(need)} to clean, "
                                            f"more than the {_bytes(free)} free: split the take, or run it alone "
                                            "on a larger machine", take=ctx.take.id)
    raw, _, _ = _load_markers(ctx, "markers_raw")
    params = _build(CleanParams, ctx.params)
    ms = _given(ctx.session.markerset, "markerset")
    refs = _subject_references(ctx.load_session("subject_geometry")) if params.repair_swaps else None
    res = clean_markers(raw, ms, ctx.take.kind, params, path=ctx.take.mocap, take=ctx.take.id,
                        references=refs)
    # the raw positions are not needed any more: a long take's are let go before the tables are built
    raw = dataclasses.replace(raw, xyz=raw.xyz[:0].copy(), valid=raw.valid[:0].copy())
    kept = dataclasses.replace(res.markers, first_frame=raw.first_frame)
    meta = {"crop": list(res.crop), "rests": [list(r) for r in res.rests], "stabilised": True}
    tables = {"markers": (markers_to_table(kept, frames=res.frames, fill_code=res.fill_code, spike=res.spike,
                                           fill_error_mm=res.fill_error_mm, meta=meta),
                          MARKERS_CLEAN)}
    # the first rest with its fill codes: which of its samples were measured (the frames stage's rest pose)
    if res.neutral is not None:
        a, b = res.rests[0] if res.rests else (0, res.neutral.n_frames)
        neutral = dataclasses.replace(res.neutral, first_frame=raw.first_frame)
        tables["neutral"] = (markers_to_table(neutral, frames=np.arange(a, b), fill_code=res.neutral_fill_code,
                                              meta={"rest": [a, b]}), MARKERS_CLEAN)
    else:
        tables["neutral"] = (markers_to_table(raw, fill_code=np.zeros(raw.valid.shape, np.int8),
                                              meta={"rest": None}), MARKERS_CLEAN)
    tables["rest_speed"] = (rest_speed_to_table(res.speed_mm_s), REST_SPEED)
    qc = dict(res.qc)
    return UnitResult(tables=tables, qc=qc, warnings=list(qc.get("warnings", [])))


register(Stage(
    name="clean", version="27", inputs=("markers_raw",), params=_params_of(CleanParams),
    outputs=("markers", "neutral", "rest_speed"), applies=_subject_take,
    # label swaps are judged against the subject's geometry from every subject capture of the session
    sources=lambda s, t: _markerset_file(s), session_inputs=("subject_geometry",),
    run=run_clean,
    help="spikes, gap filling, root stabilisation, optional low-pass, rest cropping",
    rules=rules_of(CleanParams),
))


# ------------------------------------------------------------------------------------------------ frames

def _neutral_take(session: Session) -> Take | None:
    return next((t for t in session.takes if t.kind == "neutral" and t.mocap), None)


def _frames_take(session: Session, take: Take) -> bool:
    return _subject_take(session, take) and take.kind in ("gaze_follow", "gaze_shift")


def _clean_pose(take: Take, ms: MarkerSet, params: CleanParams, refs: SubjectReferences | None) -> Markers | None:
    """A take's neutral pose, cleaned from its capture as its clean unit cleans it: the whole take for a
    ``neutral`` take, else its first rest period (None when it has none)."""
    from gazepipe.stages.clean.stage import clean_markers

    raw = _read_capture(take, ms)
    res = clean_markers(raw, ms, take.kind, params, path=take.mocap, take=take.id, references=refs)
    return res.markers if take.kind == "neutral" else res.neutral


def _gives_segment(pose: Markers, names: Sequence[str], min_frames: int) -> bool:
    """Whether ``pose`` has every marker ``names`` measured or filled in at least ``min_frames`` frames."""
    if not all(n in pose.labels for n in names):
        return False
    return int(np.isfinite(pose.xyz[:, [pose.index(n) for n in names]]).all(axis=(1, 2)).sum()) >= min_frames


def run_neutral_poses(ctx: SessionUnitContext) -> UnitResult:
    """The session's neutral poses (SPEC §3.3), cleaned once for every take's frames: the neutral take's, then,
    for each segment it cannot calibrate, the first rest periods of the other subject takes in session order
    until every such segment has one (a take whose capture cannot be read or cleaned is passed over)."""
    from gazepipe.stages.frames.stage import calibrated_segments

    session = ctx.session
    ms = session.markerset
    assert ms is not None
    clean_params = _build(CleanParams, ctx.params_of("clean"))
    frames_params = _build(FramesParams, ctx.params_of("frames"))
    refs = _subject_references(ctx.load("subject_geometry")) if clean_params.repair_swaps else None
    poses: list[PoseSource] = []
    warnings: list[str] = []
    calibrated: set[str] | None = set()
    neutral_take = _neutral_take(session)
    pose: Markers | None = None
    if neutral_take is not None:
        try:
            pose = _clean_pose(neutral_take, ms, clean_params, refs)
        except GazepipeError as exc:   # its own take fails; the others calibrate on their rests (SPEC §3.3)
            warnings.append(f"neutral take {neutral_take.id} left out: {exc.one_line()}")
        if pose is not None:
            poses.append(PoseSource(f"neutral take {neutral_take.id}", neutral_take.id, "neutral", pose))
            calibrated = calibrated_segments(pose, ms, frames_params)
    # a segment the neutral take cannot calibrate (or all, when the take's other sources decide) may be
    # missing in a take's frames: the first rest periods that give it, for that take to fall back on
    need = {seg.name: seg.markers for seg in ms.segments if calibrated is None or seg.name not in calibrated}
    poses += _first_givers(_other_rests(session, ms, clean_params, refs), need, frames_params.min_neutral_frames)
    if ms.head_centre is None and ms.eye_offset_mm is None:   # once for the session, not on each of its takes
        where = os.path.relpath(ms.path, session.root) if ms.path and session.root else ms.path
        warnings.append(f"{where}: no head_centre marker and no eye_offset_mm: the eyes' centre is the head "
                        "markers' centroid in every take of the session")
    qc = {"sources": [p.label for p in poses], "segments_without_neutral": sorted(need), "warnings": warnings}
    return UnitResult(tables={"neutral_poses": (stack_to_table(poses), MARKER_STACK)}, qc=qc, warnings=warnings)


register_session_stage(SessionStage(
    name="neutral_poses", version="1", inputs=("subject_geometry",), uses=("clean", "frames"),
    outputs=("neutral_poses",), applies=lambda s: any(_frames_take(s, t) for t in s.takes),
    sources=lambda s: [*_markerset_file(s), *_subject_files(s)],
    run=run_neutral_poses,
    help="the neutral take's pose and, for segments it lacks, other takes' first rest periods, cleaned once",
))


def _other_rests(session: Session, ms: MarkerSet, params: CleanParams,
                 refs: SubjectReferences | None) -> Iterator[PoseSource]:
    """The first rest periods of the session's subject takes other than the neutral take, in session order,
    each cleaned when drawn (a take whose capture cannot be read or cleaned, or without a rest, is passed over)."""
    for other in session.takes:
        if other.kind == "neutral" or not _subject_take(session, other):
            continue
        try:
            rest = _clean_pose(other, ms, params, refs)
        except GazepipeError:
            continue
        if rest is not None and rest.n_frames:
            yield PoseSource(f"first rest period of take {other.id}", other.id, "rest", rest)


def _first_givers(rests: Iterable[PoseSource], need: dict[str, tuple[str, ...]], min_frames: int) -> list[PoseSource]:
    """Of ``rests``, in order, those that give a segment of ``need`` (name: markers) still without one; the
    segments given leave ``need``. No rest is drawn once every segment has one."""
    out: list[PoseSource] = []
    if not need:
        return out
    for pose in rests:
        solved = [seg for seg, names in need.items() if _gives_segment(pose.markers, names, min_frames)]
        if solved:
            out.append(pose)
            for seg in solved:
                need.pop(seg)
            if not need:
                break
    return out


def _fallback_rests(poses: list[PoseSource], take_id: str, ms: MarkerSet, missing: list[str],
                    min_frames: int) -> list[PoseSource]:
    """Neutral sources of last resort (SPEC §3.3) for a take whose segments ``missing`` have none: among the
    session's first rest periods (``poses``, in session order) of the other takes, each that gives a segment
    still missing."""
    rests = (pose for pose in poses if pose.role == "rest" and pose.take != take_id)
    return _first_givers(rests, {seg: ms.segment(seg).markers for seg in missing}, min_frames)


def run_frames(ctx: TakeContext) -> UnitResult:
    from gazepipe.stages.frames.stage import compute_frames

    ms = ctx.session.markerset
    assert ms is not None
    params = _build(FramesParams, ctx.params)
    table = ctx.load("markers")
    markers, frames, _, measured = _load_measured(ctx, "markers", table)
    poses = table_to_stack(ctx.load_session("neutral_poses"))
    # neutral poses, in order of preference (SPEC §3.3)
    sources: list[tuple[str, Markers]] = [(p.label, p.markers) for p in poses if p.role == "neutral"]
    own, own_frames, nmeta, own_measured = _load_measured(ctx, "neutral")
    if own.n_frames:
        sources.append((f"first rest period {nmeta.get('rest')}", own))
    # the first rest ends where the crop starts: its frames give rotation gaps open at the crop's start a side
    before = own if own.n_frames and len(frames) and own_frames[-1] + 1 == frames[0] else None
    if ctx.take.kind != "gaze_follow":  # only gaze_follow takes track the target marker
        ms = dataclasses.replace(ms, target=None)

    def solve(srcs: list[tuple[str, Markers]]):
        return compute_frames(markers, ms, srcs, params, path=ctx.take.mocap, take=ctx.take.id, before=before,
                              measured=measured, before_measured=own_measured, fill_error_mm=fill_errors(table))

    failure: StageError | None = None
    try:
        joints = solve(sources)
        missing = [seg for seg, src in joints.qc["neutral_sources"].items() if src is None]
    except StageError as exc:      # no segment has a neutral pose among these sources
        joints, missing, failure = None, [seg.name for seg in ms.segments], exc
    if missing:
        # last resort: another take's first rest
        extra = _fallback_rests(poses, ctx.take.id, ms, missing, params.min_neutral_frames)
        if extra:
            joints = solve(sources + [(p.label, p.markers) for p in extra])
        elif failure is not None:
            raise failure
    source = sources[0][0] if sources else "none"
    qc = dict(joints.qc)
    qc["neutral_source"] = source
    meta = {"neutral_source": source}
    if joints.rest_before is not None:
        meta["rest_before"] = joints.rest_before
    table = joints_to_table(joints, frames, meta=meta)
    return UnitResult(tables={"joints": (table, joints_schema(len(joints.segments)))}, qc=qc,
                      warnings=list(qc.get("warnings", [])))


register(Stage(
    name="frames", version="14", inputs=("markers", "neutral"), params=_params_of(FramesParams),
    outputs=("joints",), applies=_frames_take,
    sources=lambda s, t: _markerset_file(s), session_inputs=("neutral_poses",),
    run=run_frames,
    help="segment orientations in the character frame, head centre, target direction",
    rules=rules_of(FramesParams),
))


# -------------------------------------------------------------------------------------------------- face

def _face_take(session: Session, take: Take) -> bool:
    return take.kind == "face" and take.tracked is not None and take.clean is not None


def run_face(ctx: TakeContext) -> UnitResult:
    from gazepipe.io.livelinkface import read_livelinkface
    from gazepipe.stages.face.stage import align_face

    take = ctx.take
    tracked_path, clean_path = _given(take.tracked, "tracked"), _given(take.clean, "clean")
    tracked = read_livelinkface(tracked_path, rate_hz=take.rate_hz, timecode_fps=take.timecode_fps)
    clean = read_livelinkface(clean_path, rate_hz=take.rate_hz, timecode_fps=take.timecode_fps)
    aligned = align_face(tracked, clean, k=int(ctx.params["k"]), paths=(tracked_path, clean_path))
    qc = dict(aligned.qc)
    warnings = _file_notes(ctx, tracked_path, tracked.warnings) + _file_notes(ctx, clean_path, clean.warnings)
    qc["warnings"] = warnings
    table = face_to_table(aligned, meta={"rate_hz": tracked.rate_hz, "timecode_fps": take.timecode_fps})
    return UnitResult(tables={"face": (table, face_schema(aligned.k))}, qc=qc, warnings=warnings)


register(Stage(
    name="face", version="2", params={"k": 1},
    outputs=("face",), applies=_face_take,
    sources=lambda s, t: [t.tracked, t.clean],
    run=run_face,
    help="tracked and clean Live Link Face tracks aligned on timecode, dt and derivatives",
    rules={"k": {"min": 1}},
))


# -------------------------------------------------------------------------------------------------- sync



def _sync_take(session: Session, take: Take) -> bool:
    ms = session.markerset
    return _subject_take(session, take) and take.video is not None and ms is not None and len(ms.clapper) == 2


def _short_video_note(ts: np.ndarray, take_s: float) -> list[str]:
    """A note when a video (frame times ``ts``, s) lasts less than half its take (``take_s``): it cannot
    cover the take's eye data (the eyes stage names the video when that makes it fail)."""
    from gazepipe.stages.eyes.params import SHORT_VIDEO_SHARE

    video_s = float(ts[-1] - ts[0]) if ts.size >= 2 else 0.0
    if video_s < SHORT_VIDEO_SHARE * take_s:
        return [f"the video lasts {video_s:.1f} s but the take {take_s:.1f} s: frames after the video's end have "
                "no eye data"]
    return []


def run_sync(ctx: TakeContext) -> UnitResult:
    from gazepipe.io.video import FrameReader, probe_video
    from gazepipe.stages.sync.stage import sync_take

    take, ms = ctx.take, _given(ctx.session.markerset, "markerset")
    video = _given(take.video, "video")
    p = _build(SyncParams, ctx.params)
    raw, _, _ = _load_markers(ctx, "markers_raw")
    a, b = raw.index(ms.clapper[0]), raw.index(ms.clapper[1])
    probe = probe_video(video)
    ts = probe.timestamps_s

    # one open capture for all of the take's windows, read forward
    with FrameReader(video, gray=True, scale=p.video_scale, timestamps_s=ts) as read_window:
        res = sync_take(raw.xyz[:, a], raw.xyz[:, b], raw.valid[:, a], raw.valid[:, b], raw.rate_hz, ts,
                        read_window, window_s=p.window_s, search_s=p.search_s, max_drift=p.max_drift,
                        min_confidence=p.min_confidence,
                        mocap_path=take.mocap, video_path=take.video, take=take.id)
        damage = read_window.damage_warning()
    clock = res.clock
    rows = {
        "clap": np.arange(len(res.mocap_claps), dtype=np.int32),
        "mocap_s": np.array([c.time_s for c in res.mocap_claps]),
        "video_s": np.array([np.nan if v is None else v.time_s for v in res.video_claps]),
        "confidence_mocap": np.array([c.confidence for c in res.mocap_claps]),
        "confidence_video": np.array([np.nan if v is None else v.confidence for v in res.video_claps]),
        "offset_s": np.full(len(res.mocap_claps), clock.offset_s),
        "ratio": np.full(len(res.mocap_claps), clock.ratio),
    }
    table = attach_meta(pa.Table.from_pydict(rows, schema=SYNC), {"video_frames": int(ts.size),
                                                                  "video_nominal_fps": probe.nominal_fps})
    qc = dict(res.qc)
    short = _short_video_note(ts, raw.n_frames / raw.rate_hz)
    qc["warnings"] = list(qc.get("warnings", [])) + _file_notes(ctx, video, probe.warnings + ([damage] if damage else [])
                                                                + short)
    return UnitResult(tables={"sync": (table, SYNC)}, qc=qc, warnings=qc["warnings"])


register(Stage(
    name="sync", version="5", inputs=("markers_raw",), params=_params_of(SyncParams),
    outputs=("sync",), applies=_sync_take,
    sources=lambda s, t: [t.video, *_markerset_file(s)],
    run=run_sync,
    help="clapper claps on the mocap and video clocks, the clock map between them",
    rules=rules_of(SyncParams),
))


# -------------------------------------------------------------------------------------------------- eyes

def _eyes_take(session: Session, take: Take) -> bool:
    return _frames_take(session, take) and take.eyes is not None


def _video_seconds(meta: dict) -> float:
    """How long a take's video lasts (s), from the sync table's metadata (NaN when it does not say)."""
    try:
        return float(meta["video_frames"]) / float(meta["video_nominal_fps"])
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return float("nan")


def run_eyes(ctx: TakeContext) -> UnitResult:
    from gazepipe.io.openface import read_openface
    from gazepipe.stages.eyes.stage import HeadMotion, eyes_take, tag_mismatch
    from gazepipe.stages.sync.clock import ClockMap, resample_to_mocap

    take, ms = ctx.take, _given(ctx.session.markerset, "markerset")
    eyes_path = _given(take.eyes, "eyes")
    eye = read_openface(eyes_path)
    ja = joints_arrays(ctx.load("joints"))
    joints = HeadMotion(segments=tuple(ja["segments"]), quat=ja["quat"], rate_hz=float(ja["meta"]["rate_hz"]),
                        target_dir=ja["target_dir"], char_rot=ja["char_rot"])
    clock = ClockMap(offset_s=0.0, ratio=1.0, n_claps=0)
    video = None
    if take.video is not None:
        sync = ctx.load("sync")
        clock = ClockMap(offset_s=float(sync.column("offset_s")[0].as_py()),
                         ratio=float(sync.column("ratio")[0].as_py()), n_claps=sync.num_rows)
        meta = read_meta(sync)
        video = (take.video, _video_seconds(meta) * clock.ratio, meta.get("video_frames"),
                 meta.get("video_nominal_fps"))
    camera = None if ms.camera_rotation is None else np.asarray(ms.camera_rotation, dtype=np.float64)
    res = eyes_take(eye, joints, ja["time_s"], clock if take.video is not None else None,
                    camera_rotation=camera, params=_build(EyesParams, ctx.params), path=take.eyes, take=take.id,
                    video=video)
    frames = ja["frame"].astype(np.int64)
    # a valid frame is "filled" when either video sample around it was bridged by slerp
    g = res.gated
    not_filled, _ = resample_to_mocap(g.time_s, (~g.filled).astype(np.float64), "confidence", ja["time_s"], clock)
    filled = res.valid & (not_filled == 0)
    table = pa.Table.from_pydict({
        "frame": pa.array(frames.astype(np.int32)),
        "source_frame": pa.array(ja["source_frame"].astype(np.int64)),
        "time_s": pa.array(ja["time_s"]),
        "valid": pa.array(res.valid),
        "filled": pa.array(filled),
        "confidence": pa.array(res.confidence),
        "eye_dir_char": fixed_list(res.eye_dir_char, 3, np.float32),
        "eye_dir_head": fixed_list(res.eye_dir_head, 3, np.float32),
    }, schema=EYES)
    table = attach_meta(table, {"camera_rotation": [float(x) for x in res.camera_rotation],
                                "camera_source": res.camera_source, "rate_hz": float(joints.rate_hz)})
    qc = dict(res.qc)
    mismatch = tag_mismatch(video, eye)
    qc["warnings"] = (_file_notes(ctx, eyes_path, eye.warnings) + list(qc.get("warnings", []))
                      + (_file_notes(ctx, take.video, [mismatch]) if mismatch and take.video else []))
    return UnitResult(tables={"eyes": (table, EYES)}, qc=qc, warnings=qc["warnings"])


register(Stage(
    name="eyes", version="2", inputs=("joints", "sync"), params=_params_of(EyesParams),
    outputs=("eyes",), applies=_eyes_take,
    sources=lambda s, t: [t.eyes, *_markerset_file(s)],
    run=run_eyes,
    help="OpenFace gaze gated, blink-masked, bridged and rotated into the character frame",
    rules=rules_of(EyesParams),
))
