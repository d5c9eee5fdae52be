"""Writing and reading the hive-partitioned training datasets (SPEC §4).

Layout of one dataset ``<name>`` under ``OUT/datasets``::

    <name>/subject=<s>/pose=<p>/take=<t>.parquet   one file per take (folder and file names URI-encoded)
    <name>/_common_metadata                        the Arrow schema (pyarrow.parquet.write_metadata)
    <name>/dataset.json                            features, statistics, counts, inputs, parameters

Files are produced as bytes and handed to a ``write_bytes(path, data)`` callback (the engine's atomic writer;
a plain file write by default), take files first, then ``_common_metadata``, then ``dataset.json`` last, so a
dataset.json always describes complete take files. The engine's streaming build stages take files as they are
built (:class:`StagedDatasetWriter`) and publishes them only when the whole dataset built. Take files of an earlier build that are no longer part of
the dataset are removed afterwards. Every table is checked against its schema before it is written and after it
is read.

Loading with other tools: the folder holds dataset.json next to the Parquet files, so plain folder readers must
skip it (:data:`IGNORE_PREFIXES`), and pandas, which types hive keys as dictionaries, needs the stored schema::

    pyarrow.dataset.dataset(root, format="parquet", partitioning="hive", ignore_prefixes=IGNORE_PREFIXES)
    pandas.read_parquet(root, schema=pq.read_schema(root / "_common_metadata"), ignore_prefixes=IGNORE_PREFIXES)
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote, unquote

import pyarrow as pa
import pyarrow.parquet as pq

from gazepipe.errors import InputError, SchemaError
from gazepipe.io.parquet import WRITE_OPTIONS, read_table
from gazepipe.schemas.base import attach_meta, check_table
from gazepipe.schemas.datasets import dataset_schema

WriteBytes = Callable[[Path, bytes], None]
INFO_NAME = "dataset.json"
COMMON_METADATA = "_common_metadata"
#: file-name prefixes a folder reader must skip in a dataset folder (pyarrow's defaults plus dataset.json)
IGNORE_PREFIXES = [".", "_", INFO_NAME]


def _plain_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def take_path(subject: str, pose: str, take: str) -> Path:
    """Relative path of a take's file: ``subject=<s>/pose=<p>/take=<t>.parquet`` (values URI-encoded, as
    pyarrow's hive partitioning decodes them)."""
    return Path(f"subject={quote(subject, safe='')}") / f"pose={quote(pose, safe='')}" / \
        f"take={quote(take, safe='')}.parquet"


def table_bytes(table: pa.Table) -> bytes:
    """Parquet bytes of ``table`` with the fixed writer options (same table → same bytes)."""
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, **WRITE_OPTIONS)
    return sink.getvalue().to_pybytes()


def schema_bytes(schema: pa.Schema) -> bytes:
    """``_common_metadata`` bytes: a Parquet footer holding ``schema`` and no row groups."""
    sink = pa.BufferOutputStream()
    pq.write_metadata(schema, sink)
    return sink.getvalue().to_pybytes()


def info_bytes(info: dict[str, Any]) -> bytes:
    """dataset.json bytes: sorted keys, floats as Python's shortest round-trip repr, no NaN."""
    try:
        text = json.dumps(info, indent=1, sort_keys=True, allow_nan=False, ensure_ascii=False)
    except ValueError as exc:
        raise SchemaError(INFO_NAME, f"cannot be written: {exc} (a statistic or parameter is not finite)") from None
    return (text + "\n").encode()


def stored_schema(built) -> pa.Schema:
    """The dataset schema tagged with its sizes (stored in ``_common_metadata`` and every take file)."""
    return attach_meta(pa.table({f.name: pa.array([], f.type) for f in built.schema}, schema=built.schema),
                       {"dataset": built.name, "sizes": built.info["sizes"]}).schema


def write_dataset(built, datasets_dir: str | Path, write_bytes: WriteBytes | None = None) -> list[Path]:
    """Write a :class:`gazepipe.stages.build.stage.BuiltDataset` (tables in memory) under ``datasets_dir/<name>``.

    Parameters
    ----------
    built : the built dataset.
    datasets_dir : the ``OUT/datasets`` folder.
    write_bytes : ``write_bytes(path, data)``, called once per file with absolute paths (default: a plain
        write, creating folders).

    Returns the paths written, in writing order. Stale take files (from an earlier build, not in ``built``) are
    deleted after dataset.json is written.
    """
    write = write_bytes or _plain_write
    root = Path(datasets_dir) / built.name
    written: list[Path] = []
    for (subject, pose, take), table in sorted(built.tables.items()):
        path = root / take_path(subject, pose, take)
        check_table(table, built.schema, path=str(path))
        write(path, table_bytes(table))
        written.append(path)
    return _finish(root, built, written, write)


class StagedDatasetWriter:
    """Writes a dataset's take files as a streaming build emits them (:data:`gazepipe.stages.build.stage.TakeSink`).

    Take files go to ``staging`` (a folder on the same file system, e.g. under ``OUT/.gazepipe/tmp``), each
    fsynced; :meth:`commit` renames them into ``datasets_dir/<name>`` and then writes ``_common_metadata`` and
    dataset.json with ``write_bytes``; :meth:`abort` deletes the staging folder. A build that fails half-way
    therefore leaves the published dataset as it was.
    """

    def __init__(self, datasets_dir: str | Path, name: str, staging: str | Path,
                 write_bytes: WriteBytes | None = None) -> None:
        self.root = Path(datasets_dir) / name
        self.staging = Path(staging)
        self.write = write_bytes or _plain_write
        self.staged: dict[Path, Path] = {}     # final path -> staged file (a take emitted again replaces it)

    def __call__(self, key: tuple[str, str, str], table: pa.Table) -> None:
        rel = take_path(*key)
        tmp = self.staging / rel
        tmp.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            fh.write(table_bytes(table))
            fh.flush()
            os.fsync(fh.fileno())
        self.staged[self.root / rel] = tmp

    def commit(self, built) -> list[Path]:
        """Publish the staged take files, then the schema file and dataset.json of ``built``; the paths written."""
        written: list[Path] = []
        for final, tmp in sorted(self.staged.items()):
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp, final)
            written.append(final)
        self.abort()
        return _finish(self.root, built, written, self.write)

    def abort(self) -> None:
        shutil.rmtree(self.staging, ignore_errors=True)


def _finish(root: Path, built, written: list[Path], write: WriteBytes) -> list[Path]:
    """Write ``_common_metadata`` and dataset.json after the take files, then delete stale take files."""
    write(root / COMMON_METADATA, schema_bytes(stored_schema(built)))
    written.append(root / COMMON_METADATA)
    write(root / INFO_NAME, info_bytes(built.info))
    written.append(root / INFO_NAME)
    keep = set(written)
    for old in sorted(root.glob("subject=*/pose=*/take=*.parquet")):
        if old not in keep:
            old.unlink(missing_ok=True)
    for d in sorted(root.glob("subject=*/pose=*"), reverse=True) + sorted(root.glob("subject=*"), reverse=True):
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()
    return written


def open_dataset(dataset_dir: str | Path):
    """The dataset folder as a ``pyarrow.dataset.Dataset`` (hive partitioning, dataset.json skipped)."""
    import pyarrow.dataset as ds

    return ds.dataset(str(dataset_dir), format="parquet", partitioning="hive", ignore_prefixes=IGNORE_PREFIXES)


def read_info(dataset_dir: str | Path) -> dict[str, Any]:
    """dataset.json of a dataset folder."""
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


def expected_schema(info: dict[str, Any], path: str | Path | None = None) -> pa.Schema:
    """The schema a dataset's files must match, rebuilt in code from dataset.json's name and sizes."""
    try:
        return dataset_schema(str(info.get("name")), dict(info.get("sizes", {})))
    except SchemaError as exc:
        raise SchemaError(path or exc.path, exc.problem) from None


def read_take(path: str | Path, schema: pa.Schema) -> pa.Table:
    """Read one take file, check it against ``schema`` and its identifiers against its folder names."""
    path = Path(path)
    table = read_table(path, schema)
    parts = {p.split("=", 1)[0]: unquote(p.split("=", 1)[1]) for p in (path.parent.parent.name,
                                                                      path.parent.name, path.stem)}
    for col, want in parts.items():
        got = set(table.column(col).unique().to_pylist())
        if table.num_rows and got != {want}:
            raise SchemaError(str(path), f"column {col!r} holds {sorted(got)}, the path says {want!r}")
    return table


def read_dataset(dataset_dir: str | Path) -> tuple[pa.Table, dict[str, Any]]:
    """Read a whole dataset folder with schema checks: (all take files concatenated in path order, info).

    Checks ``_common_metadata`` and every take file against the schema rebuilt from dataset.json, and that the
    take files are exactly the ones dataset.json counts.
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
    files = sorted(root.glob("subject=*/pose=*/take=*.parquet"))
    n_takes = int(info.get("counts", {}).get("takes", -1))
    if len(files) != n_takes:
        raise SchemaError(str(root), f"{len(files)} take files, dataset.json counts {n_takes}")
    tables = [read_take(f, schema) for f in files]
    return pa.concat_tables(tables) if tables else schema.empty_table(), info
