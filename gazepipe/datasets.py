"""Reading built datasets (SPEC §4): tables, (N, D) arrays, training windows and a PyTorch adaptor.

::

    from gazepipe.datasets import open_dataset

    ds = open_dataset("out/datasets/gaze_rnn")
    win = ds.windows("train")                 # 120-frame windows of x and y, normalised with the training stats
    for x, y in win:                          # (120, 66) and (120, 63) float32 arrays
        ...
    loader = torch.utils.data.DataLoader(ds.to_torch("train"), batch_size=64, shuffle=True)

Windows are cut inside runs of rows that share (subject, session, take, mirrored, segment): never across a
segment (a gap in the usable frames), a take or the mirrored copy. Each run of L rows gives
``(L - window) // stride + 1`` windows starting at its first row; the rows after the last full window and the
runs shorter than a window are dropped and counted (:attr:`Windows.dropped_rows`, :attr:`Windows.short_runs`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from gazepipe.errors import ConfigError
from gazepipe.io.dataset_files import read_dataset
from gazepipe.schemas.dataset_tables import IDENTIFIER_NAMES

#: the (input, target) columns a window yields by default, per dataset
DEFAULT_PAIR: dict[str, tuple[str, str]] = {
    "gaze_rnn": ("x", "y"),
    "gaze_rnn_lod": ("x", "y"),
    "face_clean": ("tracked", "clean"),
}
#: a standard deviation below this is treated as 1 (a constant feature is centred, not blown up)
MIN_STD = 1e-8


def column_array(table: pa.Table, name: str) -> np.ndarray:
    """A column as an (N, D) numpy array of its stored dtype, D = 1 for a scalar column.

    Fixed-size list columns of a single chunk come back without copying (``flatten().to_numpy()`` of the
    child values, read-only); several chunks are combined first.
    """
    col = table.column(name)
    arr = col.combine_chunks() if col.num_chunks != 1 else col.chunk(0)
    if pa.types.is_fixed_size_list(arr.type):
        lists = cast(pa.FixedSizeListArray, arr)
        return lists.flatten().to_numpy(zero_copy_only=False).reshape(-1, lists.type.list_size)
    return arr.to_numpy(zero_copy_only=False).reshape(-1, 1)


def run_bounds(table: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """(starts, stops) of the runs of consecutive rows sharing subject, session, take, mirrored and segment."""
    n = table.num_rows
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    change = np.zeros(n, dtype=bool)
    change[0] = True
    for name in ("subject", "session", "take", "mirrored", "segment"):
        col = table.column(name)
        values: pa.ChunkedArray | pa.Array = col
        if pa.types.is_string(col.type):
            values = cast(pa.DictionaryArray, pc.dictionary_encode(col).combine_chunks()).indices
        v = np.asarray(values.to_numpy(zero_copy_only=False))
        change[1:] |= v[1:] != v[:-1]
    starts = np.flatnonzero(change)
    stops = np.append(starts[1:], n)
    return starts.astype(np.int64), stops.astype(np.int64)


def window_starts(starts: np.ndarray, stops: np.ndarray, window: int, stride: int) -> np.ndarray:
    """First row of every full window of ``window`` rows, stepping by ``stride`` inside each run."""
    lengths = stops - starts
    per_run = np.where(lengths >= window, (lengths - window) // stride + 1, 0)
    total = int(per_run.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    run_of = np.repeat(np.arange(len(starts)), per_run)
    first = np.cumsum(per_run) - per_run
    k = np.arange(total) - first[run_of]
    return (starts[run_of] + k * stride).astype(np.int64)


@dataclass
class Windows:
    """Fixed-length windows over a dataset's rows.

    Attributes
    ----------
    arrays : column name → (N, D) array over the selected rows (normalised float32 when asked).
    starts : first row of each window, (n,).
    window : rows per window.
    pair : the two columns ``__getitem__`` / iteration yield, (input, target).
    dropped_rows : rows of the selection in no window (runs shorter than a window, tails after the last one).
    short_runs : runs shorter than a window.
    runs : runs (subject, session, take, mirrored, segment) in the selection.
    """

    arrays: dict[str, np.ndarray]
    starts: np.ndarray
    window: int
    pair: tuple[str, str]
    dropped_rows: int
    short_runs: int
    runs: int

    def __len__(self) -> int:
        return int(len(self.starts))

    def __getitem__(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Window ``i`` as (input, target), each a (window, D) view of :attr:`arrays`."""
        s = int(self.starts[i])
        a, b = self.pair
        return self.arrays[a][s:s + self.window], self.arrays[b][s:s + self.window]

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for i in range(len(self)):
            yield self[i]

    def stack(self, column: str) -> np.ndarray:
        """All windows of ``column`` as one (n, window, D) array (a copy)."""
        idx = self.starts[:, None] + np.arange(self.window)[None, :]
        return self.arrays[column][idx]

    @property
    def x(self) -> np.ndarray:
        """(n, window, D_in) array of the input column."""
        return self.stack(self.pair[0])

    @property
    def y(self) -> np.ndarray:
        """(n, window, D_out) array of the target column."""
        return self.stack(self.pair[1])


class Dataset:
    """A built dataset folder (``OUT/datasets/<name>``), read and checked against its schema once.

    Attributes
    ----------
    path : the folder.
    info : _dataset.json.
    name : the dataset's name (``gaze_rnn``, ``gaze_rnn_lod``, ``gaze_map``, ``face_clean``).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        table, self.info = read_dataset(self.path)
        self._table = table.combine_chunks()   # one chunk: whole-dataset arrays come without a copy
        self.name: str = str(self.info.get("name"))

    # ------------------------------------------------------------------------------------------- metadata
    @property
    def features(self) -> dict[str, list[str]]:
        """Names of every element of every feature column, in order."""
        return dict(self.info.get("features", {}))

    @property
    def stats(self) -> dict[str, Any]:
        """Normalisation statistics: ``overall`` and ``per_pose``, each column → ``mean``/``std`` lists."""
        return dict(self.info.get("stats", {}))

    @property
    def schema_version(self) -> int:
        return int(self.info.get("schema_version", -1))

    @property
    def columns(self) -> list[str]:
        """Every column of the dataset's files."""
        return list(self._table.column_names)

    @property
    def fps(self) -> float | None:
        return self.info.get("fps")

    @property
    def window(self) -> int | None:
        return self.info.get("window")

    @property
    def stride(self) -> int | None:
        return self.info.get("stride")

    def __repr__(self) -> str:
        return f"Dataset({self.name!r}, {self._table.num_rows} rows, path={str(self.path)!r})"

    # ----------------------------------------------------------------------------------------------- rows
    def table(self, split: str | None = None, pose: str | None = None, mirrored: bool | None = None) -> pa.Table:
        """The rows as an Arrow table, optionally only one split, pose and/or mirrored state (file order)."""
        t = self._table
        mask = None
        for name, value in (("split", split), ("pose", pose), ("mirrored", mirrored)):
            if value is None:
                continue
            m = pc.equal(t.column(name), pa.scalar(value, t.schema.field(name).type))
            mask = m if mask is None else pc.and_(mask, m)
        return t if mask is None else t.filter(mask)

    def array(self, column: str, split: str | None = None, pose: str | None = None,
              mirrored: bool | None = None) -> np.ndarray:
        """One column of the selected rows as an (N, D) array (without copying when the rows are one chunk)."""
        self._check_column(column)
        return column_array(self.table(split, pose, mirrored), column)

    def mean_std(self, column: str, pose: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Training-row mean and standard deviation of a feature column, (D,) float32 each; overall, or of one
        pose. A standard deviation below :data:`MIN_STD` is returned as 1."""
        st = self.stats.get("overall" if pose is None else "per_pose", {})
        if pose is not None:
            if pose not in st:
                raise ConfigError(self.path / "_dataset.json", f"no statistics for pose {pose!r} "
                                                              f"(poses: {', '.join(sorted(st))})")
            st = st[pose]
        if column not in st:
            raise ConfigError(self.path / "_dataset.json", f"no statistics for column {column!r}")
        mean = np.asarray(st[column]["mean"], dtype=np.float32)
        std = np.asarray(st[column]["std"], dtype=np.float32)
        return mean, np.where(std < MIN_STD, np.float32(1.0), std).astype(np.float32)

    def normalised(self, column: str, values: np.ndarray) -> np.ndarray:
        """``(values - mean) / std`` with the column's overall training statistics, float32."""
        mean, std = self.mean_std(column)
        return ((np.asarray(values, dtype=np.float32) - mean) / std).astype(np.float32)

    def _check_column(self, column: str) -> None:
        if column not in self._table.column_names:
            raise ConfigError(self.path, f"dataset {self.name!r} has no column {column!r} "
                                         f"(columns: {', '.join(self.columns)})")

    # -------------------------------------------------------------------------------------------- windows
    def windows(self, split: str | None, window: int | None = None, stride: int | None = None,
                normalise: bool = True, pose: str | None = None, mirrored: bool | None = None,
                columns: Sequence[str] | None = None) -> Windows:
        """Fixed-length windows of the rows of ``split`` (``None``: every split).

        Parameters
        ----------
        window, stride : rows per window and step between window starts; default _dataset.json's (gaze_rnn:
            120 frames; face_clean: 200 with a stride of 50).
        normalise : subtract the training mean and divide by the training standard deviation (overall
            statistics) for every column that has statistics; other columns (``dt_s``) stay as stored.
        pose, mirrored : further row selections.
        columns : the columns to cut (default: the dataset's input/target pair, e.g. ``x`` and ``y``); the
            first two are what iteration yields.
        """
        if self.name not in DEFAULT_PAIR:
            raise ConfigError(self.path, f"dataset {self.name!r} has one row per take, not sequences: use "
                                         ".table() or .array() instead of windows")
        window = int(window if window is not None else self.window or 0)
        stride = int(stride if stride is not None else self.stride or window)
        if window < 1 or stride < 1:
            raise ConfigError(self.path, f"window ({window}) and stride ({stride}) must be at least 1")
        cols = list(columns) if columns is not None else list(DEFAULT_PAIR[self.name])
        for c in cols:
            self._check_column(c)
        pair = (cols[0], cols[1] if len(cols) > 1 else cols[0])
        t = self.table(split, pose, mirrored)
        stats = self.stats.get("overall", {})
        arrays: dict[str, np.ndarray] = {}
        for c in cols:
            v = column_array(t, c)
            if normalise and c in stats:
                v = self.normalised(c, v)
            else:
                v = np.array(v)  # own, writable memory (torch.from_numpy needs it)
            arrays[c] = v
        starts_r, stops_r = run_bounds(t)
        starts = window_starts(starts_r, stops_r, window, stride)
        lengths = stops_r - starts_r
        covered = np.where(lengths >= window, ((lengths - window) // stride) * stride + window, 0)
        return Windows(arrays=arrays, starts=starts, window=window, pair=pair,
                       dropped_rows=int((lengths - covered).sum()), short_runs=int((lengths < window).sum()),
                       runs=int(len(lengths)))

    def to_torch(self, split: str | None, **kwargs: Any):
        """The windows of ``split`` as a ``torch.utils.data.Dataset`` of (input, target) float tensors of
        shape (window, D); keyword arguments as :meth:`windows`. Needs the ``gazepipe[torch]`` extra."""
        return TorchWindows(self.windows(split, **kwargs))


def _torch():
    try:
        import torch
    except ImportError:
        raise ConfigError(None, "PyTorch is not installed: pip install 'gazepipe[torch]'") from None
    return torch


class TorchWindows:
    """A map-style PyTorch dataset over :class:`Windows` (a ``torch.utils.data.Dataset`` subclass at run time).

    Items are tuples of tensors sharing memory with the window arrays, one per column of the windows
    (the input/target pair first).
    """

    def __new__(cls, windows: Windows):
        torch = _torch()

        dataset_base: Any = torch.utils.data.Dataset   # torch is optional and untyped here

        class _TorchWindows(dataset_base):
            def __init__(self, w: Windows) -> None:
                self.windows = w
                names = [*w.pair, *[c for c in w.arrays if c not in w.pair]]
                self.names = names
                self._tensors = [torch.from_numpy(w.arrays[c]) for c in names]

            def __len__(self) -> int:
                return len(self.windows)

            def __getitem__(self, i: int):
                s = int(self.windows.starts[i])
                e = s + self.windows.window
                return tuple(t[s:e] for t in self._tensors)

        return _TorchWindows(windows)


def open_dataset(path: str | Path) -> Dataset:
    """Open a built dataset folder (``OUT/datasets/<name>``), checking every file against its schema."""
    return Dataset(path)


__all__ = ["Dataset", "Windows", "open_dataset", "column_array", "run_bounds", "window_starts",
           "IDENTIFIER_NAMES"]
