"""Writing and reading the training datasets (SPEC §4): a layout every Parquet reader opens as it is.

Layout of one dataset ``<name>`` under ``OUT/datasets``::

    <name>/<split>/<session>/<take>.parquet   one file per take; split is train, val or test (its ``split``
                                              column); session and take URI-encoded, a leading "_" too
    <name>/_dataset.json                      features, statistics, counts, inputs, parameters
    <name>/_README.md                         the dataset card (YAML front matter for Hugging Face, then text)
    <name>/.huggingface.yaml                  the card's YAML alone: the splits Hugging Face ``datasets`` loads
    <name>/_common_metadata                   the Arrow schema (pyarrow.parquet.write_metadata)

Why so: folder names hold no ``key=value`` (pandas and pyarrow would add partition columns that clash with the
identifier columns inside the files), and every other file starts with "_" or "." (pyarrow, and so pandas,
skip those; a ``README.md`` in the folder makes them fail with "Could not read schema"). So, with no arguments::

    pandas.read_parquet(root); pyarrow.parquet.read_table(root); pyarrow.dataset.dataset(root)
    polars.read_parquet(f"{root}/**/*.parquet")           # polars refuses a folder holding other files
    duckdb.sql(f"SELECT * FROM read_parquet('{root}/**/*.parquet')")
    datasets.load_dataset(str(root))                       # splits train, validation, test

Files are produced as bytes and handed to a ``write_bytes(path, data)`` callback (the engine's atomic writer;
a plain file write by default), take files first, then the side files, ``_dataset.json`` last, so it always
describes complete take files. The engine's streaming build stages take files as they are built
(:class:`StagedDatasetWriter`; a take file made beforehand, on the worker that ran the take, is linked in rather
than copied) and publishes them only when the whole dataset built; a take file whose bytes are unchanged is left
as it is. Take files of an earlier build that are no longer part of the dataset are removed
afterwards. Every table is checked against its schema before it is written and after it is read.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote, unquote

import pyarrow as pa
import pyarrow.parquet as pq

from gazepipe.errors import InputError, SchemaError
from gazepipe.io.dataset_card import card_text, hf_yaml
from gazepipe.io.parquet import read_table, write_options
from gazepipe.schemas.base import attach_meta, check_table
from gazepipe.schemas.dataset_tables import dataset_schema

WriteBytes = Callable[[Path, bytes], None]
INFO_NAME = "_dataset.json"
CARD_NAME = "_README.md"
HF_CONFIG = ".huggingface.yaml"
COMMON_METADATA = "_common_metadata"
SPLITS = ("train", "val", "test")
#: names of an earlier layout, removed when a dataset is written again
_OLD_NAMES = ("dataset.json",)
#: a take key: (session, take)
TakeKey = tuple[str, str]


def _plain_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def _name(value: str) -> str:
    """A path component for an id: URI-encoded, a leading "_" or "." too (readers skip such names)."""
    enc = quote(value, safe="")
    return "%" + format(ord(enc[0]), "02X") + enc[1:] if enc[:1] in ("_", ".") else enc


def take_path(split: str, session: str, take: str) -> Path:
    """Relative path of a take's file: ``<split>/<session>/<take>.parquet``."""
    if split not in SPLITS:
        raise SchemaError(None, f"split {split!r} is not one of {', '.join(SPLITS)}")
    return Path(split) / _name(session) / f"{_name(take)}.parquet"


def take_files(root: str | Path) -> list[Path]:
    """The take files of a dataset folder, in path order (split, session, take)."""
    root = Path(root)
    return sorted(p for s in SPLITS for p in (root / s).glob("*/*.parquet"))


def table_split(table: pa.Table) -> str:
    """The one ``split`` value of a take's table."""
    values = table.column("split").unique().to_pylist()
    if len(values) != 1:
        raise SchemaError(None, f"a take's table holds splits {sorted(values, key=str)}, expected one")
    return str(values[0])


def table_bytes(table: pa.Table) -> bytes:
    """Parquet bytes of ``table`` with the fixed writer options (same table → same bytes)."""
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, **write_options(table.schema))
    return sink.getvalue().to_pybytes()


def schema_bytes(schema: pa.Schema) -> bytes:
    """``_common_metadata`` bytes: a Parquet footer holding ``schema`` and no row groups."""
    sink = pa.BufferOutputStream()
    pq.write_metadata(schema, sink)
    return sink.getvalue().to_pybytes()


def info_bytes(info: dict[str, Any]) -> bytes:
    """``_dataset.json`` bytes: sorted keys, floats as Python's shortest round-trip repr, no NaN."""
    try:
        text = json.dumps(info, indent=1, sort_keys=True, allow_nan=False, ensure_ascii=False)
    except ValueError as exc:
        raise SchemaError(INFO_NAME, f"cannot be written: {exc} (a statistic or parameter is not finite)") from None
    return (text + "\n").encode()


def stored_schema(built) -> pa.Schema:
    """The dataset schema tagged with its sizes (stored in ``_common_metadata`` and every take file)."""
    empty = pa.Table.from_batches([], schema=built.schema)   # (Schema.empty_table would import pandas)
    return attach_meta(empty, {"dataset": built.name, "sizes": built.info["sizes"]}).schema


def write_dataset(built, datasets_dir: str | Path, write_bytes: WriteBytes | None = None) -> list[Path]:
    """Write a :class:`gazepipe.stages.build.stage.BuiltDataset` (tables in memory) under ``datasets_dir/<name>``.

    Parameters
    ----------
    built : the built dataset.
    datasets_dir : the ``OUT/datasets`` folder.
    write_bytes : ``write_bytes(path, data)``, called once per file with absolute paths (default: a plain
        write, creating folders).

    Returns the paths written, in writing order. Stale take files (from an earlier build, not in ``built``) are
    deleted after ``_dataset.json`` is written.
    """
    write = write_bytes or _plain_write
    root = Path(datasets_dir) / built.name
    written: dict[Path, _Made] = {}
    for (session, take), table in sorted(built.tables.items()):
        path = root / take_path(table_split(table), session, take)
        check_table(table, built.schema, path=str(path))
        data = table_bytes(table)
        write(path, data)
        written[path] = _Made.of(data)
    return _finish(root, built, written, write)


@dataclass(frozen=True)
class _Made:
    """A take file's size and SHA-256, taken from its bytes when they were made (never read back)."""

    size: int
    digest: bytes

    @staticmethod
    def of(data: bytes) -> _Made:
        return _Made(len(data), hashlib.sha256(data).digest())


class StagedDatasetWriter:
    """Writes a dataset's take files as a streaming build emits them (:data:`gazepipe.stages.build.stage.TakeSink`).

    Take files go to ``staging`` (a folder on the same file system, e.g. under ``OUT/.gazepipe/tmp``), each
    fsynced; :meth:`commit` renames them into ``datasets_dir/<name>`` (leaving a published file whose bytes are
    the same untouched) and then writes the side files and ``_dataset.json`` with ``write_bytes``; :meth:`abort`
    deletes the staging folder. A build that fails half-way therefore leaves the published dataset as it was.
    """

    def __init__(self, datasets_dir: str | Path, name: str, staging: str | Path,
                 write_bytes: WriteBytes | None = None) -> None:
        self.root = Path(datasets_dir) / name
        self.staging = Path(staging)
        self.write = write_bytes or _plain_write
        self.staged: dict[TakeKey, tuple[Path, Path, _Made]] = {}   # take -> (final path, staged file, its bytes)

    def __call__(self, key: TakeKey, table: pa.Table) -> None:
        """Stage one take's table; a take emitted again (moved to another split) replaces its earlier file."""
        rel = take_path(table_split(table), *key)
        if key in self.staged:
            self.staged.pop(key)[1].unlink(missing_ok=True)
        tmp = self.staging / rel
        tmp.parent.mkdir(parents=True, exist_ok=True)
        data = table_bytes(table)
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        self.staged[key] = (self.root / rel, tmp, _Made.of(data))

    def place(self, key: TakeKey, split: str, source: str | Path) -> None:
        """Stage a take's file that is already written in its final bytes (the take's rows, made on the worker
        that ran the take): linked where the file system allows (no copy; every write of the pipeline replaces
        a file, so the two names never see different bytes), else copied."""
        rel = take_path(split, *key)
        if key in self.staged:
            self.staged.pop(key)[1].unlink(missing_ok=True)
        tmp = self.staging / rel
        tmp.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(source, tmp)
        except OSError:
            shutil.copyfile(source, tmp)
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
        with open(tmp, "rb") as fh:
            made = _Made(os.fstat(fh.fileno()).st_size, hashlib.file_digest(fh, "sha256").digest())
        self.staged[key] = (self.root / rel, tmp, made)

    def commit(self, built) -> list[Path]:
        """Publish the staged take files, then the side files and ``_dataset.json`` of ``built``; the paths
        written (take files whose published bytes were already the same are kept as they are, and listed)."""
        written: dict[Path, _Made] = {}
        for final, tmp, made in sorted(self.staged.values()):
            if not _published(final, made, tmp):
                final.parent.mkdir(parents=True, exist_ok=True)
                os.replace(tmp, final)
            written[final] = made
        self.abort()
        return _finish(self.root, built, written, self.write)

    def abort(self) -> None:
        shutil.rmtree(self.staging, ignore_errors=True)


def _published(path: Path, made: _Made, staged: Path | None = None) -> bool:
    """Whether ``path`` already holds the bytes ``made`` describes (read only when the sizes agree and it is not
    the ``staged`` file itself, linked in twice)."""
    try:
        st = path.stat()
        if staged is not None and os.path.samestat(st, staged.stat()):
            return True
        return st.st_size == made.size and hashlib.sha256(path.read_bytes()).digest() == made.digest
    except OSError:
        return False


def _finish(root: Path, built, made: dict[Path, _Made], write: WriteBytes) -> list[Path]:
    """Write the side files and ``_dataset.json`` after the take files (``made``: each one's size and digest),
    then delete stale take files (and the files of an earlier layout). Returns every path written."""
    written = list(made)
    rows = {split: int(built.info.get("counts", {}).get("by_split", {}).get(split, {}).get("rows", 0))
            for split in SPLITS}
    size = {split: sum(m.size for p, m in made.items() if p.parent.parent.name == split) for split in SPLITS}
    fingerprint = hashlib.sha256(b"".join(made[p].digest for p in sorted(made))).hexdigest()
    yaml = hf_yaml(built.name, {s: (rows[s], size[s]) for s in SPLITS}, fingerprint)
    for name, data in ((COMMON_METADATA, schema_bytes(stored_schema(built))),
                       (HF_CONFIG, yaml.encode()),
                       (CARD_NAME, card_text(built.info, yaml).encode()),
                       (INFO_NAME, info_bytes(built.info))):
        write(root / name, data)
        written.append(root / name)
    keep = set(written)
    for old in take_files(root):
        if old not in keep:
            old.unlink(missing_ok=True)
    for name in _OLD_NAMES:
        (root / name).unlink(missing_ok=True)
    for old in sorted(root.glob("subject=*")):       # an earlier, hive-partitioned layout
        shutil.rmtree(old, ignore_errors=True)
    for split in SPLITS:
        for d in sorted((root / split).glob("*")) + [root / split]:
            if d.is_dir() and not any(d.iterdir()):
                d.rmdir()
    return written


def open_dataset(dataset_dir: str | Path):
    """The dataset folder as a ``pyarrow.dataset.Dataset`` (the side files are skipped by their names)."""
    import pyarrow.dataset as ds

    return ds.dataset(str(dataset_dir), format="parquet")


def read_info(dataset_dir: str | Path) -> dict[str, Any]:
    """``_dataset.json`` of a dataset folder."""
    path = Path(dataset_dir) / INFO_NAME
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path, "file not found (not a gazepipe dataset, or an unfinished build)") from None
    except UnicodeDecodeError:
        raise InputError(path, "not a UTF-8 text file") from None
    except json.JSONDecodeError as exc:
        raise InputError(path, f"not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror})") from None
    _check_info(info, path)
    return info


def _check_info(info: Any, path: Path) -> None:
    """dataset.json's structure, as far as reading the dataset depends on it."""
    if not isinstance(info, dict):
        raise InputError(path, "expected a JSON object")
    if not isinstance(info.get("name"), str):
        raise InputError(path, "missing or non-text 'name'", key="name")
    sizes = info.get("sizes")
    if not isinstance(sizes, dict) or not all(isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool)
                                              and v >= 0 for k, v in sizes.items()):
        raise InputError(path, "'sizes' must be an object of whole numbers", key="sizes")
    for key in ("counts", "stats", "params"):
        if key in info and not isinstance(info[key], dict):
            raise InputError(path, f"'{key}' must be an object", key=key)
    for key in ("features",):
        if key in info and not isinstance(info[key], dict | list):
            raise InputError(path, f"'{key}' must be an object or a list", key=key)
    # the derivative order sets the number of columns (two per order): checked against the features listed
    # before a schema is built from it (an order of a million would take that long)
    k, features = sizes.get("k"), info.get("features")
    if k is not None and 2 * k > len(features or ()):
        raise InputError(path, f"'sizes.k' is {k}, but 'features' lists {len(features or ())} columns (two per "
                               "derivative order and more)", key="sizes")


def expected_schema(info: dict[str, Any], path: str | Path | None = None) -> pa.Schema:
    """The schema a dataset's files must match, rebuilt in code from ``_dataset.json``'s name and sizes."""
    try:
        return dataset_schema(str(info.get("name")), dict(info.get("sizes", {})))
    except SchemaError as exc:
        raise SchemaError(path or exc.path, exc.problem) from None


def read_take(path: str | Path, schema: pa.Schema) -> pa.Table:
    """Read one take file, check it against ``schema`` and its identifiers against its path
    (``<split>/<session>/<take>.parquet``)."""
    path = Path(path)
    table = read_table(path, schema)
    parts = {"split": path.parent.parent.name, "session": unquote(path.parent.name), "take": unquote(path.stem)}
    for col, want in parts.items():
        got = set(table.column(col).unique().to_pylist())
        if table.num_rows and got != {want}:
            raise SchemaError(str(path), f"column {col!r} holds {sorted(got, key=str)}, the path says {want!r}")
    return table


def read_dataset(dataset_dir: str | Path) -> tuple[pa.Table, dict[str, Any]]:
    """Read a whole dataset folder with schema checks: (all take files concatenated in path order, info).

    Checks ``_common_metadata`` and every take file against the schema rebuilt from ``_dataset.json``, and that
    the take files are exactly the ones it counts.
    """
    root = Path(dataset_dir)
    info = read_info(root)
    schema = expected_schema(info, Path(root) / INFO_NAME)
    try:
        common = pq.read_schema(str(root / COMMON_METADATA))
    except (FileNotFoundError, pa.ArrowException, OSError) as exc:
        raise InputError(root / COMMON_METADATA, f"missing or unreadable ({exc})") from None
    check_table(pa.table({f.name: pa.array([], f.type) for f in common}, schema=common), schema,
                path=str(root / COMMON_METADATA))
    files = take_files(root)
    n_takes = int(info.get("counts", {}).get("takes", -1))
    if len(files) != n_takes:
        raise SchemaError(str(root), f"{len(files)} take files, {INFO_NAME} counts {n_takes}")
    tables = [read_take(f, schema) for f in files]
    return pa.concat_tables(tables) if tables else schema.empty_table(), info
