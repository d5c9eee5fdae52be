"""How the engine stores gazepipe's tables and looks at its raw inputs: each table read or written is checked
against the schema a table of its name must have (:mod:`gazepipe.schemas`), and a capture's declared layout
against its size before it is hashed."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa

from gazepipe.errors import SchemaError
from gazepipe.io.parquet import read_batches, read_table, write_batches, write_table
from gazepipe.pipeline.registry import TableBatches, TableStore
from gazepipe.schemas import expected_schema
from gazepipe.schemas.base import check_table
from gazepipe.schemas.markers import check_markers_meta, checked_markers_batches

#: tables in the long markers layout, whose metadata must agree with their rows
MARKERS_TABLES = ("markers_raw", "markers", "neutral")


def check_stored_table(table: pa.Table, path: Path, name: str) -> None:
    """Raise :class:`~gazepipe.errors.SchemaError` when a take's table ``name`` does not have the schema a table
    of that name must have (sized tables: from their metadata), or a markers table's metadata disagrees with
    its rows."""
    _check_schema(table, path, name)
    if name in MARKERS_TABLES:
        check_markers_meta(table, str(path))


def _check_schema(table: pa.Table, path: Path, name: str) -> None:
    try:
        schema = expected_schema(name, table)
    except ValueError as exc:   # its metadata, read for its sizes, is not JSON
        raise SchemaError(str(path), f"table {name}: unreadable metadata ({exc})") from None
    if schema is not None:
        check_table(table, schema, path=str(path))


def write_stored_table(table: pa.Table | TableBatches, path: Path, schema: pa.Schema) -> None:
    """Write a take's table, whole or a batch at a time (:class:`~gazepipe.pipeline.registry.TableBatches`: the
    same bytes), checked against ``schema``."""
    if isinstance(table, TableBatches):
        write_batches(table.schema, table.batches, path, schema)
    else:
        write_table(table, path, schema)


def read_stored_batches(path: Path, name: str) -> TableBatches:
    """A take's table ``name`` a row group at a time, checked as :func:`check_stored_table` checks it whole:
    its schema (and a markers table's metadata) at once, a markers table's rows as they are read."""
    schema, rows, batches = read_batches(path)
    _check_schema(schema.empty_table(), path, name)
    if name in MARKERS_TABLES:
        batches = checked_markers_batches(schema, rows, batches, str(path))
    return TableBatches(schema, rows, batches)


def check_source(path: Path) -> None:
    """A look at an input before the engine hashes it: a C3D's declared layout against its size (a header
    that claims two million frames in a small file fails the take at once)."""
    if path.suffix.lower() == ".c3d":
        from gazepipe.io.c3d import check_c3d

        check_c3d(path)


#: the table store the engine writes and reads gazepipe's tables with
TABLE_STORE = TableStore(write=write_stored_table, read=read_table, check=check_stored_table,
                         read_batches=read_stored_batches)
