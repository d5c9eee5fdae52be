"""Outputs built once per test run and shared read-only by the tests that only read them.

:func:`build_once` builds a folder the first time a test of the run asks for it and records a snapshot of it
(every file's and folder's relative path; a file's size, modification time and SHA-256). Under pytest-xdist the
workers of one run share ``tmp_path_factory.getbasetemp().parent``: the folder is built there under a file
lock, by whichever worker asks first, and the others wait for it and use the same folder. Where ``fcntl`` is
missing (Windows) each worker builds its own.

Nothing may change such a folder: :func:`changes` compares it with its snapshot, and ``tests/conftest.py``
fails every test after which a folder it used (through the fixture named in :func:`shared_folder`) changed,
and the run's end once more. (Under pytest-xdist a
change made by a test on one worker can be reported first by a test on the other; the file list in the message
says what changed.) A test that needs to change an output works on its own copy (``shutil.copytree``) or its
own run. The folder is not made read-only on disk: the suite often runs as root, which ignores the modes, and a
snapshot catches a change whoever runs it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

try:
    import fcntl
except ImportError:     # pragma: no cover - Windows: no lock, each worker builds its own
    fcntl = None


def snapshot(root: Path) -> dict[str, list]:
    """Every path under ``root``: a folder as ``["dir"]``, a link as ``["link", target]``, a file as
    ``["file", size, mtime_ns, sha256]``."""
    out: dict[str, list] = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        if p.is_symlink():
            out[rel] = ["link", os.readlink(p)]
        elif p.is_dir():
            out[rel] = ["dir"]
        else:
            st = p.stat()
            out[rel] = ["file", st.st_size, st.st_mtime_ns, hashlib.sha256(p.read_bytes()).hexdigest()]
    return out


def changes(root: Path, recorded: dict[str, list]) -> list[str]:
    """What differs between ``root`` now and its recorded snapshot: added, removed and changed paths."""
    now = snapshot(root)
    added = [f"added {k}" for k in sorted(now.keys() - recorded.keys())]
    removed = [f"removed {k}" for k in sorted(recorded.keys() - now.keys())]
    changed = [f"changed {k}" for k in sorted(now.keys() & recorded.keys()) if now[k] != recorded[k]]
    return added + removed + changed


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    if fcntl is None:      # pragma: no cover
        yield
        return
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def build_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> tuple[Path, dict[str, list]]:
    """``(folder, snapshot)`` of the folder ``build(folder)`` makes, built once per test run (see the module's
    docstring)."""
    base = tmp_path_factory.getbasetemp()
    if fcntl is not None and os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent          # this run's folder, shared by its workers
    folder = base / f"shared-{name}"
    record = base / f"shared-{name}.json"
    with _locked(base / f"shared-{name}.lock"):
        if not record.is_file():
            if folder.exists():     # left half-built by a worker whose build failed
                shutil.rmtree(folder)
            folder.mkdir()
            build(folder)
            tmp = record.with_suffix(".tmp")
            tmp.write_text(json.dumps(snapshot(folder)))
            tmp.replace(record)
    return folder, json.loads(record.read_text())


#: the shared folders this process uses, by name: (the fixture that gives it, folder, snapshot)
REGISTRY: dict[str, tuple[str, Path, dict[str, list]]] = {}


def shared_folder(tmp_path_factory, name: str, build: Callable[[Path], None], fixture: str | None = None) -> Path:
    """The folder ``build(folder)`` makes, built once per test run (:func:`build_once`; ``name`` is unique in
    the suite), for the fixture named ``fixture`` (default ``name``): every test that uses that fixture fails if
    the folder changed afterwards."""
    folder, recorded = build_once(tmp_path_factory, name, build)
    REGISTRY[name] = (fixture or name, folder, recorded)
    return folder
