"""Which neutral poses a take's frames are calibrated against (SPEC §3.3): the session's ``neutral`` take, the
take's own first rest period, and, for a segment none of them gives, other takes' first rest periods.

Pure: markers in, pose sources out. The session stage ``neutral_poses`` cleans the session's sources once
(:func:`session_poses`); each take's ``frames`` unit then solves its frames against them
(:func:`frames_with_fallback`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from gazepipe.errors import GazepipeError, StageError
from gazepipe.model import Markers, MarkerSet
from gazepipe.schemas.poses import PoseSource
from gazepipe.stages.clean.stage import CleanParams, clean_markers
from gazepipe.stages.clean.swaps import SubjectReferences
from gazepipe.stages.frames.stage import FramesParams, Joints, calibrated_segments, compute_frames

#: a take's capture, read when drawn: ``(take id, kind, capture path, read)``; ``read()`` raises
#: :class:`~gazepipe.errors.GazepipeError` for a capture that cannot be read
Capture = tuple[str, str, str | None, Callable[[], Markers]]


def cleaned_pose(capture: Capture, ms: MarkerSet, params: CleanParams, refs: SubjectReferences | None
                 ) -> Markers | None:
    """A take's neutral pose, cleaned from its capture as its clean unit cleans it: the whole take for a
    ``neutral`` take, else its first rest period (None when it has none)."""
    take, kind, path, read = capture
    res = clean_markers(read(), ms, kind, params, path=path, take=take, references=refs)
    return res.markers if kind == "neutral" else res.neutral


def gives_segment(pose: Markers, names: Sequence[str], min_frames: int) -> bool:
    """Whether ``pose`` has every marker ``names`` measured or filled in at least ``min_frames`` frames."""
    if not all(n in pose.labels for n in names):
        return False
    return int(np.isfinite(pose.xyz[:, [pose.index(n) for n in names]]).all(axis=(1, 2)).sum()) >= min_frames


def first_givers(rests: Iterable[PoseSource], need: dict[str, tuple[str, ...]], min_frames: int) -> list[PoseSource]:
    """Of ``rests``, in order, those that give a segment of ``need`` (name: markers) still without one; the
    segments given leave ``need``. No rest is drawn once every segment has one."""
    out: list[PoseSource] = []
    if not need:
        return out
    for pose in rests:
        solved = [seg for seg, names in need.items() if gives_segment(pose.markers, names, min_frames)]
        if solved:
            out.append(pose)
            for seg in solved:
                need.pop(seg)
            if not need:
                break
    return out


def fallback_rests(poses: list[PoseSource], take_id: str, ms: MarkerSet, missing: list[str],
                   min_frames: int) -> list[PoseSource]:
    """Neutral sources of last resort (SPEC §3.3) for a take whose segments ``missing`` have none: among the
    session's first rest periods (``poses``, in session order) of the other takes, each that gives a segment
    still missing."""
    rests = (pose for pose in poses if pose.role == "rest" and pose.take != take_id)
    return first_givers(rests, {seg: ms.segment(seg).markers for seg in missing}, min_frames)


def _other_rests(others: Iterable[Capture], ms: MarkerSet, params: CleanParams,
                 refs: SubjectReferences | None) -> Iterator[PoseSource]:
    """The first rest periods of ``others`` (the session's subject takes but the neutral take, in session order),
    each cleaned when drawn (a take whose capture cannot be read or cleaned, or without a rest, is passed
    over)."""
    for capture in others:
        try:
            rest = cleaned_pose(capture, ms, params, refs)
        except GazepipeError:
            continue
        if rest is not None and rest.n_frames:
            yield PoseSource(f"first rest period of take {capture[0]}", capture[0], "rest", rest)


@dataclass(frozen=True)
class SessionPoses:
    """A session's neutral poses (:func:`session_poses`): the sources in order, the segments no source gives, and
    warnings."""

    poses: list[PoseSource]
    without_neutral: list[str]
    warnings: list[str]


def session_poses(neutral: Capture | None, others: Iterable[Capture], ms: MarkerSet, clean: CleanParams,
                  frames: FramesParams, refs: SubjectReferences | None) -> SessionPoses:
    """The session's neutral poses (SPEC §3.3), cleaned once for every take's frames: the ``neutral`` take's,
    then, for each segment it cannot calibrate, the first rest periods of ``others`` in order until every such
    segment has one (a take whose capture cannot be read or cleaned is passed over)."""
    poses: list[PoseSource] = []
    warnings: list[str] = []
    calibrated: set[str] | None = set()
    pose: Markers | None = None
    if neutral is not None:
        try:
            pose = cleaned_pose(neutral, ms, clean, refs)
        except GazepipeError as exc:   # its own take fails; the others calibrate on their rests (SPEC §3.3)
            warnings.append(f"neutral take {neutral[0]} left out: {exc.one_line()}")
        if pose is not None:
            poses.append(PoseSource(f"neutral take {neutral[0]}", neutral[0], "neutral", pose))
            calibrated = calibrated_segments(pose, ms, frames)
    # a segment the neutral take cannot calibrate (or all, when the take's other sources decide) may be
    # missing in a take's frames: the first rest periods that give it, for that take to fall back on
    need = {seg.name: seg.markers for seg in ms.segments if calibrated is None or seg.name not in calibrated}
    poses += first_givers(_other_rests(others, ms, clean, refs), need, frames.min_neutral_frames)
    return SessionPoses(poses, sorted(need), warnings)


@dataclass(frozen=True)
class OwnRest:
    """A take's own first rest period (from its ``neutral`` table): its cleaned markers (no frames: none), its
    row indices in the uncropped take, its (start, stop) rows, and which samples were measured."""

    markers: Markers
    frames: np.ndarray
    rest: object
    measured: np.ndarray | None


@dataclass(frozen=True)
class TakeMarkers:
    """A take's cleaned markers (its ``markers`` table): the markers, their row indices in the uncropped take,
    which samples were measured, and each filled sample's estimated error (mm)."""

    markers: Markers
    frames: np.ndarray
    measured: np.ndarray | None
    fill_error_mm: np.ndarray | None


def frames_with_fallback(take: TakeMarkers, own: OwnRest, poses: list[PoseSource], ms: MarkerSet, kind: str,
                         params: FramesParams, *, path: str | None, take_id: str) -> tuple[Joints, str]:
    """A take's frames (:func:`compute_frames`) against its neutral sources in order of preference (SPEC §3.3):
    the session's ``neutral`` take, its own first rest, and, for segments none of them gives, other takes' first
    rests (:func:`fallback_rests`). Returns the joints and the name of the first source ("none" without any)."""
    sources: list[tuple[str, Markers]] = [(p.label, p.markers) for p in poses if p.role == "neutral"]
    if own.markers.n_frames:
        sources.append((f"first rest period {own.rest}", own.markers))
    # the first rest ends where the crop starts: its frames give rotation gaps open at the crop's start a side
    starts = own.markers.n_frames and len(take.frames) and own.frames[-1] + 1 == take.frames[0]
    before = own.markers if starts else None
    if kind != "gaze_follow":  # only gaze_follow takes track the target marker
        ms = dataclasses.replace(ms, target=None)

    def solve(srcs: list[tuple[str, Markers]]) -> Joints:
        return compute_frames(take.markers, ms, srcs, params, path=path, take=take_id, before=before,
                              measured=take.measured, before_measured=own.measured,
                              fill_error_mm=take.fill_error_mm)

    failure: StageError | None = None
    joints: Joints | None = None
    try:
        joints = solve(sources)
        missing = [seg for seg, src in joints.qc["neutral_sources"].items() if src is None]
    except StageError as exc:      # no segment has a neutral pose among these sources
        missing, failure = [seg.name for seg in ms.segments], exc
    if missing:
        # last resort: another take's first rest
        extra = fallback_rests(poses, take_id, ms, missing, params.min_neutral_frames)
        if extra:
            joints = solve(sources + [(p.label, p.markers) for p in extra])
        elif failure is not None:
            raise failure
    assert joints is not None
    return joints, sources[0][0] if sources else "none"
