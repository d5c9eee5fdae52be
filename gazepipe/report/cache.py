"""What a report keeps between runs under ``OUT/.gazepipe/``: each take's checks (:class:`CheckCache`) and the
figures drawn before (:class:`FigureCache`), each file named by a hash of everything it was computed from, so
a hit gives the bytes a new computation would. A run's workers fill both as they go
(:mod:`gazepipe.report.validate`); the report that ends the run reads them back.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from gazepipe import __version__
from gazepipe.pipeline.lock import pid_alive
from gazepipe.pipeline.state import OutLayout
from gazepipe.report import checks as C
from gazepipe.report.collect import PLOT_TABLES, DatasetData, TakeEntry
from gazepipe.report.html import Figure

#: the take tables the checks read (their sizes and modification times are part of a take's checks key)
CHECK_TABLES = ("markers_raw", "eyes", "sync", "markers", "joints")


@functools.lru_cache(maxsize=1)
def code_version() -> bytes:
    """What the cached checks and figures depend on besides their data: every source file of gazepipe (the
    checks, the plots, the captions, the table readers…) and the versions of the libraries that compute and draw
    them."""
    from importlib.metadata import PackageNotFoundError, version

    import gazepipe

    h = hashlib.sha256(f"gazepipe {__version__} report figures 1\0".encode())
    root = Path(gazepipe.__file__).parent
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    for lib in ("matplotlib", "numpy", "scipy", "pyarrow"):
        try:
            h.update(f"{lib} {version(lib)}\0".encode())
        except PackageNotFoundError:
            h.update(f"{lib} -\0".encode())
    return h.digest()


def feed(h: Any, v: Any) -> None:
    """Hash ``v`` (arrays, numbers, strings, lists, dicts, None) with its types and shapes."""
    if isinstance(v, np.ndarray):
        if v.dtype == object:
            v = v.astype(str)
        h.update(f"nd {v.dtype.str} {v.shape}\0".encode())
        h.update(np.ascontiguousarray(v).tobytes())
    elif isinstance(v, dict):
        h.update(f"dict {len(v)}\0".encode())
        for k in sorted(v, key=str):
            feed(h, str(k))
            feed(h, v[k])
    elif isinstance(v, list | tuple):
        h.update(f"list {len(v)}\0".encode())
        for x in v:
            feed(h, x)
    else:
        h.update(f"{type(v).__name__} {v!r}\0".encode())


def feed_json(h: Any, v: Any) -> None:
    """Hash ``v``, a structure read from JSON (a unit record, a build record), as its canonical JSON text: one
    call, where :func:`feed` walks every item of records that hold thousands."""
    h.update(b"json\0" + json.dumps(v, sort_keys=True, separators=(",", ":"), default=repr).encode() + b"\0")


def feed_tables(h: Any, layout: OutLayout, e: TakeEntry, names: Any) -> bool:
    """Hash the bytes of a take's tables ``names`` (a missing one as none); False when one cannot be read."""
    for name in names:
        path = layout.table(e.session, e.take, name)
        feed(h, name)
        try:
            feed(h, hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None)
        except OSError:
            return False
    return True


class _KeyedFiles:
    """JSON files under ``OUT/.gazepipe/<dirname>/`` named by key: written whole then renamed (a reader never
    sees half a file), not synced (losing one only costs time), never written once the run ``parent_pid`` is
    gone; :meth:`prune` deletes those the report written last did not use."""

    DIRNAME = ""

    def __init__(self, layout: OutLayout, parent_pid: int | None = None) -> None:
        self.layout = layout
        self.dir = layout.state / self.DIRNAME
        self.used: set[str] = set()
        #: a run's process, when a worker of that run writes: nothing is written once it is gone
        self.parent_pid = parent_pid

    def _load(self, key: str | None) -> Any:
        if key is None:
            return None
        self.used.add(key)
        try:
            return json.loads((self.dir / f"{key}.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None

    def _store(self, key: str | None, entry: Any) -> None:
        try:
            data = json.dumps(entry, ensure_ascii=False, allow_nan=False).encode()
        except ValueError:
            return
        self._write(key, f"{key}.json", data)

    def _write(self, key: str | None, name: str, data: bytes) -> None:
        """``data`` into the file ``name`` of ``key``, whole then renamed; nothing once the run is gone."""
        if key is None or (self.parent_pid is not None and not pid_alive(self.parent_pid)):
            return
        self.used.add(key)
        tmp = self.layout.tmp / f".{name}.{os.getpid()}.part"
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            self.layout.tmp.mkdir(parents=True, exist_ok=True)
            tmp.write_bytes(data)
            os.replace(tmp, self.dir / name)
        except OSError:
            tmp.unlink(missing_ok=True)

    def prune(self) -> None:
        """Delete the files the report written last does not use."""
        for path in sorted(self.dir.glob("*.*")) if self.dir.is_dir() else []:
            if path.stem not in self.used:
                path.unlink(missing_ok=True)


class CheckCache(_KeyedFiles):
    """Each take's checks (all but ``stages``, whose freshness depends on the inputs now), under
    ``OUT/.gazepipe/report_checks/``, named by a hash of the take's settings and unit records, the size and
    modification time of every table the checks read, the thresholds and the source of gazepipe."""

    DIRNAME = "report_checks"

    def key(self, e: TakeEntry, th: C.Thresholds) -> str | None:
        """The key of a take's checks (``None`` when a table cannot be looked at)."""
        h = hashlib.sha256(code_version() + b"checks\0")
        feed(h, [e.key, e.kind, e.pose, e.has_video, e.has_eyes])
        feed_json(h, e.records)
        feed(h, th.to_dict())
        for name in CHECK_TABLES:
            path = self.layout.table(e.session, e.take, name)
            try:
                st = path.stat()
                feed(h, [name, st.st_size, st.st_mtime_ns])
            except FileNotFoundError:
                feed(h, [name, None])
            except OSError:
                return None
        return h.hexdigest()[:40]

    def get(self, key: str | None) -> list[C.Check] | None:
        entry = self._load(key)
        try:
            return None if entry is None else [C.Check(**d) for d in entry["checks"]]
        except (KeyError, TypeError):
            return None

    def put(self, key: str | None, checks: list[C.Check]) -> None:
        self._store(key, {"checks": [c.to_dict() for c in checks]})


class DatasetCache(_KeyedFiles):
    """Each dataset's part of the report (its report.json entry, the split of each of its takes, the key of its
    figures), under ``OUT/.gazepipe/report_datasets/``, named by a hash of the dataset's build record, the name,
    size and modification time of every file in its folder, the thresholds and the source of gazepipe."""

    DIRNAME = "report_datasets"

    def key(self, name: str, path: Path | None, record: dict[str, Any] | None, th: C.Thresholds) -> str | None:
        h = hashlib.sha256(code_version() + b"dataset part\0")
        feed(h, [name, th.to_dict()])
        feed_json(h, record)
        try:
            for f in sorted(path.rglob("*")) if path is not None else []:
                st = f.stat()
                feed(h, [f.relative_to(path).as_posix() if path is not None else "", st.st_size, st.st_mtime_ns])
        except OSError:
            return None
        return h.hexdigest()[:40]

    def get(self, key: str | None) -> dict[str, Any] | None:
        entry = self._load(key)
        return entry if isinstance(entry, dict) and {"entry", "take_splits", "figure_key"} <= set(entry) else None

    def put(self, key: str | None, part: dict[str, Any]) -> None:
        self._store(key, part)


def stored_checks(checks: list[C.Check]) -> list[C.Check]:
    """``checks`` as :class:`CheckCache` gives them back (JSON values: tuples as lists, numpy numbers as
    Python's, non-finite numbers as ``None``), so a report is the same bytes whether they were cached or not."""
    return [C.Check(**d) for d in json.loads(json.dumps([c.to_dict() for c in checks], allow_nan=False))]


class FigureCache(_KeyedFiles):
    """Figures drawn before, under ``OUT/.gazepipe/report_plots/``, one file per take or dataset, named by a hash
    of everything its plots are drawn from: the bytes of the tables (a take) or the sampled rows (a dataset), the
    unit records and markerset they use, the source of gazepipe and the versions of matplotlib, numpy, scipy and
    pyarrow. Drawing is most of a validation's time, and a run draws the plots its report has: a ``gazepipe
    validate`` after it reads them back (no matplotlib at all) with the same bytes as drawing them again. What
    the report written last does not use is deleted.
    """

    DIRNAME = "report_plots"

    def take_key(self, e: TakeEntry, markerset: Any) -> str | None:
        """The key of a take's plots (``None``: a table cannot be read, so nothing is cached)."""
        h = hashlib.sha256(code_version() + b"take\0")
        feed(h, e.key)
        if not feed_tables(h, self.layout, e, PLOT_TABLES):
            return None
        feed_json(h, {stage: {k: r.get(k) for k in ("status", "qc", "components")} for stage, r in e.records.items()})
        feed(h, repr(markerset))
        return h.hexdigest()[:40]

    def dataset_key(self, d: DatasetData) -> str:
        h = hashlib.sha256(code_version() + b"dataset\0")
        feed(h, d.name)
        feed(h, d.info.get("features"))
        smp = d.all_rows
        feed(h, None if smp is None else [smp.columns, smp.pose, smp.n_total, smp.n_total_by_pose])
        return h.hexdigest()[:40]

    def get(self, key: str | None) -> tuple[list[Figure], list[str]] | None:
        entry = self._load(key)
        try:
            if entry is None:
                return None
            return [Figure(f["title"], f["caption"], f["svg"]) for f in entry["figures"]], \
                [str(n) for n in entry["notes"]]
        except (KeyError, TypeError):
            return None

    def put(self, key: str | None, figs: list[Figure], notes: list[str]) -> None:
        self._store(key, {"figures": [{"title": f.title, "caption": f.caption, "svg": f.svg} for f in figs],
                          "notes": notes})


class ReplayCache(_KeyedFiles):
    """Each take's 3D replay page (:mod:`gazepipe.report.replay_page`) as made before, under
    ``OUT/.gazepipe/report_replays/<key>.html``, the key a hash of the bytes of the tables it is made from
    (:data:`gazepipe.report.replay.REPLAY_TABLES`), the unit records and markerset it uses, the source of
    gazepipe and the versions of plotly and the libraries. A run's workers make the pages of the takes its
    report shows; the report copies them into ``qc/replay/``. A take with nothing to replay is kept as a
    ``<key>.txt`` saying why. Written whole then renamed, never once the run ``parent_pid`` is gone."""

    DIRNAME = "report_replays"

    def key(self, e: TakeEntry, markerset: Any) -> str | None:
        from importlib.metadata import PackageNotFoundError, version

        from gazepipe.report.replay import REPLAY_TABLES

        h = hashlib.sha256(code_version() + b"replay\0")
        try:
            h.update(f"plotly {version('plotly')}\0".encode())
        except PackageNotFoundError:
            h.update(b"plotly -\0")
        feed(h, e.key)
        feed(h, [e.kind, e.pose])
        if not feed_tables(h, self.layout, e, REPLAY_TABLES):
            return None
        feed_json(h, {stage: {k: r.get(k) for k in ("status", "qc", "components", "error")}
                      for stage, r in e.records.items()})
        feed(h, repr(markerset))
        return h.hexdigest()[:40]

    def get(self, key: str | None) -> tuple[bytes | None, str | None] | None:
        """``(page, None)``, ``(None, why there is none)``, or ``None`` when not made before."""
        if key is None:
            return None
        self.used.add(key)
        try:
            return (self.dir / f"{key}.html").read_bytes(), None
        except OSError:
            pass
        try:
            return None, (self.dir / f"{key}.txt").read_text(encoding="utf-8")
        except OSError:
            return None

    def put(self, key: str | None, page: bytes | None, why: str | None = None) -> None:
        """Keep ``page`` (or, when there is none, ``why``) under ``key``."""
        if page is not None:
            self._write(key, f"{key}.html", page)
        else:
            self._write(key, f"{key}.txt", (why or "").encode())
