"""The QC records of the take stages as frozen dataclasses, and how one is read back from a unit record.

Each take stage writes a JSON QC record into its unit record (``OUT/.gazepipe/units/<session>/<take>/<stage>.json``,
under ``"qc"``); its package declares that record's shape as a frozen dataclass deriving from :class:`QCRecord`
(``stages/sync/qc.py`` :class:`~gazepipe.stages.sync.qc.SyncQC`, …; the ingest stage's in
:mod:`gazepipe.stages.ingest_qc`). The report turns each record into its dataclass once
(:meth:`QCRecord.from_record`) and reads attributes, so a key a stage stops writing, or writes with another type,
is a loud :class:`QCRecordError` naming the record file and the key, never a check that passes on a default.

The field types say what :meth:`QCRecord.from_record` checks: ``int``, ``float`` (an integer is a number too),
``str``, ``bool``, ``X | None`` (the key must be there; its value may be null), ``tuple[X, ...]`` and fixed
``tuple[X, Y]`` (a JSON list), ``Mapping[str, X]`` (a JSON object), a nested :class:`QCRecord` (a JSON object)
and ``Any`` (anything, for entries the report does not read into); :meth:`QCRecord.problems` adds what a type
cannot say (a gap's method is a fill code that has a validation error entry). A key a stage writes only sometimes is a
``X | None`` field made with :func:`absent_when`, which says when and why it is left out; every other key must be
present. Keys a record has beyond its dataclass's fields are ignored (a newer stage may record more).
"""

from __future__ import annotations

import dataclasses
import functools
import numbers
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np

from gazepipe.errors import SchemaError

#: the metadata key of a field whose key may be absent from the record (its value: when, and why)
ABSENT_WHEN = "gazepipe.absent_when"


class QCRecordError(SchemaError):
    """A unit record's QC lacks a key the report reads, or holds one with the wrong type (names the record file
    and the key, e.g. ``qc.claps[1].video_s``)."""


def absent_when(reason: str) -> Any:
    """A field for a key the stage writes only sometimes (``reason``: when it does not); it is ``None`` then.
    Not a default: :meth:`QCRecord.from_record` still fills every field, and the dataclass's constructor still
    needs it."""
    return dataclasses.field(metadata={ABSENT_WHEN: reason})


class QCRecord:
    """Base of the stages' QC dataclasses (frozen dataclasses deriving from it)."""

    #: the stage whose unit records hold it (set by each stage's top-level QC type)
    stage: ClassVar[str]

    @classmethod
    def from_record(cls, qc: Mapping[str, Any], path: str | Path | None = None) -> Self:
        """The QC record ``qc`` (a unit record's ``"qc"``, as JSON reads it, or a stage's own dict) as this
        dataclass; :class:`QCRecordError` naming ``path`` (the record file) and the key when a key is missing
        or its value has the wrong type."""
        return typing.cast(Self, _parse_dataclass(cls, qc, "qc", path))

    def problems(self) -> list[tuple[str, str]]:
        """What is wrong with the record beyond its keys' types, as (key, problem) pairs (none here; a record type
        with an invariant the report relies on says so)."""
        return []

    def to_record(self) -> dict[str, Any]:
        """The JSON-ready dict the stage writes: lists for tuples, a key of :func:`absent_when` left out when it is
        ``None``; ``from_record(x.to_record()) == x``."""
        return typing.cast(dict[str, Any], _plain(self))


def _plain(v: Any) -> Any:
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {f.name: _plain(x) for f in dataclasses.fields(v)
                if not ((x := getattr(v, f.name)) is None and ABSENT_WHEN in f.metadata)}
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    return v


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _fail(path: str | Path | None, where: str, problem: str) -> QCRecordError:
    return QCRecordError(path, problem, key=where)


def _kind(v: Any) -> str:
    return "null" if v is None else type(v).__name__


def _parse_dataclass(cls: type, value: Any, where: str, path: str | Path | None) -> Any:
    if not isinstance(value, Mapping):
        raise _fail(path, where, f"is {_kind(value)}, not an object ({cls.__name__})")
    hints = _hints(cls)
    kw: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        at = f"{where}.{f.name}"
        if f.name not in value:
            if ABSENT_WHEN in f.metadata:
                kw[f.name] = None
                continue
            raise _fail(path, at, f"missing from the {cls.__name__} record")
        kw[f.name] = _convert(hints[f.name], value[f.name], at, path)
    out = cls(**kw)
    if isinstance(out, QCRecord):
        for key, problem in out.problems():
            raise _fail(path, f"{where}.{key}", problem)
    return out


def _convert(tp: Any, v: Any, where: str, path: str | Path | None) -> Any:
    if tp is Any:
        return v
    origin = typing.get_origin(tp)
    if origin is typing.Union or origin is types.UnionType:
        args = typing.get_args(tp)
        if v is None:
            if type(None) in args:
                return None
            raise _fail(path, where, "is null")
        rest = [a for a in args if a is not type(None)]
        if len(rest) != 1:
            raise TypeError(f"unsupported QC field type {tp}")
        return _convert(rest[0], v, where, path)
    if dataclasses.is_dataclass(tp):
        return _parse_dataclass(typing.cast(type, tp), v, where, path)
    if tp is bool:
        if isinstance(v, bool | np.bool_):
            return bool(v)
        raise _fail(path, where, f"is {_kind(v)}, not a boolean")
    if tp is int:
        if isinstance(v, numbers.Integral) and not isinstance(v, bool | np.bool_):
            return int(v)
        raise _fail(path, where, f"is {_kind(v)}, not an integer")
    if tp is float:
        if isinstance(v, numbers.Real) and not isinstance(v, bool | np.bool_):
            # a JSON integer stays one (the report echoes some values as the record has them)
            return v if type(v) in (int, float) else float(v)
        raise _fail(path, where, f"is {_kind(v)}, not a number")
    if tp is str:
        if isinstance(v, str):
            return v
        raise _fail(path, where, f"is {_kind(v)}, not a string")
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(v, list | tuple):
            raise _fail(path, where, f"is {_kind(v)}, not a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], x, f"{where}[{i}]", path) for i, x in enumerate(v))
        if len(v) != len(args):
            raise _fail(path, where, f"has {len(v)} item(s), not {len(args)}")
        return tuple(_convert(a, x, f"{where}[{i}]", path) for i, (a, x) in enumerate(zip(args, v, strict=True)))
    if origin in (Mapping, dict) or tp in (Mapping, dict):
        args = typing.get_args(tp) or (str, Any)
        if not isinstance(v, Mapping):
            raise _fail(path, where, f"is {_kind(v)}, not an object")
        out: dict[str, Any] = {}
        for k, x in v.items():
            if not isinstance(k, str):
                raise _fail(path, where, f"has a key {k!r} that is not a string")
            out[k] = _convert(args[1], x, f"{where}.{k}", path)
        return out
    raise TypeError(f"unsupported QC field type {tp}")


__all__ = ["ABSENT_WHEN", "QCRecord", "QCRecordError", "absent_when"]
