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


class _Bad(Exception):
    """A value that does not parse; ``where`` collects the keys and indices from the value up (joined only on
    failure, so a record that parses builds no key strings)."""

    def __init__(self, problem: str) -> None:
        super().__init__(problem)
        self.problem = problem
        self.where: list[str] = []


def _at(bad: _Bad, key: str) -> _Bad:
    bad.where.append(key)
    return bad


def _kind(v: Any) -> str:
    return "null" if v is None else type(v).__name__


def _parse_dataclass(cls: type, value: Any, where: str, path: str | Path | None) -> Any:
    try:
        return _converter(cls)(value)
    except _Bad as bad:
        raise QCRecordError(path, bad.problem, key=where + "".join(reversed(bad.where))) from None


Converter = typing.Callable[[Any], Any]


@functools.cache
def _converter(tp: Any) -> Converter:
    """The function that checks and converts a JSON value to the field type ``tp`` (made once per type)."""
    if tp is Any:
        return _as_is
    origin = typing.get_origin(tp)
    if origin is typing.Union or origin is types.UnionType:
        return _optional(tp)
    if dataclasses.is_dataclass(tp):
        return _dataclass(typing.cast(type, tp))
    if tp in _SCALARS:
        return _SCALARS[tp]
    if origin is tuple:
        return _tuple(tp)
    if origin in (Mapping, dict) or tp in (Mapping, dict):
        return _mapping(tp)
    raise TypeError(f"unsupported QC field type {tp}")


def _as_is(v: Any) -> Any:
    return v


def _optional(tp: Any) -> Converter:
    args = typing.get_args(tp)
    rest = [a for a in args if a is not type(None)]
    if len(rest) != 1:
        raise TypeError(f"unsupported QC field type {tp}")
    inner, nullable = _converter(rest[0]), type(None) in args

    def convert(v: Any) -> Any:
        if v is None:
            if nullable:
                return None
            raise _Bad("is null")
        return inner(v)
    return convert


def _dataclass(cls: type) -> Converter:
    hints = _hints(cls)
    fields = [(f.name, ABSENT_WHEN in f.metadata, _converter(hints[f.name])) for f in dataclasses.fields(cls)]
    checked = issubclass(cls, QCRecord)

    def convert(value: Any) -> Any:
        if not isinstance(value, Mapping):
            raise _Bad(f"is {_kind(value)}, not an object ({cls.__name__})")
        kw: dict[str, Any] = {}
        for name, may_be_absent, conv in fields:
            if name not in value:
                if may_be_absent:
                    kw[name] = None
                    continue
                raise _at(_Bad(f"missing from the {cls.__name__} record"), f".{name}")
            try:
                kw[name] = conv(value[name])
            except _Bad as bad:
                bad.where.append(f".{name}")
                raise
        out = cls(**kw)
        if checked:
            for key, problem in out.problems():
                raise _at(_Bad(problem), f".{key}")
        return out
    return convert


def _boolean(v: Any) -> bool:
    if isinstance(v, bool | np.bool_):
        return bool(v)
    raise _Bad(f"is {_kind(v)}, not a boolean")


def _integer(v: Any) -> int:
    if isinstance(v, numbers.Integral) and not isinstance(v, bool | np.bool_):
        return int(v)
    raise _Bad(f"is {_kind(v)}, not an integer")


def _number(v: Any) -> Any:
    if isinstance(v, numbers.Real) and not isinstance(v, bool | np.bool_):
        # a JSON integer stays one (the report echoes some values as the record has them)
        return v if type(v) in (int, float) else float(v)
    raise _Bad(f"is {_kind(v)}, not a number")


def _string(v: Any) -> str:
    if isinstance(v, str):
        return v
    raise _Bad(f"is {_kind(v)}, not a string")


_SCALARS: dict[Any, Converter] = {bool: _boolean, int: _integer, float: _number, str: _string}


def _tuple(tp: Any) -> Converter:
    args = typing.get_args(tp)
    if len(args) == 2 and args[1] is Ellipsis:
        item = _converter(args[0])

        def convert_all(v: Any) -> tuple[Any, ...]:
            if not isinstance(v, list | tuple):
                raise _Bad(f"is {_kind(v)}, not a list")
            return _each([item] * len(v), v)
        return convert_all
    items = [_converter(a) for a in args]

    def convert_fixed(v: Any) -> tuple[Any, ...]:
        if not isinstance(v, list | tuple):
            raise _Bad(f"is {_kind(v)}, not a list")
        if len(v) != len(items):
            raise _Bad(f"has {len(v)} item(s), not {len(items)}")
        return _each(items, v)
    return convert_fixed


def _each(convs: list[Converter], values: Any) -> tuple[Any, ...]:
    """``values`` converted item by item (a failure names the item's index)."""
    out = []
    for i, (conv, x) in enumerate(zip(convs, values, strict=True)):
        try:
            out.append(conv(x))
        except _Bad as bad:
            bad.where.append(f"[{i}]")
            raise
    return tuple(out)


def _mapping(tp: Any) -> Converter:
    conv = _converter((typing.get_args(tp) or (str, Any))[1])

    def convert(v: Any) -> dict[str, Any]:
        if not isinstance(v, Mapping):
            raise _Bad(f"is {_kind(v)}, not an object")
        out: dict[str, Any] = {}
        for k, x in v.items():
            if not isinstance(k, str):
                raise _Bad(f"has a key {k!r} that is not a string")
            try:
                out[k] = conv(x)
            except _Bad as bad:
                bad.where.append(f".{k}")
                raise
        return out
    return convert


__all__ = ["ABSENT_WHEN", "QCRecord", "QCRecordError", "absent_when"]
