"""Schema checking shared by every table gazepipe writes or reads.

Every table carries its schema's name and version in the Arrow schema metadata (``gazepipe.table``,
``gazepipe.schema_version``) plus a JSON object of table-level facts (``gazepipe.meta``: rate, labels, …).
:func:`check_table` compares a table against the schema the code expects, field by field.
"""

from __future__ import annotations

import json
from typing import Any, cast

import pyarrow as pa

from gazepipe.errors import SchemaError

TABLE_KEY = b"gazepipe.table"
VERSION_KEY = b"gazepipe.schema_version"
META_KEY = b"gazepipe.meta"


def with_identity(schema: pa.Schema, name: str, version: int) -> pa.Schema:
    """Return ``schema`` tagged with a table name and schema version."""
    md = dict(schema.metadata or {})
    md[TABLE_KEY] = name.encode()
    md[VERSION_KEY] = str(version).encode()
    return schema.with_metadata(md)


#: Arrow metadata as pyarrow's type stubs take it (an exact dict type: a ``dict[bytes, bytes]`` read back from a
#: schema has to be cast or copied into it)
ArrowMetadata = dict[bytes | str, bytes | str]

#: field-metadata key of a list column's element names (a JSON list: one name per value, in order)
ELEMENTS_KEY = b"gazepipe.elements"


def with_element_names(schema: pa.Schema, names: dict[str, list[str]]) -> pa.Schema:
    """``schema`` with each fixed-size list column named in ``names`` carrying its element names in its field
    metadata (:data:`ELEMENTS_KEY`), so a reader of the file alone knows what each value is."""
    fields = []
    for f in schema:
        elems = names.get(f.name)
        if elems is not None and pa.types.is_fixed_size_list(f.type):
            if len(elems) != f.type.list_size:
                raise SchemaError(None, f"column {f.name!r} holds {f.type.list_size} values, {len(elems)} names given")
            md: ArrowMetadata = {k: v for k, v in (f.metadata or {}).items()}
            md[ELEMENTS_KEY] = json.dumps(list(elems)).encode()
            f = f.with_metadata(md)
        fields.append(f)
    return pa.schema(fields, metadata=cast(ArrowMetadata | None, schema.metadata))


def element_names(field: pa.Field) -> list[str] | None:
    """The element names a list column's field carries (:func:`with_element_names`), or None."""
    raw = (field.metadata or {}).get(ELEMENTS_KEY)
    return json.loads(raw) if raw else None


def attach_meta(table: pa.Table, meta: dict[str, Any]) -> pa.Table:
    """Store ``meta`` (JSON-able, keys sorted so bytes are stable) in the table's schema metadata."""
    md = dict(table.schema.metadata or {})
    md[META_KEY] = json.dumps(meta, sort_keys=True, separators=(",", ":"), allow_nan=True).encode()
    return table.replace_schema_metadata(md)


def read_meta(table: pa.Table | pa.Schema) -> dict[str, Any]:
    """The ``gazepipe.meta`` object of a table or schema (empty when absent)."""
    schema = table if isinstance(table, pa.Schema) else table.schema
    raw = (schema.metadata or {}).get(META_KEY)
    return json.loads(raw) if raw else {}


def check_table(table: pa.Table, expected: pa.Schema, *, path: str | None = None) -> None:
    """Raise :class:`SchemaError` unless ``table`` has exactly the fields of ``expected`` (names, types, order)
    and the same table name and schema version."""
    where = path or "table"
    exp_name = (expected.metadata or {}).get(TABLE_KEY, b"").decode()
    got_md = table.schema.metadata or {}
    got_name = got_md.get(TABLE_KEY, b"").decode()
    if exp_name and got_name != exp_name:
        raise SchemaError(where, f"expected a '{exp_name}' table, found '{got_name or 'untagged'}'")
    exp_ver = (expected.metadata or {}).get(VERSION_KEY)
    if exp_ver is not None and got_md.get(VERSION_KEY) != exp_ver:
        got = got_md.get(VERSION_KEY, b"none").decode()
        raise SchemaError(where, f"'{exp_name}' schema version {got}, this gazepipe reads version "
                                 f"{exp_ver.decode()} (re-run with --force)")
    got_fields = [(f.name, f.type) for f in table.schema]
    exp_fields = [(f.name, f.type) for f in expected]
    if got_fields != exp_fields:
        missing = [n for n, _ in exp_fields if n not in dict(got_fields)]
        extra = [n for n, _ in got_fields if n not in dict(exp_fields)]
        wrong = [f"{n} is {t} not {dict(exp_fields)[n]}" for n, t in got_fields
                 if n in dict(exp_fields) and dict(exp_fields)[n] != t]
        detail = "; ".join(filter(None, [
            f"missing columns {missing}" if missing else "",
            f"unexpected columns {extra}" if extra else "",
            ", ".join(wrong),
            "columns out of order" if not (missing or extra or wrong) else "",
        ]))
        raise SchemaError(where, f"'{exp_name}' table does not match its schema: {detail}")
