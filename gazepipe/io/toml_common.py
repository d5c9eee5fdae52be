"""Shared parts of the TOML readers (:mod:`gazepipe.io.session_toml`, :mod:`gazepipe.io.markerset_toml`):
collecting one-line problems with their dotted keys, reading a TOML file, resolving a path inside a folder.
"""

from __future__ import annotations

import difflib
import json
import math
import os
import re
import tomllib
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from gazepipe.errors import ConfigError
from gazepipe.io.limits import MAX_ID_CHARS, MAX_TOML_BYTES, MAX_TOML_DEPTH, rate_problem

WORD = re.compile(r"[A-Za-z0-9_-]+")
CTRL = re.compile(r"[\x00-\x1f\x7f]")


def key_name(name: Any) -> str:
    """A TOML key as it would be written: bare when possible, else quoted (always one line)."""
    s = str(name)
    return s if WORD.fullmatch(s) else json.dumps(s)


def show(value: Any) -> str:
    """Short one-line rendering of a value for messages."""
    r = repr(value)
    return r if len(r) <= 40 else r[:37] + "..."


def type_name(value: Any) -> str:
    return {bool: "boolean", int: "integer", float: "number", str: "string", list: "array",
            dict: "table"}.get(type(value), type(value).__name__)


def is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def too_long(what: str, value: str) -> str:
    """The problem of an id too long to name a file or folder."""
    return (f"{what} {show(value)} is {len(value)} characters long: at most {MAX_ID_CHARS} (it names output "
            "folders and files)")


def suggest(key: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


#: the page that documents every key of session.toml and markerset.toml (in the repository)
FORMAT_DOC = "docs/session-format.md"
#: the section of :data:`FORMAT_DOC` for each top-level key of a file (the heading's anchor as GitHub makes it)
_DOC_SECTIONS: dict[str, dict[str, str]] = {
    "session": {"schema": "schema", "session": "session", "defaults": "defaults", "takes": "takes"},
    "markerset": {"schema": "schema", "segments": "segmentsname",
                  **{k: k for k in ("up_axis", "units", "root", "target", "clapper", "head_centre", "eye_offset_mm",
                                    "lod", "camera")}},
}
_FILE_SECTIONS = {"session": "sessiontoml", "markerset": "markersettoml"}


def doc_link(doc: str | None, key: str | None) -> str:
    """Where :data:`FORMAT_DOC` explains ``key`` (dotted, ``takes[2].rate_hz``) of a ``doc`` file (``session``
    or ``markerset``): ``docs/session-format.md#takes``; empty for another file or no key."""
    if doc not in _DOC_SECTIONS or not key:
        return ""
    top = re.split(r"[.\[]", key, maxsplit=1)[0]
    return f"{FORMAT_DOC}#{_DOC_SECTIONS[doc].get(top, _FILE_SECTIONS[doc])}"


class FormatError(ConfigError):
    """A problem of a session.toml or markerset.toml key: its line ends with where the key is explained
    (``link``, :func:`doc_link`); ``problem`` is the problem alone."""

    def __init__(self, path: str | Path | None, problem: str, *, key: str | None = None, take: str | None = None,
                 link: str = "") -> None:
        self.link = link
        super().__init__(path, problem, key=key, take=take)

    def one_line(self) -> str:
        line = super().one_line()
        return f"{line} (see {self.link})" if self.link else line


def doc_error(path: str | Path | None, problem: str, *, key: str | None, doc: str | None,
              take: str | None = None) -> ConfigError:
    """A :class:`FormatError` naming the file and the key, its line ending with where the key is explained
    (:func:`doc_link`)."""
    return FormatError(path, problem, key=key, take=take, link=doc_link(doc, key))


class Collector:
    """Gathers the problems of one file; ``doc`` (``session`` or ``markerset``) links each problem naming a key to
    the section of :data:`FORMAT_DOC` that explains it."""

    def __init__(self, path: Path, doc: str | None = None) -> None:
        self.path = path
        self.doc = doc
        self.errors: list[ConfigError] = []
        self.take: str | None = None  # the take id problems are attributed to, while reading a take

    def add(self, key: str | None, problem: str, take: str | None = None) -> None:
        self.errors.append(doc_error(self.path, problem, key=key, doc=self.doc, take=take or self.take))

    def unknown_keys(self, table: dict, known: Sequence[str], prefix: str, what: str = "key") -> None:
        for name in table:
            if name not in known:
                self.add(f"{prefix}{key_name(name)}", f"unknown {what} {name!r}{suggest(str(name), known)}")

    def table(self, value: Any, key: str) -> dict | None:
        if isinstance(value, dict):
            return value
        self.add(key, f"must be a table, got {type_name(value)}")
        return None

    def string(self, table: dict, name: str, key: str, *, required: bool = False) -> str | None:
        if name not in table:
            if required:
                self.add(key, "missing (a string is required)")
            return None
        value = table[name]
        if not isinstance(value, str):
            self.add(key, f"must be a string, got {type_name(value)} {show(value)}")
            return None
        return value

    def word(self, table: dict, name: str, key: str, what: str, *, required: bool = False) -> str | None:
        value = self.string(table, name, key, required=required)
        if value is not None and not WORD.fullmatch(value):
            self.add(key, f"bad {what} {show(value)}: use only letters, digits, '_' and '-'")
            return None
        if value is not None and len(value) > MAX_ID_CHARS:
            self.add(key, too_long(what, value))
            return None
        return value

    def number(self, table: dict, name: str, key: str, *, positive: bool = False) -> float | None:
        if name not in table:
            return None
        value = table[name]
        if not is_number(value):
            self.add(key, f"must be a finite number, got {type_name(value)} {show(value)}")
            return None
        if positive and value <= 0:
            self.add(key, f"must be > 0, got {show(value)}")
            return None
        return float(value)

    def rate(self, table: dict, name: str, key: str) -> float | None:
        """A rate in Hz: a number within :data:`~gazepipe.io.limits.MIN_RATE_HZ` -
        :data:`~gazepipe.io.limits.MAX_RATE_HZ` (the bounds every capture file's rate is held to)."""
        value = self.number(table, name, key, positive=True)
        if value is not None and (problem := rate_problem(value)) is not None:
            self.add(key, problem)
            return None
        return value

    def marker_name(self, value: Any, key: str) -> str | None:
        if not isinstance(value, str):
            self.add(key, f"must be a marker name (string), got {type_name(value)} {show(value)}")
            return None
        if not value or value != value.strip() or CTRL.search(value):
            self.add(key, f"bad marker name {show(value)}: empty, padded or with control characters")
            return None
        return value

    def schema(self, doc: dict) -> None:
        if "schema" in doc and (type(doc["schema"]) is not int or doc["schema"] != 1):
            self.add("schema", f"unsupported schema {show(doc['schema'])} (this version reads schema = 1)")


def read_document(path: Path, col: Collector, top_keys: Sequence[str]) -> dict | None:
    """A gazepipe TOML file's top-level table: read (:func:`read_toml`), its ``schema`` checked and keys not in
    ``top_keys`` reported to ``col``. None when it cannot be read or parsed."""
    doc = read_toml(path, col)
    if doc is not None:
        col.schema(doc)
        col.unknown_keys(doc, top_keys, "")
    return doc


def read_toml(path: Path, col: Collector) -> dict | None:
    """The parsed TOML document, or None after reporting why it cannot be read to ``col``.

    Files over :data:`~gazepipe.io.limits.MAX_TOML_BYTES` are refused before they are read, and documents
    nested deeper than :data:`~gazepipe.io.limits.MAX_TOML_DEPTH` after they are parsed (deeper than Python's
    recursion limit, the parser itself gives up: that is refused the same way).
    """
    try:
        size = path.stat().st_size
        if path.is_file() and size > MAX_TOML_BYTES:
            col.add(None, f"file is {size} bytes: a gazepipe TOML file is at most {MAX_TOML_BYTES >> 20} MiB")
            return None
        with open(path, "rb") as fh:
            raw = fh.read(MAX_TOML_BYTES + 1)
    except FileNotFoundError:
        col.add(None, "file not found")
        return None
    except IsADirectoryError:
        col.add(None, "is a directory, not a TOML file")
        return None
    except OSError as exc:
        col.add(None, f"cannot read: {exc.strerror or exc}")
        return None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        col.add(None, f"not TOML: not UTF-8 text (byte {exc.start})")
        return None
    if len(raw) > MAX_TOML_BYTES:   # not a regular file (a pipe), or it grew since stat
        col.add(None, f"more than {MAX_TOML_BYTES >> 20} MiB: a gazepipe TOML file is at most "
                      f"{MAX_TOML_BYTES >> 20} MiB")
        return None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        col.add(None, f"TOML syntax error: {exc}")
        return None
    except RecursionError:
        col.add(None, f"arrays or tables nested too deep (at most {MAX_TOML_DEPTH} levels)")
        return None
    if _depth(doc) > MAX_TOML_DEPTH:
        col.add(None, f"arrays or tables nested too deep (at most {MAX_TOML_DEPTH} levels)")
        return None
    return doc


def _depth(doc: Any) -> int:
    """How deep arrays and tables nest in a parsed document (the document itself is level 1), without
    recursion: it stops counting one level past :data:`~gazepipe.io.limits.MAX_TOML_DEPTH`."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(doc, 1)]
    while stack:
        node, level = stack.pop()
        deepest = max(deepest, level)
        if level > MAX_TOML_DEPTH:
            break
        children = node.values() if isinstance(node, dict) else node
        stack.extend((c, level + 1) for c in children if isinstance(c, dict | list))
    return deepest


def resolve_inside(root: Path, value: str, key: str, col: Collector, take: str | None = None,
                    must_exist: bool = True) -> str | None:
    """Absolute path of ``value`` (relative to ``root``), or ``None`` after reporting why it is unusable.

    What the path finally points to (symbolic links followed) must lie inside ``root``. With ``must_exist``
    the result is that real path, and it must be a file. Without, the result is the path as listed
    (normalised, links kept): whether it exists is then its reader's matter, and every message about it
    names the file the user listed, not a link's target.
    """
    if not value or CTRL.search(value):
        col.add(key, f"bad path {show(value)}: empty or with control characters", take)
        return None
    try:
        p = (root / value).resolve()
        inside = p == root or p.is_relative_to(root)
        if not inside:
            col.add(key, f"path {show(value)} escapes the session folder {root}", take)
            return None
        if must_exist and not p.is_file():
            col.add(key, f"{'not a file' if p.exists() else 'file not found'}: {p}", take)
            return None
    except (OSError, RuntimeError, ValueError) as exc:
        listed = os.path.normpath(root / value)
        if not must_exist and not isinstance(exc, ValueError) and Path(listed).is_relative_to(root):
            # a link loop, a name too long, a folder that cannot be searched: the file cannot be read, which
            # its reader says (failing its take), as for a missing file; nothing outside the folder is read
            return listed
        col.add(key, f"bad path {show(value)}: {exc}", take)
        return None
    return str(p) if must_exist else os.path.normpath(root / value)
