"""The ``_dataset.json`` object of a built dataset, accumulated one take at a time.

:class:`DatasetSummary` is fed each take's table as the build emits it and keeps only small facts (counts, the
take's QC, its input hashes, segment lengths) and running statistics, so a dataset of any size is summarised in
the memory of one take. Statistics are the mean and population standard deviation of the stored float32 values
over the training rows, overall and per pose, merged take by take with Chan et al.'s pairwise update (equal to a
two-pass computation over the concatenated rows to ~1e-15 relative).

A take's part of it (:class:`TakeFacts`: its row count, QC, input hashes, segment lengths and per-column moments)
is computed from the take's table alone (:func:`take_facts`), on the worker that built the take's rows, and
travels as JSON (:meth:`TakeFacts.to_json`: floats as their shortest round-trip repr, so the moments come back
bit for bit); merged in the same take order, the statistics are the same bits as those of one process.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe import __version__
from gazepipe.model import SPLITS
from gazepipe.schemas.dataset_tables import IDENTIFIER_NAMES, schema_version
from gazepipe.schemas.joints import list_to_numpy


def feature_values(table: pa.Table, column: str) -> np.ndarray:
    """A feature column as an (N, D) array of its stored dtype (D = 1 for a scalar column)."""
    ftype = table.schema.field(column).type
    if pa.types.is_fixed_size_list(ftype):
        return list_to_numpy(table.column(column), ftype.list_size)
    return table.column(column).to_numpy().reshape(-1, 1)


def table_hash(table: pa.Table) -> str:
    """sha256 of a table's Arrow IPC stream (schema, metadata and data)."""
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, table.schema) as writer:
        writer.write_table(table)
    return hashlib.sha256(sink.getvalue().to_pybytes()).hexdigest()


@dataclass
class RunningMoments:
    """Count, mean and sum of squared deviations per element of one feature (float64), mergeable.

    NaN values are null (gaze_map's parameters that cannot be computed): each element keeps its own count of
    the values that are not, and its mean and deviations are over those alone. Without NaN the update is the
    one of whole rows, bit for bit."""

    n: np.ndarray | int = 0
    mean: np.ndarray | None = None
    m2: np.ndarray | None = None

    def _merge(self, nb: np.ndarray, mb: np.ndarray, m2b: np.ndarray) -> None:
        """Merge moments (count, mean, squared deviations; each (D,), mean and m2 0 where the count is 0)."""
        if self.mean is None:
            self.n, self.mean, self.m2 = nb.copy(), mb.copy(), m2b.copy()
            return
        n = self.n + nb
        d = np.maximum(n, 1)
        delta = mb - self.mean
        self.mean = self.mean + delta * (nb / d)
        self.m2 = self.m2 + m2b + delta ** 2 * (self.n * nb / d)
        self.n = n

    def add(self, values: np.ndarray) -> None:
        """Merge the rows of ``values`` (N, D); NaN values are left out of their element."""
        v = np.asarray(values, dtype=np.float64)
        if v.shape[0] == 0:
            return
        ok = ~np.isnan(v)
        if ok.all():
            nb = np.full(v.shape[1], v.shape[0], dtype=np.int64)
            mb = v.mean(axis=0)
            m2b = ((v - mb) ** 2).sum(axis=0)
        else:
            nb = ok.sum(axis=0).astype(np.int64)
            mb = np.where(ok, v, 0.0).sum(axis=0) / np.maximum(nb, 1)
            m2b = np.where(ok, (np.where(ok, v, 0.0) - mb) ** 2, 0.0).sum(axis=0)
        self._merge(nb, mb, m2b)

    def merge(self, other: RunningMoments) -> None:
        """Merge another set of moments (the same update as :meth:`add` with its rows)."""
        if other.mean is None or other.m2 is None:
            return
        self._merge(np.asarray(other.n), other.mean, other.m2)

    def to_json(self) -> dict[str, list] | None:
        """The moments as JSON values (exact: Python's float repr round-trips), ``None`` when empty."""
        if self.mean is None or self.m2 is None:
            return None
        return {"n": [int(x) for x in np.asarray(self.n)], "mean": [float(x) for x in self.mean],
                "m2": [float(x) for x in self.m2]}

    @staticmethod
    def from_json(obj: dict[str, list] | None) -> RunningMoments:
        """The moments :meth:`to_json` gave."""
        if obj is None:
            return RunningMoments()
        return RunningMoments(np.asarray(obj["n"], dtype=np.int64), np.asarray(obj["mean"], dtype=np.float64),
                              np.asarray(obj["m2"], dtype=np.float64))

    def result(self) -> dict[str, list]:
        """``mean``, ``std`` (population) and ``count`` (values that are not null) per element. An element with
        no value has mean 0 and std 0 (readers then centre nothing and divide by 1)."""
        if self.mean is None:
            return {"mean": [], "std": [], "count": []}
        n = np.asarray(self.n)
        std = np.sqrt(self.m2 / np.maximum(n, 1))
        return {"mean": [float(x) for x in self.mean], "std": [float(x) for x in std],
                "count": [int(x) for x in n]}


@dataclass
class TakeFacts:
    """What a dataset's summary needs of one take's table: its rows (mirrored ones included), its QC, its input
    hashes, the lengths of its segments (original rows; windowed gaze datasets only) and each feature column's
    moments (partial sums: the statistics are exact whichever takes end up in train)."""

    rows: int
    qc: dict[str, Any]
    hashes: dict[str, str]
    segment_lengths: list[int] | None
    moments: dict[str, RunningMoments]

    def to_json(self) -> dict[str, Any]:
        return {"rows": self.rows, "qc": self.qc, "hashes": dict(self.hashes),
                "segment_lengths": self.segment_lengths,
                "moments": {c: m.to_json() for c, m in self.moments.items()}}

    @staticmethod
    def from_json(obj: dict[str, Any]) -> TakeFacts:
        return TakeFacts(rows=int(obj["rows"]), qc=dict(obj["qc"]), hashes=dict(obj["hashes"]),
                         segment_lengths=obj["segment_lengths"],
                         moments={c: RunningMoments.from_json(m) for c, m in obj["moments"].items()})


def take_facts(table: pa.Table, columns: list[str], qc: dict[str, Any], hashes: dict[str, str],
               segments: bool) -> TakeFacts:
    """A take's :class:`TakeFacts` from its dataset table (``columns``: the feature columns; ``segments``:
    whether its segment lengths count, as for the windowed gaze datasets)."""
    lengths = None
    if segments:
        original = ~table.column("mirrored").to_numpy(zero_copy_only=False)
        lengths = [int(x) for x in np.bincount(table.column("segment").to_numpy()[original])]
    moments = {}
    for c in columns:
        moments[c] = RunningMoments()
        moments[c].add(feature_values(table, c))
    return TakeFacts(table.num_rows, qc, dict(hashes), lengths, moments)


@dataclass
class _Group:
    rows: int = 0
    moments: dict[str, RunningMoments] = field(default_factory=dict)


@dataclass
class _Take:
    """What the statistics need of one take: its pose, split, row count and per-column moments (partial sums,
    so the statistics are exact whichever takes end up in train)."""

    pose: str
    split: str
    rows: int
    moments: dict[str, RunningMoments]
    pinned: bool = False


@dataclass
class DatasetSummary:
    """Facts of a dataset gathered take by take (see :meth:`add_take`), turned into _dataset.json by :meth:`info`."""

    name: str
    columns: list[str]
    window: int | None
    #: bool mask columns (gaze_map's ``known``): not statistics, their element names go to _dataset.json
    masks: list[str] = field(default_factory=list)
    by_split: dict[str, dict[str, int]] = field(default_factory=lambda: {s: {"takes": 0, "rows": 0} for s in SPLITS})
    by_pose: dict[str, dict[str, int]] = field(default_factory=dict)
    split_takes: dict[str, list[str]] = field(default_factory=lambda: {s: [] for s in SPLITS})
    per_take: dict[str, Any] = field(default_factory=dict)
    #: frames that gave no row, by reason, over every take (datasets whose rows say why)
    dropped: dict[str, int] = field(default_factory=dict)
    #: takes whose row has each mask entry null (gaze_map: segment, ``eyes``, ``overshoot`` → takes), or None
    #: for datasets whose rows have no nulls
    nulls: dict[str, int] | None = None
    inputs: dict[str, dict[str, str]] = field(default_factory=dict)
    segment_lengths: list[np.ndarray] = field(default_factory=list)
    takes: dict[str, _Take] = field(default_factory=dict)
    #: takes moved out of their hashed split so that no split is empty: (take, from, to, why)
    moves: list[tuple[str, str, str, str]] = field(default_factory=list)
    n_takes: int = 0
    n_rows: int = 0

    def add_take(self, tid: str, pose: str, split: str, facts: TakeFacts, pinned: bool = False) -> None:
        """Count one take (its rows, mirrored ones included) and keep its statistics' partial sums."""
        n, qc = facts.rows, facts.qc
        self.n_takes += 1
        self.n_rows += n
        self.by_split[split]["takes"] += 1
        self.by_split[split]["rows"] += n
        bp = self.by_pose.setdefault(pose, {"takes": 0, "rows": 0})
        bp["takes"] += 1
        bp["rows"] += n
        self.split_takes[split].append(tid)
        self.per_take[tid] = {**qc, "split": split, "rows": n}
        for reason, frames in qc.get("dropped", {}).items():
            self.dropped[reason] = self.dropped.get(reason, 0) + int(frames)
        if "null_segments" in qc:
            self.nulls = self.nulls or {}
            for what in qc["null_segments"]:
                self.nulls[what] = self.nulls.get(what, 0) + 1
        self.inputs[tid] = dict(sorted(facts.hashes.items()))
        if self.segmented:
            self.segment_lengths.append(np.asarray(facts.segment_lengths or [], dtype=np.int64))
        self.takes[tid] = _Take(pose, split, n, {c: facts.moments[c] for c in self.columns}, pinned)

    @property
    def segmented(self) -> bool:
        """Whether the dataset counts its segments against its window (the windowed gaze datasets)."""
        return self.window is not None and self.name != "face_clean"

    def move(self, tid: str, split: str, why: str) -> None:
        """Move take ``tid`` to ``split`` (its table re-emitted by the caller with that split)."""
        t = self.takes[tid]
        old = t.split
        self.moves.append((tid, old, split, why))
        for s, sign in ((old, -1), (split, 1)):
            self.by_split[s]["takes"] += sign
            self.by_split[s]["rows"] += sign * t.rows
        self.split_takes[old].remove(tid)
        self.split_takes[split].append(tid)
        t.split = split
        self.per_take[tid]["split"] = split

    @property
    def train_takes(self) -> int:
        return self.by_split["train"]["takes"]

    def _stats(self) -> dict[str, Any]:
        overall, per_pose = _Group(), dict[str, _Group]()
        for t in self.takes.values():             # in build order: the merge is the same whatever moved
            if t.split != "train":
                continue
            for g in (overall, per_pose.setdefault(t.pose, _Group())):
                g.rows += t.rows
                for c in self.columns:
                    g.moments.setdefault(c, RunningMoments()).merge(t.moments[c])

        def summary(g: _Group) -> dict[str, Any]:
            out: dict[str, Any] = {"rows": g.rows}
            for c in self.columns:
                out[c] = g.moments.get(c, RunningMoments()).result()
            return out

        stats: dict[str, Any] = {"overall": summary(overall),
                                 "per_pose": {p: summary(per_pose[p]) for p in sorted(per_pose)}}
        stats["rows_used"] = "training rows only, mirrored copies included"
        stats["std"] = "population standard deviation (ddof = 0) of the stored float32 values"
        stats["count"] = ("values per element that are not null (NaN) and enter its mean and std; an element "
                          "without any has mean 0 and std 0")
        return stats

    def info(self, *, params: dict[str, Any], names: dict[str, list[str]], sizes: dict[str, int], fps: list[float],
             stride: int | None, mirror: bool, salt: str, train_frac: float, val_frac: float,
             skipped: list[dict[str, str]]) -> dict[str, Any]:
        """The _dataset.json object."""
        warnings = [f"take {k} moved from {a} to {b}: {why}" for k, a, b, why in self.moves]
        pinned_only = all(t.pinned for t in self.takes.values())
        for s in SPLITS:
            if self.by_split[s]["takes"] == 0:
                least = {"train": 1, "val": 3, "test": 5}[s]
                why = ("every take is pinned to another split" if pinned_only and self.n_takes else
                       f"{self.n_takes} take(s): the {s} split is filled from the others only with {least} or more"
                       if self.n_takes < least else "no take could move there")
                warnings.append(f"split {s!r} is empty: {why}")
        if len(fps) > 1 and self.name != "face_clean":
            warnings.append(f"takes have different frame rates {fps} Hz: a window of frames spans different times")
        counts: dict[str, Any] = {"takes": self.n_takes, "rows": self.n_rows, "mirrored": bool(mirror),
                                  "by_split": self.by_split, "by_pose": dict(sorted(self.by_pose.items())),
                                  "skipped": len(skipped)}
        if self.segmented:
            lengths, w = self.segment_lengths, self.window
            counts["segments"] = int(sum(len(v) for v in lengths))
            counts["segments_with_a_window"] = int(sum(int((v >= w).sum()) for v in lengths))
            counts["rows_in_segments_with_a_window"] = int(sum(int(v[v >= w].sum()) for v in lengths))
            counts["rows_in_segments"] = int(sum(int(v.sum()) for v in lengths))    # mirrored copies not counted
        if self.dropped:
            counts["dropped_frames"] = dict(self.dropped)
        if self.nulls is not None:
            counts["null_segments"] = dict(sorted(self.nulls.items()))
            counts["takes_with_nulls"] = sum(1 for q in self.per_take.values() if q.get("null_segments"))
        counts["per_take"] = self.per_take
        return {
            "name": self.name,
            "description": DESCRIPTIONS[self.name],
            "version": __version__,
            "schema_version": schema_version(self.name),
            "identifiers": list(IDENTIFIER_NAMES),
            "features": {c: list(names[c]) for c in self.columns},
            "masks": {c: list(names[c]) for c in self.masks},
            "sizes": dict(sizes),
            "units": UNITS[self.name],
            "fps": fps[0] if len(fps) == 1 else None,
            "rates_hz": fps,
            "window": self.window,
            "stride": stride,
            "splits": {"train_frac": train_frac, "val_frac": val_frac, "salt": salt, "takes": self.split_takes},
            "stats": self._stats(),
            "counts": counts,
            "inputs": dict(sorted(self.inputs.items())),
            "params": params,
            "skipped": skipped,
            "warnings": warnings,
        }


_RNN_NOTE = ("one row per frame t of a run of consecutive usable frames (segment); x = target direction at t, "
             "each segment's 6-number rotation (forward R·z, up R·y) at t-1{eyes}; y = the same at t. The first "
             "frame of a segment only provides the previous pose of the second and has no row. Character "
             "frame of each frame (+X left, +Y up, +Z forward).")
DESCRIPTIONS: dict[str, str] = {
    "gaze_rnn": "Klein 6.1 gaze RNN: " + _RNN_NOTE.format(eyes=", eye direction at t-1") +
                " A frame with invalid eyes ends a segment.",
    "gaze_rnn_lod": "Klein 7 level-of-detail gaze RNN ([lod] segments, no eyes): " + _RNN_NOTE.format(eyes=""),
    "gaze_map": ("Pejsa 5.1 gaze displacement motions: one row per gaze_shift take; rotations in the character "
                 "frame held fixed at the crop's first frame; p_plus = parent-relative displacement per segment "
                 "L(last)·L(first)^-1, then the eyes' D_head^T·Ry(yaw)·Rx(-pitch); start_times and "
                 "overshoot_time are fractions of duration_s. known (segments, eyes, overshoot) marks what could "
                 "be computed: where False, that segment's p_plus, the eyes' p_plus, or overshoot_time and "
                 "overshoot are NaN; start_known marks start_times: False = NaN (the segment never reached the "
                 "start speed, or its start could not be read). A take with nothing known gives no row."),
    "face_clean": ("Berson 3.1 face cleaner: one row per aligned frame of a face take; dt_s = t[n+1] - t[n]; "
                   "tracked_dK / clean_dK are forward derivatives of order K divided by dt; rows of a take form "
                   "one sequence (segment 0)."),
}

UNITS: dict[str, dict[str, str]] = {
    "gaze_rnn": {"x": "unit vectors, character frame (+X left, +Y up, +Z forward)", "y": "unit vectors",
                 "time_s": "s"},
    "gaze_rnn_lod": {"x": "unit vectors, character frame (+X left, +Y up, +Z forward)", "y": "unit vectors",
                     "time_s": "s"},
    "gaze_map": {"yaw_deg": "deg", "pitch_deg": "deg", "duration_s": "s", "start_times": "fraction of duration",
                 "overshoot_time": "fraction of duration", "overshoot": "fraction of the final displacement",
                 "p_plus": "quaternion w, x, y, z", "known": "True = computed, False = NaN in the row",
                 "start_known": "True = a start found, False = NaN in start_times",
                 "time_s": "s"},
    "face_clean": {"tracked": "blendshape coefficient", "clean": "blendshape coefficient", "dt_s": "s",
                   "tracked_dK": "1/s^K", "clean_dK": "1/s^K", "time_s": "s"},
}
