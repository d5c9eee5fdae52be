"""The ``build`` stage (SPEC §3.6, §4): the training datasets ``gaze_rnn``, ``gaze_rnn_lod``, ``gaze_map`` and
``face_clean`` from every take's per-take tables.

:func:`build_dataset` is pure: per-take Arrow tables in, per-take dataset tables and the ``_dataset.json``
object out (:mod:`gazepipe.io.dataset_files` writes them). For each dataset:

- take-disjoint splits (:mod:`gazepipe.stages.build.splits`): a take's rows, mirrored copies included, all go to
  its split;
- a mirrored copy of every row (``mirrored`` = True; SPEC §2), after the take's original rows;
- normalisation statistics (mean and population standard deviation per feature element) over the training
  rows only, mirrored training rows included, overall and per pose; at least one training take is required.

A take that cannot give rows (no eyes for gaze_rnn, missing rests for gaze_map, …) is left out and listed
under ``skipped`` in _dataset.json with the reason; the other takes still build. A gaze_map row keeps the
parameters that can be computed: the others are NaN, marked False in its ``known`` mask, and counted per take
(``null_segments`` in ``counts.per_take``, totals in ``counts.null_segments``). Statistics are taken per element
over the values that are not null.

The work splits in two halves: :func:`take_part` makes one take's part from its tables alone (its table, in the
split its key draws, and :class:`TakePart`'s facts: shape, frame rate, why it gives no rows, counts, QC, input
hashes, per-column moments), and :class:`DatasetMerge` merges the parts in (session, take) order (which takes
fit the dataset, the moves that fill an empty split, _dataset.json). :func:`build_dataset` does both in one
process; a run makes the parts in each take's own unit and merges their JSON in the dataset's build, with the
same bytes.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections import Counter
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from gazepipe.errors import GazepipeError, StageError
from gazepipe.model import MarkerSet, Take
from gazepipe.schemas.base import attach_meta, check_table, read_meta, with_element_names
from gazepipe.schemas.dataset_tables import DATASETS, dataset_schema, feature_columns, mask_columns
from gazepipe.schemas.joints import joints_arrays, list_to_numpy
from gazepipe.stages.build.splits import assign_split, check_fractions, rebalance
from gazepipe.stages.build.summary import DatasetSummary, TakeFacts, feature_values, table_hash, take_facts

if TYPE_CHECKING:  # the row builders import scipy and pandas: loaded when a dataset is built, not when planned
    from gazepipe.stages.build.gaze import TakeRows

KINDS = {"gaze_rnn": "gaze_follow", "gaze_rnn_lod": "gaze_follow", "gaze_map": "gaze_shift", "face_clean": "face"}


@dataclass(frozen=True)
class BuildParams:
    """Parameters of :func:`build_dataset`.

    Attributes
    ----------
    train_frac, val_frac : shares of the hashed takes (not pinned by ``split``) that go to train and val; the
        rest goes to test. With few takes a split can be empty; it is reported, not forced.
    split_salt : prefix of the hashed ``<session>/<take>``; change it to draw another deterministic split.
    mirror : add a mirrored copy of every row (Klein 6.2).
    rnn_window, rnn_stride : frames per training sequence and step between sequences for gaze_rnn trainers
        (Klein 6.2: 120 frames = 4 s), written to _dataset.json.
    face_window, face_stride : the same for face_clean (Berson 4.1: 200-frame chunks, overlap 150).
    start_speed_deg_s : gaze_map start-time threshold on parent-relative angular speed (Pejsa: 18°/s).
    start_filter_hz : −3 dB frequency (Hz) of the zero-phase Gaussian low-pass applied to the parent-relative
        rotations before the start-time speeds (``None`` = raw central differences, Pejsa's rule on clean
        data). Marker noise of 0.5 mm gives parent-relative orientations ~1° of noise, so raw central
        differences at 30 Hz carry ~22°/s of speed noise on average (up to ~70°/s) in the sample session's
        rests: above 18°/s, so segments that never move that fast "start" within the first frames. At 2 Hz the
        noise is ~4°/s on average and stays below 17°/s (p99.9 13°/s), while the noise-free speed peaks of
        the ~0.5 s gaze-shift movements drop by ~12 % (9–27 %). On the sample session this leaves 3 of 90
        segment start times off by more than 2 frames, all segments whose noise-free peak speed is within
        2°/s of 18°/s, which noise of a few °/s cannot resolve (raw: 7 of 90, among them the chest starting
        6–11 frames early on every 72° shift; 1.5 Hz: 4, the chest never found; 2.5 Hz: 9; 3 Hz: 13).
    start_min_s : the low-passed speed must stay above the threshold at least this long (s) for a start
        (1/15 s = 2 frames at 30 Hz: a single-frame noise excursion does not count).
    overshoot_window_s : gaze_map overshoot confirmation window each side (s).
    max_bridge_s : gaze_map: runs of crop frames without a rotation up to this long (s) are bridged in rotation
        space for the start times and the overshoot; after a longer run an event not found before it is null in
        the take's row (its ``known`` entry False; SPEC §3.6).
    head_segment : the head segment for gaze_map; ``None`` = the one named ``head``, else the last.

    Each field's metadata gives its allowed values (:func:`gazepipe.pipeline.registry.value_problem`) and its one
    line of help (``help``: what ``gazepipe params`` prints).
    """

    train_frac: float = field(default=0.8, metadata={
        "min": 0, "max": 1, "help": "share of the takes in the training split"})
    val_frac: float = field(default=0.1, metadata={
        "min": 0, "max": 1, "help": "share of the takes in the validation split (the rest is the test "
            "split)"})
    split_salt: str = field(default="", metadata={
        "help": "change it to draw another (still reproducible) assignment of takes to splits"})
    mirror: bool = field(default=True, metadata={"help": "add a left-right mirrored copy of every row"})
    rnn_window: int = field(default=120, metadata={
        "min": 1, "help": "frames per training sequence of the gaze_rnn datasets"})
    rnn_stride: int = field(default=30, metadata={
        "min": 1, "help": "frames between the starts of two gaze_rnn sequences"})
    face_window: int = field(default=200, metadata={
        "min": 1, "help": "frames per training sequence of the face_clean dataset"})
    face_stride: int = field(default=50, metadata={
        "min": 1, "help": "frames between the starts of two face_clean sequences"})
    start_speed_deg_s: float = field(default=18.0, metadata={
        "gt": 0, "help": "gaze_map: a joint starts moving when its speed passes this, in degrees/s"})
    start_filter_hz: float | None = field(default=2.0, metadata={
        "gt": 0, "help": "gaze_map: low-pass, in Hz, of the rotations before measuring that speed"})
    start_min_s: float = field(default=1.0 / 15.0, metadata={
        "min": 0, "help": "gaze_map: the speed must stay above the threshold this long, in s"})
    overshoot_window_s: float = field(default=0.1, metadata={
        "min": 0, "help": "gaze_map: window, in s, each side of a peak that confirms an overshoot"})
    max_bridge_s: float = field(default=0.5, metadata={
        "min": 0, "help": "gaze_map: missing rotations up to this long, in s, are bridged; longer ones "
            "leave the event unknown"})
    head_segment: str | None = field(default=None, metadata={
        "help": "gaze_map: name of the head segment (default: the one named head, else the last)"})

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def problems(self) -> list[str]:
        """What is wrong between parameters, one line each (each one's own range is in its field's
        metadata)."""
        if self.train_frac + self.val_frac > 1.0:
            return [f"parameters build.train_frac + build.val_frac must add up to at most 1, "
                    f"got {self.train_frac:g} + {self.val_frac:g}"]
        return []


@dataclass
class TakeTables:
    """One take's inputs to the build.

    Attributes
    ----------
    session, subject : the session id and subject.
    take : the take's entry in session.toml (kind, pose, split pin, requested yaw/pitch).
    joints : the ``joints`` table (gaze_follow and gaze_shift takes).
    eyes : the ``eyes`` table (gaze_follow takes with eye tracking).
    face : the ``face`` table (face takes).
    markerset : the session's markerset (``lod_segments`` for gaze_rnn_lod).
    meta : extra facts: ``rests`` (list of [start, stop) frames of the uncropped take, from the clean stage;
        needed by gaze_map) and ``rate_hz`` (default: the joints table's).
    hashes : content hashes of the inputs by table name; computed from the tables when absent.
    loader : when set, called when the build reaches this take; returns the fields to fill in (``joints``,
        ``eyes``, ``face`` tables, ``meta`` entries), so only one take's tables are in memory at a time.
    """

    session: str
    subject: str
    take: Take
    joints: pa.Table | None = None
    eyes: pa.Table | None = None
    face: pa.Table | None = None
    markerset: MarkerSet | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    hashes: dict[str, str] = field(default_factory=dict)
    loader: Callable[[], dict[str, Any]] | None = None

    @property
    def key(self) -> tuple[str, str]:
        """The take's identity: (session, take id); one subject may have the same take ids in several sessions."""
        return (self.session, self.take.id)

    def loaded(self) -> TakeTables:
        """This take with its tables loaded (itself when there is no ``loader``)."""
        if self.loader is None:
            return self
        got = dict(self.loader())
        meta = {**self.meta, **got.pop("meta", {})}
        return dataclasses.replace(self, loader=None, meta=meta, **got)


#: receives each take's dataset table as soon as it is built: ``sink((session, take), table)``; a take moved to
#: another split afterwards is emitted again
TakeSink = Callable[[tuple[str, str], pa.Table], None]


@dataclass
class BuiltDataset:
    """A built dataset: per-take tables keyed by (session, take) (empty when they went to a sink), the
    ``_dataset.json`` object, the schema."""

    name: str
    tables: dict[tuple[str, str], pa.Table]
    info: dict[str, Any]
    schema: pa.Schema


def _where(name: str) -> str:
    return f"datasets/{name}"


# --------------------------------------------------------------------------------------------- per take

@dataclass
class Shape:
    """What every take of a dataset must share: its segments (face_clean: its blendshape channels), the names
    of the feature elements and the sizes of the schema."""

    segments: list[str]
    names: dict[str, list[str]]
    sizes: dict[str, int]


@dataclass
class _Progress:
    """How far a take's rows got before a problem: its shape is known, its frame rate counted."""

    shape: Shape | None = None
    fps: float | None = None


def _rnn(tt: TakeTables, lod: bool, got: _Progress) -> TakeRows:
    from gazepipe.stages.build.gaze import align_eyes, rnn_feature_names, rnn_rows

    if tt.joints is None:
        raise StageError(None, "no joints table", take=tt.take.id)
    j = joints_arrays(tt.joints)
    segs = list(j["segments"])
    if lod:
        want = list(tt.markerset.lod_segments) if tt.markerset else []
        if not want:
            raise StageError(None, "the markerset has no [lod] segments", take=tt.take.id)
        missing = [s for s in want if s not in segs]
        if missing:
            raise StageError(None, f"[lod] segments {missing} are not in the joints table", take=tt.take.id)
    else:
        want = segs
    names = rnn_feature_names(want, with_eyes=not lod)
    got.shape = Shape(want, names, {"n_in": len(names["x"]), "n_out": len(names["y"])})
    eyes = None
    if not lod:
        if tt.eyes is None:
            raise StageError(None, "no eyes table (eye tracking is needed for gaze_rnn)", take=tt.take.id)
        e = tt.eyes
        eyes = align_eyes(np.asarray(j["frame"]), e.column("frame").to_numpy(), e.column("valid").to_numpy(),
                          list_to_numpy(e.column("eye_dir_char"), 3).astype(np.float64))
    got.fps = float(tt.meta.get("rate_hz", j["meta"].get("rate_hz")))
    return rnn_rows(j, [segs.index(s) for s in want], eyes)


def _gaze_map(tt: TakeTables, params: BuildParams, got: _Progress) -> TakeRows:
    from gazepipe.stages.build.gaze import gaze_map_names, gaze_map_row

    take = tt.take
    if tt.joints is None:
        raise StageError(None, "no joints table", take=take.id)
    if take.target_yaw_deg is None or take.target_pitch_deg is None:
        raise StageError(None, "no requested target yaw/pitch", take=take.id)
    if "rests" not in tt.meta:
        raise StageError(None, "no rest periods given", take=take.id)
    j = joints_arrays(tt.joints)
    segs = list(j["segments"])
    got.shape = Shape(segs, gaze_map_names(segs), {"n_segments": len(segs)})
    p = params
    head_name = p.head_segment or ("head" if "head" in segs else segs[-1])
    if head_name not in segs:
        raise StageError(None, f"head segment {head_name!r} is not in the joints table", take=take.id)
    rate = float(tt.meta.get("rate_hz", j["meta"].get("rate_hz")))
    got.fps = rate
    return gaze_map_row(j, tt.meta["rests"], rate, float(take.target_yaw_deg), float(take.target_pitch_deg),
                        head=segs.index(head_name), start_speed_deg_s=p.start_speed_deg_s,
                        start_filter_hz=p.start_filter_hz, start_min_s=p.start_min_s,
                        overshoot_window_s=p.overshoot_window_s, max_bridge_s=p.max_bridge_s, take=take.id)


def _face(tt: TakeTables, got: _Progress) -> TakeRows:
    from gazepipe.stages.build.face import face_columns, face_rows

    if tt.face is None:
        raise StageError(None, "no face table", take=tt.take.id)
    meta = read_meta(tt.face)
    k = int(meta.get("k", 1))
    channels = list(meta.get("names", []))
    if not channels:
        raise StageError(None, "the face table's metadata has no channel names", take=tt.take.id)
    got.shape = Shape(channels, {c: [f"{c}.{n}" for n in channels] for c in face_columns(k)},
                      {"k": k, "n_channels": len(channels)})
    if "rate_hz" in meta:
        got.fps = float(meta["rate_hz"])
    return face_rows(tt.face, k)


def _rows(name: str, tt: TakeTables, params: BuildParams, got: _Progress) -> TakeRows:
    if name == "gaze_map":
        return _gaze_map(tt, params, got)
    if name == "face_clean":
        return _face(tt, got)
    return _rnn(tt, name == "gaze_rnn_lod", got)


def _differs(name: str, shape: Shape, ref: Shape) -> str:
    """Why a take's shape does not fit the dataset's (that of its first take), or ""."""
    if shape.segments == ref.segments and shape.sizes == ref.sizes:
        return ""
    if name == "face_clean":
        return f"face channels or derivative order (k={shape.sizes['k']}) differ from the dataset's"
    return f"segments {shape.segments} differ from the dataset's {ref.segments}"


def _mirror(name: str, rows: TakeRows, segments: list[str]) -> dict[str, np.ndarray]:
    from gazepipe.stages.build.face import mirror_face_rows
    from gazepipe.stages.build.gaze import mirror_gaze_map, mirror_rnn, segment_permutation

    if name == "face_clean":
        return mirror_face_rows(rows.features, segments)
    perm = segment_permutation(segments)
    if name == "gaze_map":
        return mirror_gaze_map(rows.features, perm)
    return mirror_rnn(rows.features, len(segments), name == "gaze_rnn", perm)


# -------------------------------------------------------------------------------------------- assembly

def _column(values: np.ndarray, ftype: pa.DataType) -> pa.Array:
    if pa.types.is_fixed_size_list(ftype):
        vt = ftype.value_type
        flat = np.ascontiguousarray(values, dtype=bool if vt == pa.bool_() else np.float32).reshape(-1)
        return pa.FixedSizeListArray.from_arrays(pa.array(flat, vt), ftype.list_size)
    return pa.array(np.ascontiguousarray(values).reshape(-1), ftype)


def _take_table(tt: TakeTables, split: str, rows: TakeRows, mirrored: dict[str, np.ndarray] | None,
                schema: pa.Schema, sizes: dict[str, int]) -> pa.Table:
    parts = [rows.features] + ([mirrored] if mirrored is not None else [])
    n = rows.n_rows * len(parts)
    ident: dict[str, Any] = {
        "subject": tt.subject, "session": tt.session, "take": tt.take.id, "pose": tt.take.pose, "split": split,
    }
    cols: list[pa.Array] = []
    for f in schema:
        if f.name in ident:
            cols.append(pa.array([ident[f.name]] * n, pa.string()))
        elif f.name == "mirrored":
            cols.append(pa.array(np.repeat(np.arange(len(parts)) == 1, rows.n_rows)))
        elif f.name in ("segment", "frame", "time_s"):
            cols.append(pa.array(np.tile(getattr(rows, f.name), len(parts)), f.type))
        else:
            cols.append(_column(np.concatenate([p[f.name] for p in parts]), f.type))
    table = pa.Table.from_arrays(cols, schema=schema)
    table = attach_meta(table, {"dataset": schema.metadata[b"gazepipe.table"].decode(), "sizes": sizes})
    check_table(table, schema, path=f"take {tt.take.id}")
    return table


def with_split(table: pa.Table, split: str, schema: pa.Schema | None = None) -> pa.Table:
    """A take's dataset table with every row in ``split`` (a take the dataset moved to fill an empty split):
    the table :func:`take_part` makes with that split. ``schema``: the dataset's, for a table read back from
    Parquet (whose list items come back named ``element``, not ``item``)."""
    if schema is not None:
        table = table.cast(schema.with_metadata(table.schema.metadata))
    i = table.schema.get_field_index("split")
    return table.set_column(i, table.schema.field(i), pa.array([split] * table.num_rows, pa.string()))


def _schema(name: str, shape: Shape) -> pa.Schema:
    return with_element_names(dataset_schema(name, shape.sizes), shape.names)


@dataclass
class TakePart:
    """One take's share of a dataset, made from the take's tables alone (:func:`take_part`; in a run, on the
    worker that ran the take), and all the dataset's build needs of it (:class:`DatasetMerge`) besides its table.

    Attributes
    ----------
    session, take, pose : the take's identity and pose.
    pinned : the split session.toml pins it to, or ``None``.
    shape : its segments, element names and sizes (``None``: it gave up before they were known).
    fps : its frame rate, when it got as far as counting it.
    problem : why it gives no rows ("" when it gives some).
    split : the split its own key draws (:func:`~gazepipe.stages.build.splits.assign_split`); the dataset may
        move it to fill an empty split.
    fatal : a problem that fails the whole dataset if the take is kept (its segments cannot be mirrored).
    facts : what the dataset's summary needs of its table (:class:`~gazepipe.stages.build.summary.TakeFacts`).
    table : its dataset table (rows, mirrored copies, identifiers, ``split``); not part of :meth:`to_json`.
    """

    session: str
    take: str
    pose: str
    pinned: str | None
    shape: Shape | None = None
    fps: float | None = None
    problem: str = ""
    split: str = ""
    fatal: str = ""
    facts: TakeFacts | None = None
    table: pa.Table | None = None

    @property
    def key(self) -> tuple[str, str]:
        return (self.session, self.take)

    def to_json(self) -> dict[str, Any]:
        """Everything but the table, as JSON values that come back exactly (:meth:`from_json`)."""
        out = {k: v for k, v in dataclasses.asdict(dataclasses.replace(self, table=None, facts=None)).items()
               if k not in ("table", "facts")}
        out["facts"] = self.facts.to_json() if self.facts is not None else None
        return out

    @staticmethod
    def from_json(obj: dict[str, Any]) -> TakePart:
        shape = obj.get("shape")
        facts = obj.get("facts")
        return TakePart(session=obj["session"], take=obj["take"], pose=obj["pose"], pinned=obj["pinned"],
                        shape=Shape(**shape) if shape is not None else None, fps=obj["fps"],
                        problem=obj["problem"], split=obj["split"], fatal=obj["fatal"],
                        facts=TakeFacts.from_json(facts) if facts is not None else None)


def take_part(name: str, tt: TakeTables, params: BuildParams | None = None, split: str | None = None,
              known: Collection[str] = ()) -> TakePart:
    """Take ``tt``'s share of dataset ``name``: its rows with their mirrored copies as a table, in the split its
    key draws (or ``split``), and the facts the dataset's statistics, counts and checks need.

    A take with a ``loader`` is loaded here. A take that cannot give rows has ``problem`` set and no table;
    whether it fits the dataset (its segments those of the dataset's first take) is the dataset's to decide
    (:meth:`DatasetMerge.add`). ``known``: tables whose input hash the caller gives (not computed here).
    """
    params = params or BuildParams()
    part = TakePart(session=tt.session, take=tt.take.id, pose=tt.take.pose, pinned=tt.take.split)
    got = _Progress()
    try:
        t = tt.loaded()
        rows = _rows(name, t, params, got)
    except GazepipeError as exc:
        part.shape, part.fps, part.problem = got.shape, got.fps, exc.problem
        return part
    part.shape, part.fps = got.shape, got.fps
    if rows.n_rows == 0:
        part.problem = "no usable frames"
        return part
    assert got.shape is not None
    part.split = split or assign_split(f"{t.session}/{t.take.id}", t.take.split, params.train_frac,
                                       params.val_frac, params.split_salt)
    mirrored = None
    if params.mirror:
        try:
            mirrored = _mirror(name, rows, got.shape.segments)
        except StageError as exc:
            part.fatal = f"mirroring: {exc.problem}"
            return part
    schema = _schema(name, got.shape)
    part.table = _take_table(t, part.split, rows, mirrored, schema, got.shape.sizes)
    part.facts = take_facts(part.table, feature_columns(schema), rows.qc, _input_hashes(t, name, known),
                            segments=name in ("gaze_rnn", "gaze_rnn_lod"))
    return part


# ---------------------------------------------------------------------------------------------- merge

class DatasetMerge:
    """The dataset's half of a build: the takes' parts (:func:`take_part`) in (session, take) order in, which
    of them the dataset keeps, the takes it moves so that no split is empty, and ``_dataset.json``.

    Call :meth:`add` for each take in order, then :meth:`rebalance` once, then :meth:`info`. Only the parts'
    facts are used (no table), so the merge holds a few numbers per take whatever the dataset's size.
    """

    def __init__(self, name: str, params: BuildParams) -> None:
        self.name, self.params = name, params
        self.ref: Shape | None = None         # the dataset's shape: its first take's that got so far
        self.fps: set[float] = set()
        self.skipped: list[dict[str, str]] = []
        self.schema: pa.Schema | None = None
        self.summary: DatasetSummary | None = None
        self.split: dict[tuple[str, str], str] = {}     # kept take → its split

    def add(self, part: TakePart) -> bool:
        """Count take ``part`` in, or list it under ``skipped``; whether it is kept. Raises
        :class:`StageError` for a kept take whose rows cannot be mirrored."""
        def skip(reason: str) -> bool:
            self.skipped.append({"session": part.session, "take": part.take, "reason": reason})
            return False

        if part.shape is None:
            return skip(part.problem)
        if self.ref is None:
            self.ref = part.shape
        elif why := _differs(self.name, part.shape, self.ref):
            return skip(why)
        if part.fps is not None:
            self.fps.add(part.fps)
        if part.problem:
            return skip(part.problem)
        if self.summary is None:
            self.schema = _schema(self.name, self.ref)
            window = {"gaze_rnn": self.params.rnn_window, "gaze_rnn_lod": self.params.rnn_window,
                      "face_clean": self.params.face_window}.get(self.name)
            self.summary = DatasetSummary(self.name, feature_columns(self.schema), window,
                                          masks=mask_columns(self.schema))
        if part.fatal:
            raise StageError(_where(self.name), part.fatal)
        assert part.facts is not None
        self.summary.add_take(f"{part.session}/{part.take}", part.pose, part.split, part.facts,
                              pinned=part.pinned is not None)
        self.split[part.key] = part.split
        return True

    def rebalance(self) -> list[tuple[str, str, str, str]]:
        """Move takes so that no split is empty when a take can fill it (SPEC §3.6): the moves, as
        ``(take, from, to, why)`` with take ``<session>/<take>``; their tables must be made again in their new
        split (:func:`with_split`). Raises :class:`StageError` when no take was kept or none is in train."""
        if self.summary is None:
            reasons = "; ".join(f"{s['take']}: {s['reason']}" for s in self.skipped[:3])
            raise StageError(_where(self.name), f"no take gave rows ({reasons})")
        p, summary = self.params, self.summary
        moves = rebalance([(k, v.split, v.pinned) for k, v in summary.takes.items()], p.train_frac, p.val_frac,
                          p.split_salt)
        keys = {f"{s}/{t}": (s, t) for s, t in self.split}
        for tid, _, new, why in moves:
            summary.move(tid, new, why)
            self.split[keys[tid]] = new
        if not summary.train_takes:
            raise StageError(_where(self.name), f"no training take among {summary.n_takes}: every take is pinned "
                                                "to another split; statistics need one (pin a take with split = "
                                                "\"train\")")
        return moves

    def info(self) -> dict[str, Any]:
        """The _dataset.json object."""
        assert self.summary is not None and self.ref is not None
        p = self.params
        stride = {"gaze_rnn": p.rnn_stride, "gaze_rnn_lod": p.rnn_stride, "face_clean": p.face_stride}.get(self.name)
        return self.summary.info(params=p.to_dict(), names=self.ref.names, sizes=self.ref.sizes,
                                 fps=sorted(self.fps), stride=stride, mirror=p.mirror, salt=p.split_salt,
                                 train_frac=p.train_frac, val_frac=p.val_frac, skipped=self.skipped)


def check_dataset(name: str, params: BuildParams) -> None:
    """Raise for an unknown dataset or split fractions that do not add up."""
    if name not in DATASETS:
        raise StageError(_where(name), f"unknown dataset (known: {', '.join(DATASETS)})")
    check_fractions(params.train_frac, params.val_frac)


def build_dataset(name: str, takes: list[TakeTables], params: BuildParams | None = None,
                  sink: TakeSink | None = None) -> BuiltDataset:
    """Build dataset ``name`` (one of :data:`gazepipe.schemas.dataset_tables.DATASETS`) from the takes' tables: each
    take's part (:func:`take_part`), merged (:class:`DatasetMerge`), as a run does on its workers and then in
    the dataset's build.

    Takes are processed one at a time in (session, take) order: a take with a ``loader`` is loaded when
    its turn comes, its table goes to ``sink(key, table)`` as soon as it is built (and is then dropped), and
    _dataset.json is summarised as it goes, so memory holds one take whatever the dataset's size. Without a
    ``sink`` the tables are kept in :attr:`BuiltDataset.tables`.

    Takes of other kinds are ignored; a take that cannot give rows is skipped and listed in
    ``info["skipped"]``. Raises :class:`StageError` for an unknown dataset, two takes with the same
    (session, take id), no usable take, or no training take (statistics need one); the sink may already
    have received tables then.
    """
    params = params or BuildParams()
    check_dataset(name, params)
    kind = KINDS[name]
    mine = sorted((t for t in takes if t.take.kind == kind), key=lambda t: t.key)
    if not mine:
        raise StageError(_where(name), f"no {kind} takes to build from")
    twice = sorted(k for k, c in Counter(t.key for t in mine).items() if c > 1)
    if twice:
        raise StageError(_where(name), f"take {twice[0][1]!r} of session {twice[0][0]!r} is given twice")

    merge = DatasetMerge(name, params)
    kept: dict[tuple[str, str], pa.Table] = {}
    emit = sink or kept.__setitem__
    by_id: dict[str, TakeTables] = {}
    for ref in mine:
        part = take_part(name, ref, params)
        if merge.add(part):
            assert part.table is not None
            emit(part.key, part.table)
            by_id[f"{part.session}/{part.take}"] = ref
        del part
    # no split left empty when a take can fill it (SPEC §3.6): the few takes that move are built again
    for tid, _, new, _ in merge.rebalance():
        part = take_part(name, by_id[tid], params, split=new)
        assert part.table is not None
        emit(part.key, part.table)
    assert merge.schema is not None
    return BuiltDataset(name=name, tables=kept, info=merge.info(), schema=merge.schema)


def _input_hashes(t: TakeTables, name: str, known: Collection[str] = ()) -> dict[str, str]:
    """The take's input hashes for _dataset.json: those given, plus a content hash of every table neither given
    nor ``known`` (its hash given later by the caller)."""
    hashes = dict(t.hashes)
    for tname in ("joints", "eyes", "face"):
        tab = getattr(t, tname)
        if tab is not None and tname not in hashes and tname not in known:
            hashes[tname] = table_hash(tab)
    if "rests" in t.meta and name == "gaze_map":
        hashes.setdefault("rests", hashlib.sha256(repr(t.meta["rests"]).encode()).hexdigest())
    return hashes


__all__ = ["KINDS", "BuildParams", "BuiltDataset", "DatasetMerge", "Shape", "TakePart", "TakeSink", "TakeTables",
           "build_dataset", "feature_values", "table_hash", "take_part", "with_split"]
