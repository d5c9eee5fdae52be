"""Gather what the report needs from an output folder: unit records, per-take tables, datasets.

Reading goes through :mod:`gazepipe.pipeline.state` (records), :mod:`gazepipe.io.parquet` /
:mod:`gazepipe.io.dataset_files` (tables, schema-checked) and :mod:`gazepipe.schemas`. A table that cannot be read is
not fatal: its error is kept and the checks that need it report ``error``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gazepipe.errors import ConfigError, GazepipeError
from gazepipe.io.parquet import read_schema, read_table
from gazepipe.model import Markers
from gazepipe.pipeline.state import OutLayout, all_records, read_json
from gazepipe.report.checks import Thresholds
from gazepipe.report.checks_datasets import FileFacts, StatsSample, schema_hash
from gazepipe.schemas import expected_schema
from gazepipe.schemas.base import check_table
from gazepipe.schemas.joints import list_to_numpy
from gazepipe.schemas.markers import check_markers_meta, fill_codes, table_to_markers
from gazepipe.stages.clean.qc import CleanQC
from gazepipe.stages.eyes.qc import EyesQC
from gazepipe.stages.face.qc import FaceQC
from gazepipe.stages.frames.qc import FramesQC
from gazepipe.stages.ingest_qc import IngestQC
from gazepipe.stages.qc import QCRecord, QCRecordError
from gazepipe.stages.sync.qc import SyncQC

#: the QC type of each take stage's unit record
QC_TYPES: dict[str, type[QCRecord]] = {cls.stage: cls for cls in (IngestQC, CleanQC, FramesQC, SyncQC, EyesQC,
                                                                   FaceQC)}

Q = TypeVar("Q", bound=QCRecord)


def open_output(out: str | Path) -> OutLayout:
    """The layout of ``out``; :class:`ConfigError` (exit 2) when it is not a gazepipe output folder."""
    layout = OutLayout(Path(out))
    if not layout.root.is_dir():
        raise ConfigError(out, "not a folder")
    if not layout.state.is_dir():
        raise ConfigError(out, "not a gazepipe output folder (no .gazepipe/ inside; run `gazepipe run` first)")
    return layout


# ------------------------------------------------------------------------------------------------- takes

@dataclass
class TakeEntry:
    """One take known to the output folder: its settings and its unit records by stage.

    The records are the engine's (status, error, warnings, components); the QC a stage recorded in one is read
    as that stage's QC dataclass (:meth:`qc`), converted once.
    """

    session: str
    take: str
    kind: str = "?"
    pose: str = "?"
    has_video: bool = False
    has_eyes: bool = False
    records: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: stage → its QC dataclass, or why the record's QC does not parse (one line naming the record file and the
    #: key; filled as :meth:`qc` is asked)
    _qc: dict[str, QCRecord | str] = field(default_factory=dict, repr=False, compare=False)

    @property
    def key(self) -> str:
        return f"{self.session}/{self.take}"

    def ran(self, stage: str) -> bool:
        """Whether the stage's unit has a record that says it ran ok."""
        rec = self.records.get(stage)
        return rec is not None and rec.get("status") == "ok"

    def record_path(self, stage: str) -> str:
        """The stage's unit record file, relative to the output folder and with ``/`` (the report names no
        absolute path, and reads the same on every system)."""
        return OutLayout(Path()).record(self.session, self.take, stage).as_posix()

    def _parsed(self, cls: type[QCRecord]) -> QCRecord | str | None:
        if not self.ran(cls.stage):
            return None
        if cls.stage not in self._qc:
            rec, path = self.records[cls.stage], self.record_path(cls.stage)
            try:
                if "qc" not in rec:
                    raise QCRecordError(path, "missing from the unit record", key="qc")
                self._qc[cls.stage] = cls.from_record(rec["qc"], path)
            except QCRecordError as exc:
                self._qc[cls.stage] = exc.one_line()
        return self._qc[cls.stage]

    def qc(self, cls: type[Q]) -> Q | None:
        """The QC the stage of ``cls`` (:data:`QC_TYPES`) recorded, as ``cls``; ``None`` when its unit has no
        record, did not run ok, or its QC does not parse (:meth:`qc_error` says why)."""
        got = self._parsed(cls)
        return got if isinstance(got, cls) else None

    def qc_error(self, cls: type[QCRecord]) -> str | None:
        """Why the stage's QC record does not parse as ``cls`` (one line naming the record file and the key), or
        ``None``."""
        got = self._parsed(cls)
        return got if isinstance(got, str) else None

    def params(self, stage: str) -> dict[str, Any]:
        return ((self.records.get(stage) or {}).get("components") or {}).get("params") or {}


def load_sessions(layout: OutLayout) -> tuple[dict[str, Any], list[str]]:
    """The sessions the output folder remembers (id → :class:`~gazepipe.model.Session`) and the problems of
    those that cannot be read now."""
    from gazepipe.io.session_toml import load_session

    sessions, problems = {}, []
    for sid, path in sorted((read_json(layout.sessions) or {}).items()):
        try:
            sessions[sid] = load_session(path)
        except GazepipeError as exc:
            problems.append(f"session {sid}: {exc.one_line()}")
    return sessions, problems


def unit_states(layout: OutLayout) -> dict[str, list[dict[str, Any]]] | None:
    """Per take (``session/take``), its units' states now (:func:`gazepipe.dag.collect_status`:
    ok | failed | stale | pending); ``None`` when they cannot be worked out."""
    from gazepipe.dag import collect_status

    try:
        rows = collect_status(layout.root)
    except GazepipeError:
        return None
    out: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        out.setdefault(f"{r['session']}/{r['take']}", []).append(r)
    return out


def take_entries(layout: OutLayout, sessions: dict[str, Any]) -> list[TakeEntry]:
    """Every take with a unit record, plus the takes of the remembered sessions that never ran; sorted."""
    entries: dict[tuple[str, str], TakeEntry] = {}
    for rec in all_records(layout):
        key = (str(rec.get("session")), str(rec.get("take")))
        e = entries.setdefault(key, TakeEntry(*key))
        e.records[str(rec.get("stage"))] = rec
        cfg = (rec.get("components") or {}).get("take") or {}
        if cfg:
            e.kind, e.pose = str(cfg.get("kind", e.kind)), str(cfg.get("pose", e.pose))
            e.has_video, e.has_eyes = bool(cfg.get("video")), bool(cfg.get("eyes"))
    for sid, s in sessions.items():
        for t in s.takes:
            e = entries.setdefault((sid, t.id), TakeEntry(sid, t.id))
            e.kind, e.pose, e.has_video, e.has_eyes = t.kind, t.pose, bool(t.video), bool(t.eyes)
    return [entries[k] for k in sorted(entries)]


def take_entry(layout: OutLayout, session: str, take: Any) -> TakeEntry:
    """One take's entry as :func:`take_entries` makes it: its unit records and its settings (``take``, the
    take's entry in session.toml)."""
    e = TakeEntry(session, take.id)
    folder = layout.record(session, take.id, "x").parent
    for p in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        rec = read_json(p)
        if isinstance(rec, dict):
            e.records[str(rec.get("stage"))] = rec
    e.kind, e.pose, e.has_video, e.has_eyes = take.kind, take.pose, bool(take.video), bool(take.eyes)
    return e


@dataclass
class TakeTables:
    """Arrays of one take's tables that the checks and plots use (``None`` where a table is absent)."""

    raw: Markers | None = None
    fill: np.ndarray | None = None          # (N, M) fill codes of the kept frames
    fill_labels: list[str] = field(default_factory=list)
    kept_frames: np.ndarray | None = None   # (N,) rows of the uncropped take
    rest_speed: np.ndarray | None = None    # (T,) mm/s, the speed the clean stage found the rests on
    #: frame numbers of the joints rows that can give dataset rows (a character frame, every segment's rotation
    #: and, for a gaze_follow take, the target direction); ``None`` without a joints table
    row_frames: np.ndarray | None = None
    eyes: dict[str, np.ndarray] | None = None
    sync: dict[str, np.ndarray] | None = None
    errors: dict[str, str] = field(default_factory=dict)


def _read(layout: OutLayout, e: TakeEntry, name: str, tables: TakeTables) -> pa.Table | None:
    path = layout.table(e.session, e.take, name)
    if not path.exists():
        return None
    try:
        table = read_table(path)
        schema = expected_schema(name, table)
        if schema is not None:
            check_table(table, schema, path=str(path))
        return table
    except GazepipeError as exc:
        tables.errors[name] = exc.one_line()
    except Exception as exc:  # a table that decodes into nonsense is an error of that table, not of the report
        tables.errors[name] = f"{path}: {type(exc).__name__}: {exc}"
    return None


def _probe(layout: OutLayout, e: TakeEntry, name: str, tables: TakeTables) -> None:
    """Check that a table's footer reads and its schema is the expected one, without decoding its rows."""
    path = layout.table(e.session, e.take, name)
    if not path.exists():
        return
    try:
        empty = read_schema(path).empty_table()
        schema = expected_schema(name, empty)
        if schema is not None:
            check_table(empty, schema, path=str(path))
    except GazepipeError as exc:
        tables.errors[name] = exc.one_line()
    except Exception as exc:
        tables.errors[name] = f"{path}: {type(exc).__name__}: {exc}"


#: the take tables the plots draw from (the raw markers: gaps, speed, clapper; the eyes: confidence)
PLOT_TABLES = ("markers_raw", "rest_speed", "eyes")


def has_plot_tables(layout: OutLayout, e: TakeEntry) -> bool:
    """Whether the take has a table the plots draw from (a face take, or one whose ingest failed, has none)."""
    return any(layout.table(e.session, e.take, name).exists() for name in PLOT_TABLES)


def _row_frames(layout: OutLayout, e: TakeEntry, tables: TakeTables) -> np.ndarray | None:
    """Frame numbers of the take's joints rows that can give dataset rows (``None``: no readable joints
    table)."""
    path = layout.table(e.session, e.take, "joints")
    if not path.exists():
        return None
    try:
        t = read_table(path, columns=["frame", "valid", "target_dir"])
        ok = t.column("valid").to_numpy(zero_copy_only=False).astype(bool)
        if e.kind == "gaze_follow":
            ok &= np.isfinite(list_to_numpy(t.column("target_dir"), 3)).all(axis=1)
        return t.column("frame").to_numpy().astype(np.int64)[ok]
    except GazepipeError as exc:
        tables.errors["joints"] = exc.one_line()
    except Exception as exc:
        tables.errors["joints"] = f"{path}: {type(exc).__name__}: {exc}"
    return None


def load_take_tables(layout: OutLayout, e: TakeEntry, *, arrays: bool = True,
                     only: tuple[str, ...] | None = None) -> TakeTables:
    """Read the take's markers_raw, markers, eyes and sync tables (whichever exist; with ``only``, just those:
    :data:`PLOT_TABLES` for the plots).

    With ``arrays=False`` (what the checks need) only the cleaned markers are decoded, for their fill codes; the
    other tables are probed (footer and schema) so an unreadable one is still reported.
    """
    out = TakeTables()
    if not arrays:
        for name in ("markers_raw", "eyes", "sync", "markers"):
            _probe(layout, e, name, out)
        out.row_frames = _row_frames(layout, e, out)
        path = layout.table(e.session, e.take, "markers")
        if path.exists() and "markers" not in out.errors:
            try:  # the fill codes, with the rows' layout checked against the metadata; not the coordinates
                fills = read_table(path, columns=["marker", "frame", "fill"])
                check_markers_meta(fills, str(path))
                out.fill_labels, out.kept_frames, out.fill = fill_codes(fills)
            except GazepipeError as exc:
                out.errors["markers"] = exc.one_line()
            except Exception as exc:
                out.errors["markers"] = f"{path}: {type(exc).__name__}: {exc}"
        return out
    wanted = set(only) if only is not None else {"markers_raw", "markers", "rest_speed", "eyes", "sync"}
    t: pa.Table | None = _read(layout, e, "markers_raw", out) if "markers_raw" in wanted else None
    if t is not None:
        out.raw = table_to_markers(t)[0]
    t = _read(layout, e, "markers", out) if "markers" in wanted else None
    if t is not None:
        m, frames, fill, _ = table_to_markers(t)
        out.fill, out.fill_labels, out.kept_frames = fill, list(m.labels), frames
    t = _read(layout, e, "rest_speed", out) if "rest_speed" in wanted else None
    if t is not None:
        out.rest_speed = t.column("speed_mm_s").to_numpy(zero_copy_only=False).astype(np.float64)
    t = _read(layout, e, "eyes", out) if "eyes" in wanted else None
    if t is not None:
        out.eyes = {"time_s": t.column("time_s").to_numpy(), "frame": t.column("frame").to_numpy(),
                    "valid": t.column("valid").to_numpy(zero_copy_only=False),
                    "filled": t.column("filled").to_numpy(zero_copy_only=False),
                    "confidence": t.column("confidence").to_numpy(zero_copy_only=False).astype(np.float64)}
    t = _read(layout, e, "sync", out) if "sync" in wanted else None
    if t is not None:
        out.sync = {c: t.column(c).to_numpy() for c in t.column_names}
    return out


# ---------------------------------------------------------------------------------------------- datasets

@dataclass
class DatasetData:
    """What the dataset checks and plots need from one dataset folder."""

    name: str
    info: dict[str, Any] = field(default_factory=dict)
    expected: pa.Schema | None = None
    common: pa.Schema | None = None
    common_error: str = ""
    files: list[FileFacts] = field(default_factory=list)
    sample: StatsSample | None = None       # training rows, for the statistics check
    all_rows: StatsSample | None = None     # rows of every split, for the distribution plots
    errors: list[str] = field(default_factory=list)
    take_splits: dict[str, str] = field(default_factory=dict)


def dataset_dirs(layout: OutLayout) -> list[Path]:
    base = layout.root / "datasets"
    return sorted(p for p in base.iterdir() if p.is_dir()) if base.is_dir() else []


def dataset_records(layout: OutLayout) -> dict[str, dict[str, Any]]:
    """The engine's record of each dataset build (``OUT/.gazepipe/datasets/<name>.json``), by name."""
    out = {}
    base = layout.state / "datasets"
    for p in sorted(base.glob("*.json")) if base.is_dir() else []:
        rec = read_json(p)
        if isinstance(rec, dict):
            out[p.stem] = rec
    return out


def load_dataset(path: Path, th: Thresholds) -> DatasetData:
    """Read dataset.json, ``_common_metadata`` and every take file's identifiers; sample the training rows."""
    from gazepipe.io.dataset_files import COMMON_METADATA, read_info, take_files
    from gazepipe.io.dataset_files import expected_schema as ds_schema

    d = DatasetData(path.name)
    try:
        d.info = read_info(path)
    except GazepipeError as exc:
        d.errors.append(exc.one_line())
        return d
    try:
        d.expected = ds_schema(d.info)
    except GazepipeError as exc:
        d.errors.append(exc.one_line())
    try:
        d.common = pq.read_schema(str(path / COMMON_METADATA))
    except (OSError, pa.ArrowException) as exc:
        d.common_error = f"{path / COMMON_METADATA}: unreadable ({' '.join(str(exc).split())})"
    feature_cols = list((d.info.get("features") or {}).keys())
    # pass 1: identifiers only (split, session) of every take file; pass 2 reads the feature columns of one file
    # at a time and keeps only the sampled rows, so memory holds one take whatever the dataset's size
    readable: list[tuple[Path, str, int, np.ndarray]] = []   # file, pose, rows, positions of training rows
    for f in take_files(path):
        facts = _file_facts(f, path, feature_cols, readable)
        if facts.error:
            d.errors.append(facts.error)
        d.files.append(facts)
        splits = [s for s, n in facts.rows_by_split.items() if n]
        if len(splits) == 1:
            d.take_splits[f"{facts.session}/{facts.take}"] = splits[0]
    if readable:
        _sample_rows(d, readable, feature_cols, th)
    return d


def _file_facts(f: Path, path: Path, feature_cols: list[str],
                readable: list[tuple[Path, str, int, np.ndarray]]) -> FileFacts:
    """What a take file of the dataset at ``path`` holds, from its identifier columns; the file joins
    ``readable`` (file, pose, rows, positions of its training rows) when it has every feature column."""
    from urllib.parse import unquote

    facts = FileFacts(str(f.relative_to(path)), session=unquote(f.parent.name), take=unquote(f.stem),
                      folder=f.parent.parent.name)
    try:
        pf = pq.ParquetFile(str(f))
        names = pf.schema_arrow.names
        facts.schema_hash = schema_hash(pf.schema_arrow)
        ident = pf.read(columns=[c for c in ("split", "session", "take", "subject", "pose") if c in names])
        split = np.asarray(ident.column("split").to_pylist(), dtype=object).astype(str) \
            if "split" in ident.column_names else np.zeros(0, str)
        for sp, n in zip(*np.unique(split, return_counts=True), strict=True):
            facts.rows_by_split[str(sp)] = int(n)
        for col in ("session", "take", "subject", "pose"):
            values = ident.column(col).unique().to_pylist() if col in ident.column_names else []
            if len(values) == 1:
                setattr(facts, col if col in ("subject", "pose") else f"{col}_column", str(values[0]))
        if all(c in names for c in feature_cols):
            readable.append((f, facts.pose, pf.metadata.num_rows, np.flatnonzero(split == "train")))
    except (OSError, pa.ArrowException) as exc:
        facts.error = f"{f}: unreadable ({' '.join(str(exc).split())})"
    return facts


def _sample_rows(d: DatasetData, readable: list[tuple[Path, str, int, np.ndarray]], feature_cols: list[str],
                 th: Thresholds) -> None:
    """The seeded samples of the training rows (``d.sample``) and of all rows (``d.all_rows``) of the
    ``readable`` take files, reading one file's feature columns at a time."""
    train_pick = _choose([(pose, len(tr)) for _, pose, _, tr in readable], th)
    all_pick = _choose([(pose, n) for _, pose, n, _ in readable], th)
    train_rows: dict[str, list[np.ndarray]] = {c: [] for c in feature_cols}
    all_rows: dict[str, list[np.ndarray]] = {c: [] for c in feature_cols}
    train_pose: list[np.ndarray] = []
    all_pose: list[np.ndarray] = []
    for i, (f, pose, _, train) in enumerate(readable):
        t_idx, a_idx = train[train_pick.rows[i]], all_pick.rows[i]
        if not (t_idx.size or a_idx.size):
            continue
        try:
            t = read_table(f, columns=feature_cols)
        except GazepipeError as exc:
            d.errors.append(exc.one_line())
            continue
        except (OSError, pa.ArrowException) as exc:
            d.errors.append(f"{f}: unreadable ({' '.join(str(exc).split())})")
            continue
        for idx, rows, poses in ((t_idx, train_rows, train_pose), (a_idx, all_rows, all_pose)):
            if idx.size:
                sub = t.take(pa.array(idx))
                for c in feature_cols:
                    rows[c].append(_values(sub, c))
                poses.append(np.full(idx.size, pose, dtype=object))
    if train_pick.n_total:
        d.sample = train_pick.sample(train_rows, train_pose)
    if all_pick.n_total:
        d.all_rows = all_pick.sample(all_rows, all_pose)


@dataclass
class _Pick:
    """Which rows of each part a seeded sample takes (positions within the part), and the part sizes."""

    rows: list[np.ndarray]
    n_total: int
    n_total_by_pose: dict[str, int]

    def sample(self, cols: dict[str, list[np.ndarray]], poses: list[np.ndarray]) -> StatsSample:
        return StatsSample(columns={c: np.concatenate(v) for c, v in cols.items() if v},
                           pose=np.concatenate(poses).astype(str) if poses else np.array([], str),
                           n_total=self.n_total, n_total_by_pose=dict(sorted(self.n_total_by_pose.items())))


def _choose(sizes: list[tuple[str, int]], th: Thresholds) -> _Pick:
    """A seeded sample (without replacement) of at most ``th.stats_sample_rows`` of the rows of parts of these
    (pose, size), in order: the positions taken in each part."""
    n_total = sum(n for _, n in sizes)
    by_pose: dict[str, int] = {}
    for p, n in sizes:
        if n:
            by_pose[p] = by_pose.get(p, 0) + n
    rng = np.random.default_rng(th.stats_seed)
    k = min(n_total, int(th.stats_sample_rows))
    chosen = np.sort(rng.choice(n_total, size=k, replace=False)) if k < n_total else np.arange(n_total)
    starts = np.cumsum([0] + [n for _, n in sizes])
    rows = [chosen[(chosen >= starts[i]) & (chosen < starts[i + 1])] - starts[i] for i in range(len(sizes))]
    return _Pick(rows, n_total, by_pose)


def _values(table: pa.Table, column: str) -> np.ndarray:
    col = table.column(column)
    ftype = table.schema.field(column).type
    if pa.types.is_fixed_size_list(ftype):
        return list_to_numpy(col, ftype.list_size).astype(np.float64)
    return col.to_numpy().astype(np.float64).reshape(-1, 1)
