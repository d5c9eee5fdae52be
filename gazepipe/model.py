"""In-memory containers passed between readers, stages and writers.

Readers in :mod:`gazepipe.io` return these; stages in :mod:`gazepipe.stages` take and return them (or plain
numpy arrays); :mod:`gazepipe.schemas` turns them into Arrow tables and back.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gazepipe.arkit import ARKIT_NAMES, EYE_NAMES, HEAD_NAMES
from gazepipe.timebase import frame_times


@dataclass
class Markers:
    """Marker trajectories of one capture, in the canonical form.

    Attributes
    ----------
    labels : unique marker labels, in file order (duplicates already made unique: ``LABEL``, ``LABEL~2``).
    xyz : (T, M, 3) float64 positions in millimetres, lab frame; NaN wherever ``valid`` is False.
    valid : (T, M) bool, True where the sample was measured (or filled, after cleaning).
    rate_hz : sampling rate in Hz (already snapped by :func:`gazepipe.timebase.snap_rate`).
    first_frame : source frame number of row 0 (the C3D header's first frame; 1-based in most files).
    units : the point units as found in the file (``None`` when the file does not say).
    source_format : short name of the reader that produced it (``c3d``, ``vicon_csv``, ``qtm_tsv``, ``wide_csv``).
    model_outputs : labels of points that are model outputs (angles, forces, …), kept out of ``xyz``.
    warnings : one-line notes about the file (suspicious gap share, renamed labels, reader fallback, …).
    """

    labels: list[str]
    xyz: np.ndarray
    valid: np.ndarray
    rate_hz: float
    first_frame: int = 1
    units: str | None = None
    source_format: str = ""
    model_outputs: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.xyz = np.asarray(self.xyz, dtype=np.float64)
        self.valid = np.asarray(self.valid, dtype=bool)
        if self.xyz.ndim != 3 or self.xyz.shape[2] != 3:
            raise ValueError(f"xyz must be (T, M, 3), got {self.xyz.shape}")
        if self.valid.shape != self.xyz.shape[:2]:
            raise ValueError(f"valid must be {self.xyz.shape[:2]}, got {self.valid.shape}")
        if len(self.labels) != self.xyz.shape[1]:
            raise ValueError(f"{len(self.labels)} labels for {self.xyz.shape[1]} markers")
        if len(set(self.labels)) != len(self.labels):
            raise ValueError("marker labels must be unique")

    @property
    def n_frames(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def n_markers(self) -> int:
        return int(self.xyz.shape[1])

    @property
    def time_s(self) -> np.ndarray:
        """Seconds since the first frame, (T,) float64."""
        return frame_times(self.n_frames, self.rate_hz)

    @property
    def source_frame(self) -> np.ndarray:
        """Source frame number of every row, (T,) int64."""
        return self.first_frame + np.arange(self.n_frames, dtype=np.int64)

    def index(self, label: str) -> int:
        """Column of ``label`` (raises ``KeyError`` naming the label when absent)."""
        try:
            return self.labels.index(label)
        except ValueError:
            raise KeyError(label) from None

    def gap_fraction(self) -> np.ndarray:
        """Share of invalid samples per marker, (M,) float64."""
        if self.n_frames == 0:
            return np.ones(self.n_markers)
        return 1.0 - self.valid.mean(axis=0)


def filled_samples(orig: Markers, filled: Markers, removed: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The samples a gap filler changed in a capture, for writers that copy the file and rewrite only those.

    ``orig`` is the capture as read, ``filled`` the same markers after filling, ``removed`` (T, M) the measured
    samples taken out first (spikes). Returns ``(write, valid)``, (T, M) bool each: ``write`` where ``filled``
    gives a sample ``orig`` lacks or ``removed`` takes one out, ``valid`` the filled mask (a sample to write that
    is not valid becomes a gap). Raises ValueError when the two are not the same markers or a filled sample has
    no coordinates.
    """
    if filled.labels != orig.labels or filled.xyz.shape != orig.xyz.shape:
        raise ValueError("the filled markers do not match the file's markers")
    valid = np.asarray(filled.valid, dtype=bool)
    gone = np.zeros_like(valid) if removed is None else np.asarray(removed, dtype=bool) & orig.valid
    new = (valid & ~orig.valid) | (gone & valid)
    if new.any() and not np.isfinite(filled.xyz[new]).all():
        raise ValueError("a filled sample has no coordinates")
    return new | (gone & ~valid), valid


TAKE_KINDS = ("gaze_follow", "gaze_shift", "face", "neutral")
KNOWN_POSES = ("standing", "sitting", "laying", "walking")
SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class Segment:
    """One rigid body of the subject, from ``[segments.<name>]`` in markerset.toml."""

    name: str
    markers: tuple[str, ...]
    parent: str | None = None


@dataclass(frozen=True)
class MarkerSet:
    """The validated contents of markerset.toml (SPEC §1).

    ``segments`` are ordered from the root of the chain to the head (file order); the root segment is the
    first one without a parent. ``camera_rotation`` is a quaternion (w, x, y, z) or ``None``.
    """

    path: str
    up_axis: str
    units: str
    root: str
    target: str | None
    clapper: tuple[str, ...]
    segments: tuple[Segment, ...]
    head_centre: str | None = None
    eye_offset_mm: tuple[float, float, float] | None = None
    lod_segments: tuple[str, ...] = ()
    camera_rotation: tuple[float, float, float, float] | None = None

    @property
    def root_segment(self) -> Segment:
        return next(s for s in self.segments if s.parent is None)

    def segment(self, name: str) -> Segment:
        return next(s for s in self.segments if s.name == name)

    @property
    def subject_markers(self) -> tuple[str, ...]:
        """Markers on the subject: every segment marker, the root and the head centre (not target or clapper)."""
        names: list[str] = [self.root]
        for s in self.segments:
            names.extend(s.markers)
        if self.head_centre:
            names.append(self.head_centre)
        return tuple(dict.fromkeys(names))

    @property
    def all_markers(self) -> tuple[str, ...]:
        names = list(self.subject_markers)
        if self.target:
            names.append(self.target)
        names.extend(self.clapper)
        return tuple(dict.fromkeys(names))


@dataclass(frozen=True)
class Take:
    """One ``[[takes]]`` entry with every path resolved (absolute, inside the session folder)."""

    id: str
    kind: str
    pose: str
    mocap: str | None = None
    video: str | None = None
    eyes: str | None = None
    tracked: str | None = None
    clean: str | None = None
    split: str | None = None
    target_yaw_deg: float | None = None
    target_pitch_deg: float | None = None
    rate_hz: float | None = None
    timecode_fps: float = 60.0

    @property
    def files(self) -> tuple[str, ...]:
        """Every input file of the take, in a fixed order."""
        return tuple(p for p in (self.mocap, self.video, self.eyes, self.tracked, self.clean) if p)


@dataclass(frozen=True)
class Session:
    """The validated contents of session.toml plus its markerset."""

    root: str            # absolute path of the session folder
    path: str            # absolute path of session.toml
    id: str
    subject: str
    markerset: MarkerSet | None
    takes: tuple[Take, ...]

    def take(self, take_id: str) -> Take:
        return next(t for t in self.takes if t.id == take_id)


#: how each cleaned sample was obtained (the ``fill`` column of the cleaned markers table); ``swap_repaired``: a
#: measured sample the capture gave another marker's name, put back under its own (SPEC §3.2)
FILL_CODES: dict[str, int] = {"measured": 0, "linear": 1, "pchip": 2, "rigid": 3, "pca": 4, "unfilled": 5,
                              "swap_repaired": 6}
FILL_NAMES: tuple[str, ...] = tuple(FILL_CODES)


# ------------------------------------------------------------------- eye, face and video tracks

@dataclass
class EyeTrack:
    """Per-frame eye tracking of one video (OpenFace), on the video clock.

    Attributes
    ----------
    time_s : (N,) float64 seconds, the video's timestamps as written by OpenFace.
    frame : (N,) int64 video frame numbers as written (1-based in OpenFace).
    success : (N,) bool, OpenFace's tracking success; rows with False are kept, their values are junk.
    confidence : (N,) float64 in [0, 1].
    gaze_left, gaze_right : (N, 3) float64 unit gaze vectors of the subject's own left / right eye, camera
        axes (x right, y down, z forward; looking into the camera is about (0, 0, -1)). NaN where the file's
        vector has zero length.
    blink : (N,) bool, or ``None`` when the file has no AU45 column.
    face_id : the face kept when the file holds several, else ``None``.
    layout : ``"openface2"`` (has ``face_id`` or ``gaze_angle_*``) or ``"openface_legacy"``.
    warnings : one-line notes about the file.
    """

    time_s: np.ndarray
    frame: np.ndarray
    success: np.ndarray
    confidence: np.ndarray
    gaze_left: np.ndarray
    gaze_right: np.ndarray
    blink: np.ndarray | None
    face_id: int | None = None
    layout: str = ""
    warnings: list[str] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return int(self.time_s.shape[0])


@dataclass
class FaceTrack:
    """Per-frame ARKit blendshapes and head/eye rotations of one Live Link Face take.

    Attributes
    ----------
    timecode : (N,) str, the timecodes as written (``HH:MM:SS:FF.fff``).
    tc_frame : (N,) int64 timecode frames since midnight at ``timecode_fps`` (a take that crosses midnight keeps
        counting past 24 h).
    tc_subframe : (N,) float64 fraction of a timecode frame, in [0, 1).
    time_s : (N,) float64 seconds since the first row, from the timecode.
    timecode_fps : frames per second the timecode's FF field counts.
    rate_hz : capture rate in Hz.
    frame_index : (N,) int64 capture frame of every row, 0 at the first row; gaps are dropped frames.
    values : (N, 52) float32 blendshape coefficients, columns in :data:`gazepipe.arkit.ARKIT_NAMES` order.
    head : (N, 3) float64 head yaw, pitch, roll in radians; NaN when head tracking was off or absent.
    eyes : (N, 6) float64 left eye yaw, pitch, roll, right eye yaw, pitch, roll, radians (face's own
        left/right); NaN when absent.
    dropped_frames : capture frames missing between rows.
    blendshape_count : the file's ``BlendShapeCount`` when constant over the valid rows, else ``None``.
    warnings : one-line notes about the file.
    valid : (N,) bool, False on rows written while tracking was lost (their values, head and eyes are NaN);
        ``None``: every row is valid.
    """

    timecode: np.ndarray
    tc_frame: np.ndarray
    tc_subframe: np.ndarray
    time_s: np.ndarray
    timecode_fps: float
    rate_hz: float
    frame_index: np.ndarray
    values: np.ndarray
    head: np.ndarray
    eyes: np.ndarray
    dropped_frames: int = 0
    blendshape_count: int | None = None
    warnings: list[str] = field(default_factory=list)
    names: tuple[str, ...] = ARKIT_NAMES
    head_names: tuple[str, ...] = HEAD_NAMES
    eye_names: tuple[str, ...] = EYE_NAMES
    valid: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def valid_rows(self) -> np.ndarray:
        """(N,) bool: the rows that hold tracking (all of them when ``valid`` is None)."""
        return np.ones(self.n_frames, dtype=bool) if self.valid is None else np.asarray(self.valid, dtype=bool)

    @property
    def timecode_s(self) -> np.ndarray:
        """(N,) float64 seconds since midnight of the first row's day (for matching two takes' rows)."""
        return (self.tc_frame.astype(np.float64) + self.tc_subframe) / float(self.timecode_fps)


@dataclass
class VideoProbe:
    """What a video holds, from its container, without decoding pictures.

    Attributes
    ----------
    n_frames : frames actually found by reading the stream.
    nominal_fps : the container's declared frame rate (can differ from the real one).
    timestamps_s : (n_frames,) float64 presentation time of every frame in seconds, 0 at the stream start.
    width, height : picture size in pixels.
    header_frames : the frame count the container declares (may be an estimate).
    timestamp_source : ``"packets"`` (undecoded packets' timestamps), ``"decoded"`` (grabbed frames) or
        ``"nominal"`` (frame index / nominal fps, when the container has no usable timestamps).
    warnings : one-line notes (frame count mismatch, missing timestamps, …).
    """

    n_frames: int
    nominal_fps: float
    timestamps_s: np.ndarray
    width: int
    height: int
    header_frames: int
    timestamp_source: str = "packets"
    warnings: list[str] = field(default_factory=list)
