"""What a stage's code is, as a digest: the normalised syntax trees of the modules its ``run`` function reaches.

A unit's code identity (:func:`gazepipe.pipeline.runner.code_identity`) covers the code that computes it, so an
edit that changes what a stage does re-runs its units (and, through their code identities, their readers')
without anyone bumping a version by hand; an edit of comments, docstrings or layout changes nothing.

What a ``run`` function reaches, read from the source (nothing is imported):

- in its own module (a DAG module wiring many stages), the top-level definitions it names, and those they name,
  transitively: an edit of another stage's adapter there leaves it alone;
- every module of the same top-level package those definitions import (at module level or inside a function),
  whole, and the modules those import, transitively (a package's ``__init__`` where it is imported itself);
- the third-party distributions all of them import, by name and version (:func:`importlib.metadata.version`),
  and Python's version: an upgrade that may change the numbers re-runs the stages that use it.

A module's syntax tree is normalised before hashing: docstrings and other bare string statements dropped, no
line or column numbers, fields that are empty or None left out (so the text does not depend on the Python version
adding a field). Modules and definitions are hashed in sorted order: the digest depends on neither the folder the
package lies in, nor the hash seed, nor the order of imports. Digests are computed once per process.
"""

from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import importlib.metadata
import json
import os
import sys
import types
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Code:
    """The code a ``run`` function runs.

    digest : sha256 (hex) of the normalised syntax trees of the definitions and modules it reaches.
    modules : the modules it reaches, sorted (its own module last, for the definitions named there).
    libraries : the third-party distributions they import, with their installed versions, by name.
    """

    digest: str
    modules: tuple[str, ...]
    libraries: Mapping[str, str]


def code_of(fn: Callable[..., Any], memo: MutableMapping[str, Any] | None = None) -> Code:
    """The code ``fn`` runs; computed once per process for each function. A function made inside another (a
    factory's) counts as the top-level function that made it.

    ``memo`` keeps what each module's source gave (its digest and imports) between processes, keyed by a hash
    of the source itself (and of the Python version): a later run that finds a module unchanged does not parse
    it again. New entries are added to it.
    """
    key = (fn.__module__, fn.__code__.co_qualname.partition(".")[0])
    if _path(key[0]) is None:   # not in a package on disk (a test's stand-in, a script's function)
        return _compiled(fn)
    if key not in _CODES:
        if memo is not None:
            _MEMO.update((k, v) for k, v in memo.items() if k not in _MEMO)
        shared = _shared_memo(key[0].partition(".")[0])
        _MEMO.update((k, v) for k, v in shared.items() if k not in _MEMO)
        known = len(_MEMO)
        _CODES[key] = _code_of(*key)
        if len(_MEMO) != known:
            _keep_shared_memo(key[0].partition(".")[0])
    if memo is not None:
        memo.update((k, v) for k, v in _MEMO.items() if k not in memo)
    return _CODES[key]


def _shared_memo_path(top: str) -> Path | None:
    """Where the memo beside the package's own bytecode cache lies (``<package>/__pycache__/``; None when
    Python writes no bytecode, ``sys.dont_write_bytecode``)."""
    if sys.dont_write_bytecode or sys.pycache_prefix or not hasattr(sys.modules.get(top), "__path__"):
        return None
    root = Path(sys.modules[top].__file__ or "").parent
    return root / "__pycache__" / f"codehash.{sys.implementation.cache_tag}.json"


@functools.cache
def _shared_memo(top: str) -> dict[str, Any]:
    """The memo kept beside the package's bytecode (read once per process; its entries are keyed by the hashes
    of the sources they come from, so an entry is never stale): a process planning a run in a new output
    folder does not parse the modules again."""
    path = _shared_memo_path(top)
    try:
        got = json.loads(path.read_text()) if path is not None and path.is_file() else {}
    except (OSError, ValueError):
        return {}
    return got if isinstance(got, dict) else {}


def _keep_shared_memo(top: str) -> None:
    """Write the memo beside the package's bytecode, whole and at once (another process reads either the old
    file or the new one); where that folder cannot be written, nothing is kept, as Python keeps no bytecode."""
    path = _shared_memo_path(top)
    if path is None:
        return
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(exist_ok=True)
        tmp.write_text(json.dumps(_MEMO, sort_keys=True))
        os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError):
            tmp.unlink()


#: the code of each ``run`` function seen in this process, by (module, top-level name)
_CODES: dict[tuple[str, str], Code] = {}
#: what a module's source gave: ``[digest, imports]`` by :func:`_source_key`
_MEMO: dict[str, Any] = {}
#: bumped when what a digest covers changes (every stage then re-runs once)
ALGORITHM = "1"


def _compiled(fn: Callable[..., Any]) -> Code:
    """The code of a function without a module source to read: a digest of its compiled code (instructions,
    names, constants; no line numbers), Python's version as its only library."""
    def canon(code: Any) -> str:
        if isinstance(code, types.CodeType):
            consts = ",".join(canon(c) for c in code.co_consts)
            return f"code({code.co_code.hex()};{code.co_names};{code.co_varnames};{code.co_freevars};{consts})"
        if isinstance(code, frozenset):
            return "frozenset(" + ",".join(sorted(canon(c) for c in code)) + ")"
        if isinstance(code, tuple):
            return "(" + ",".join(canon(c) for c in code) + ")"
        return repr(code)

    digest = hashlib.sha256(f"{fn.__module__}:{fn.__qualname__}\0{canon(fn.__code__)}".encode()).hexdigest()
    return Code(digest, (fn.__module__,), {"python": f"{sys.version_info.major}.{sys.version_info.minor}"})


def library_changes(old: Mapping[str, str] | None, new: Mapping[str, str]) -> str:
    """The libraries whose versions differ between two :attr:`Code.libraries`, as text (``numpy 2.1.0 ->
    2.2.0``; ``-`` for one absent); empty when none differ."""
    old = old or {}
    return ", ".join(f"{name} {old.get(name, '-')} -> {new.get(name, '-')}" for name in sorted({*old, *new})
                     if old.get(name) != new.get(name))


# ------------------------------------------------------------------------------------------ syntax trees

def _canon(node: Any) -> str:
    """A node as text: its type and non-empty fields, recursively (no positions)."""
    if isinstance(node, ast.AST):
        fields = [f"{name}={_canon(value)}" for name, value in ast.iter_fields(node)
                  if value is not None and value != []]
        return f"{type(node).__name__}({','.join(fields)})"
    if isinstance(node, list):
        return f"[{','.join(_canon(v) for v in node)}]"
    return repr(node)


def _bare_string(stmt: ast.stmt) -> bool:
    return isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) and isinstance(stmt.value.value, str)


def _bodies(node: ast.AST) -> Iterator[tuple[ast.AST, str, list[ast.stmt]]]:
    """The statement lists directly under ``node``: ``(owner, field, statements)``."""
    for name in ("body", "orelse", "finalbody"):
        body = getattr(node, name, None)
        if isinstance(body, list) and body and isinstance(body[0], ast.stmt):
            yield node, name, body
    for sub in getattr(node, "handlers", None) or getattr(node, "cases", None) or ():
        yield sub, "body", sub.body


def _statements(tree: ast.Module) -> Iterator[ast.stmt]:
    """Every statement of ``tree`` at any depth (expressions are not entered: imports and docstrings are
    statements)."""
    todo: list[ast.AST] = [tree]
    while todo:
        node = todo.pop()
        for _, _, body in _bodies(node):
            yield from body
            todo.extend(body)


def _strip_docstrings(tree: ast.Module) -> ast.Module:
    """``tree`` without its bare string statements (docstrings: they change nothing a stage computes)."""
    todo: list[ast.AST] = [tree]
    while todo:
        node = todo.pop()
        for owner, name, body in list(_bodies(node)):
            kept = [s for s in body if not _bare_string(s)]
            setattr(owner, name, kept or [ast.Pass()])
            todo.extend(kept)
    return tree


@functools.cache
def _index(top: str) -> Mapping[str, Path]:
    """Every module of the top-level package ``top`` (imported already: a ``run`` function's) by name, found
    on disk without importing any of them."""
    root = Path(sys.modules[top].__file__ or "").parent
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.with_suffix("").relative_to(root.parent).parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _path(module: str) -> Path | None:
    """Where ``module``'s source is, when it belongs to an imported package (None otherwise)."""
    top = module.partition(".")[0]
    if not hasattr(sys.modules.get(top), "__path__"):
        return None
    return _index(top).get(module)


def _tree(module: str, source: bytes | None = None) -> ast.Module | None:
    """The module's syntax tree without docstrings; None for a module without Python source."""
    path = _path(module)
    if path is None:
        return None
    return _strip_docstrings(ast.parse(path.read_bytes() if source is None else source))


def _source_key(module: str, source: bytes) -> str:
    head = f"{ALGORITHM}\0{sys.version_info.major}.{sys.version_info.minor}\0{module}\0".encode()
    return hashlib.sha256(head + source).hexdigest()


@functools.cache
def _facts(module: str) -> tuple[str, tuple[tuple[str, str], ...]]:
    """The digest of a module's normalised syntax tree and its imports as written (``(base, name)``: ``name``
    empty for ``import base``; relative imports made absolute), from the memo when its source was seen."""
    path = _path(module)
    if path is None:
        return "", ()
    source = path.read_bytes()
    key = _source_key(module, source)
    hit = _MEMO.get(key)
    if isinstance(hit, list) and len(hit) == 2:
        return str(hit[0]), tuple((str(b), str(n)) for b, n in hit[1])
    tree = _tree(module, source)
    assert tree is not None
    digest = hashlib.sha256(_canon(tree).encode()).hexdigest()
    raw = sorted({pair for node in _statements(tree) if isinstance(node, ast.Import | ast.ImportFrom)
                  for pair in _written(node, module)})
    _MEMO[key] = [digest, [list(p) for p in raw]]
    return digest, tuple(raw)


# ------------------------------------------------------------------------------------------------ imports

def _is_module(name: str) -> bool:
    return _path(name) is not None


def _package_of(module: str) -> str:
    path = _path(module)
    return module if path is not None and path.name == "__init__.py" else module.rpartition(".")[0]


def _written(node: ast.Import | ast.ImportFrom, module: str) -> Iterator[tuple[str, str]]:
    """``(base, name)`` for each name an import statement of ``module`` binds (``name`` empty for ``import
    base``), relative imports made absolute."""
    if isinstance(node, ast.Import):
        for a in node.names:
            yield a.name, ""
        return
    base = node.module or ""
    if node.level:
        parts = _package_of(module).split(".")
        base = ".".join(parts[: len(parts) - (node.level - 1)] + ([node.module] if node.module else []))
    for a in node.names:
        yield base, a.name


def _resolved(base: str, name: str, module: str) -> str:
    """The module an import of ``module`` brings in: ``base.name`` when that is a module of the same
    top-level package (``from package import module``), else ``base`` (another package's are not looked up)."""
    full = f"{base}.{name}"
    ours = bool(name) and base.partition(".")[0] == module.partition(".")[0]
    return full if ours and _is_module(full) else base


def _imported(node: ast.Import | ast.ImportFrom, module: str) -> Iterator[tuple[str, str]]:
    """``(bound name, module)`` for each name an import binds."""
    for alias, (base, name) in zip(node.names, _written(node, module), strict=True):
        if name:
            yield alias.asname or name, _resolved(base, name, module)
        else:
            yield alias.asname or base.partition(".")[0], base


@functools.cache
def _imports_of(module: str) -> frozenset[str]:
    """Every module ``module`` imports anywhere (module level, functions, ``TYPE_CHECKING`` blocks)."""
    return frozenset(_resolved(base, name, module) for base, name in _facts(module)[1])


def _closure(modules: set[str], top: str) -> tuple[set[str], set[str]]:
    """The modules of package ``top`` that ``modules`` import, transitively (with ``modules``), and the other
    top-level modules they import. A package's ``__init__`` counts only where it is imported itself."""
    seen: set[str] = set()
    other: set[str] = set()
    todo = sorted(modules)
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        if m.partition(".")[0] != top:
            other.add(m.partition(".")[0])
            continue
        seen.add(m)
        todo.extend(sorted(_imports_of(m) - seen))
    return seen, other


# ------------------------------------------------------------------------------- one module's definitions

def _top_level(tree: ast.Module, module: str) -> tuple[dict[str, list[ast.stmt]], dict[str, str]]:
    """A module's top-level definitions (functions, classes, assignments) by the names they bind, and the
    modules its top-level imports bind by name."""
    defs: dict[str, list[ast.stmt]] = {}
    imports: dict[str, str] = {}
    for stmt in tree.body:
        if isinstance(stmt, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            defs.setdefault(stmt.name, []).append(stmt)
        elif isinstance(stmt, ast.Assign | ast.AnnAssign | ast.AugAssign):
            targets = stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]
            for t in targets:
                for n in ast.walk(t):
                    if isinstance(n, ast.Name):
                        defs.setdefault(n.id, []).append(stmt)
        elif isinstance(stmt, ast.Import | ast.ImportFrom):
            imports.update(_imported(stmt, module))
        elif isinstance(stmt, ast.If):   # e.g. ``if TYPE_CHECKING:`` imports
            for sub in stmt.body + stmt.orelse:
                if isinstance(sub, ast.Import | ast.ImportFrom):
                    imports.update(_imported(sub, module))
    return defs, imports


def _reached(module: str, name: str, source: bytes) -> tuple[list[ast.stmt], set[str]]:
    """The top-level definitions of ``module`` (its ``source``) that ``name`` reaches (by the names they use,
    transitively), in source order, and the modules they import or name."""
    tree = _tree(module, source)
    assert tree is not None
    defs, imports = _top_level(tree, module)
    if name not in defs:
        raise ValueError(f"{module} defines no top-level {name}")
    names, todo, used = set(), [name], set()
    while todo:
        n = todo.pop()
        if n in names:
            continue
        names.add(n)
        for stmt in defs[n]:
            for node in ast.walk(stmt):
                if isinstance(node, ast.Name) and node.id not in names:
                    if node.id in defs:
                        todo.append(node.id)
                    elif node.id in imports:
                        used.add(imports[node.id])
                elif isinstance(node, ast.Import | ast.ImportFrom):
                    used.update(m for _, m in _imported(node, module))
    stmts = {id(s): s for n in names for s in defs[n]}
    order = [s for s in tree.body if id(s) in stmts]
    return order, used


# ------------------------------------------------------------------------------------------------- digest

@functools.cache
def _distributions() -> Mapping[str, list[str]]:
    return importlib.metadata.packages_distributions()


def _providers(top: str) -> dict[str, str]:
    """The distributions providing the top-level module ``top``, with their versions: the one of that name
    when there is one (most are), else those naming it in their metadata (a slower look through every
    installed distribution's files, done once)."""
    try:
        dist = importlib.metadata.distribution(top)
        return {dist.metadata["Name"]: dist.version}
    except importlib.metadata.PackageNotFoundError:
        pass
    out: dict[str, str] = {}
    for name in _distributions().get(top, ()):
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return out


@functools.cache
def _installed() -> tuple[str, ...]:
    """The distribution metadata folders on ``sys.path`` (``numpy-2.1.0.dist-info``…): their names carry the
    versions, so they change with any install or upgrade."""
    out: set[str] = set()
    for entry in sys.path:
        try:
            out.update(n for n in os.listdir(entry or ".") if n.endswith((".dist-info", ".egg-info")))
        except OSError:
            continue
    return tuple(sorted(out))


def _libraries(tops: set[str]) -> dict[str, str]:
    """The installed distributions providing the third-party top-level modules ``tops`` (the standard library
    left out), by name, with their versions, and Python's (``python``: major.minor); from the memo while nothing
    was installed since."""
    tops = tops - set(sys.stdlib_module_names) - {"__future__"}
    key = hashlib.sha256("\0".join(["libraries", ALGORITHM, *sorted(tops), "", *_installed()]).encode()).hexdigest()
    hit = _MEMO.get(key)
    if isinstance(hit, dict):
        return {str(k): str(v) for k, v in hit.items()}
    out: dict[str, str] = {}
    for top in sorted(tops):
        out.update(_providers(top))
    out["python"] = f"{sys.version_info.major}.{sys.version_info.minor}"
    _MEMO[key] = out = dict(sorted(out.items()))
    return out


def _own(module: str, name: str) -> tuple[str, tuple[str, ...]]:
    """The digest of the definitions of ``module`` that ``name`` reaches (:func:`_reached`), and the modules they
    import or name; from the memo when the module's source was seen."""
    path = _path(module)
    if path is None:
        raise ValueError(f"no Python source for module {module}")
    source = path.read_bytes()
    key = f"{_source_key(module, source)}:{name}"
    hit = _MEMO.get(key)
    if isinstance(hit, list) and len(hit) == 2:
        return str(hit[0]), tuple(str(m) for m in hit[1])
    stmts, used = _reached(module, name, source)
    h = hashlib.sha256(f"{module}:{name}\0".encode())
    for stmt in stmts:
        h.update(_canon(stmt).encode())
        h.update(b"\n")
    _MEMO[key] = [h.hexdigest(), sorted(used)]
    return h.hexdigest(), tuple(sorted(used))


def _code_of(module: str, name: str) -> Code:
    top = module.partition(".")[0]
    own, used = _own(module, name)
    inside, other = _closure({m for m in used if m.partition(".")[0] == top}, top)
    other |= {m.partition(".")[0] for m in used if m.partition(".")[0] != top}
    inside.discard(module)
    h = hashlib.sha256()
    for m in sorted(inside):
        h.update(f"{m}\0{_facts(m)[0]}\n".encode())
    h.update(f"{own}\n".encode())
    return Code(h.hexdigest(), (*sorted(inside), module), _libraries(other))
