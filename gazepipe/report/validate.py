"""``gazepipe validate``: run every check on an output folder and write ``qc/report.json``, ``qc/takes.parquet``
and ``qc/report.html``.

Takes are processed one at a time (their tables are dropped after their checks and plots), datasets one at a
time. Same output folder, same thresholds → byte-identical files: nothing in them depends on the clock, the
machine or the folder's absolute path.

Every take and dataset is checked; plots are drawn for every dataset but, by default, only for the
:data:`DEFAULT_PLOT_TAKES` worst takes (:func:`take_rank_key`: failed first): drawing is most of a validation's
time (a tenth of a second or more a take), checking is not. ``plot_takes`` / ``--plot-takes N|all`` and
``plot_named`` / ``--plot-take SESSION/TAKE`` ask for more, and the page names the takes plotted and says how.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe import __version__
from gazepipe.errors import ConfigError
from gazepipe.io.parquet import count_rows, write_table
from gazepipe.pipeline.atomic import atomic_path
from gazepipe.pipeline.lock import OutputLock
from gazepipe.pipeline.state import OutLayout
from gazepipe.report import checks as C
from gazepipe.report import checks_datasets as D
from gazepipe.report.cache import CheckCache, DatasetCache, FigureCache, ReplayCache, stored_checks
from gazepipe.report.collect import (
    PLOT_TABLES,
    QC_TYPES,
    DatasetData,
    TakeEntry,
    TakeTables,
    dataset_dirs,
    dataset_records,
    has_plot_tables,
    load_dataset,
    load_sessions,
    load_take_tables,
    open_output,
    take_entries,
    unit_states,
)
from gazepipe.report.html import Figure, PlotSelection, render_html
from gazepipe.report.schema import REPORT_SCHEMA_VERSION, TAKES_SCHEMA
from gazepipe.stages.clean.qc import CleanQC
from gazepipe.stages.eyes.qc import EyesQC
from gazepipe.stages.face.qc import FaceQC
from gazepipe.stages.frames.qc import FramesQC
from gazepipe.stages.ingest_qc import IngestQC
from gazepipe.stages.sync.qc import SyncQC

FAIL_ON = ("warning", "fail")
GATE = {"fail": ("fail", "error"), "warning": ("warning", "fail", "error")}


@dataclass
class ValidateResult:
    """What :func:`validate_output` wrote and decided."""

    report: dict[str, Any]
    paths: list[Path]
    passed: bool
    takes: pa.Table
    html: str = ""
    figures: int = 0
    notes: list[str] = field(default_factory=list)
    #: the takes whose plots the page has (``session/take``), worst first
    plotted: list[str] = field(default_factory=list)
    #: the 3D replay pages written (``qc/replay/<session>/<take>.html``)
    replays: list[Path] = field(default_factory=list)


# ------------------------------------------------------------------------------------------------- takes

def take_checks(e: TakeEntry, tables: TakeTables, th: C.Thresholds,
                states: list[dict[str, Any]] | None = None) -> list[C.Check]:
    """Every check of one take (pure: records, unit states and arrays in, checks out)."""
    return [C.check_stages(e.records, states)] + take_output_checks(e, tables, th)


def take_output_checks(e: TakeEntry, tables: TakeTables, th: C.Thresholds) -> list[C.Check]:
    """The checks of one take's outputs: all but ``stages`` (whether its units are up to date with the inputs
    now), so they depend on the records and tables alone and can be computed as soon as the take ran."""
    out = [C.check_stage_warnings(e.records)]
    for name, err in sorted(tables.errors.items()):
        out.append(C.Check(f"table_{name}", "error", f"{name} table unreadable: {err}"))
    errors = {cls.stage: why for cls in QC_TYPES.values() if (why := e.qc_error(cls)) is not None}
    parsed = {cls.stage for cls in QC_TYPES.values() if e.qc(cls) is not None}
    return C.qc_record_errors(out + _qc_checks(e, tables, th), errors, parsed)


def _qc_checks(e: TakeEntry, tables: TakeTables, th: C.Thresholds) -> list[C.Check]:
    """The checks of the take's stages' QC records (and its cleaned markers' fill codes)."""
    if e.kind == "face":
        return C.face_checks(e.qc(FaceQC), th)
    ingest, clean, frames_qc = e.qc(IngestQC), e.qc(CleanQC), e.qc(FramesQC)
    n_frames = None if ingest is None else ingest.frames
    rate = None if ingest is None else ingest.rate_hz
    out = [C.check_gap_share(ingest, th)]
    out.append(C.check_longest_gap(clean, th))
    out.append(C.check_fill_error(clean, th))
    if "markers" in tables.errors:
        out.append(C.Check("unfilled", "error", "cleaned markers table unreadable"))
    else:
        out.append(C.check_unfilled(tables.fill, tables.fill_labels, th, kept_frames=tables.kept_frames,
                                    row_frames=tables.row_frames, feeds=e.kind in ("gaze_follow", "gaze_shift"))
                   if e.ran("clean")
                   else C.skipped("unfilled", "no clean record"))
    out.append(C.check_spikes(clean, n_frames, th))
    out.append(C.check_swaps(clean))
    out.append(C.check_crop(clean, e.kind, n_frames, rate, th))
    kept = None if clean is None else clean.kept_frames
    if e.kind in ("gaze_follow", "gaze_shift"):
        out.append(C.check_invalid_frames(frames_qc, kept, th))
    crop_s = None if clean is None or not rate else (clean.crop[0] / rate, (clean.crop[1] - 1) / rate)
    out.extend(C.sync_checks(e.qc(SyncQC), e.has_video, n_frames, rate, th, crop_s))
    if e.kind == "gaze_follow":
        out.extend(C.eyes_checks(e.qc(EyesQC), e.has_eyes, th))
    return out


def _value(checks: list[C.Check], cid: str) -> Any:
    for c in checks:
        if c.id == cid and c.severity not in ("skipped", "error"):
            return c.value
    return None


def _detail(checks: list[C.Check], cid: str, key: str) -> Any:
    for c in checks:
        if c.id == cid:
            return c.details.get(key)
    return None


def _num(v: Any) -> float | None:
    return None if v is None or not np.isfinite(float(v)) else float(v)


def take_row(e: TakeEntry, checks: list[C.Check], severity: str) -> dict[str, Any]:
    ingest, clean, sync, eyes = e.qc(IngestQC), e.qc(CleanQC), e.qc(SyncQC), e.qc(EyesQC)
    crop = (None, None) if clean is None else clean.crop
    bad = sorted((c for c in checks if C.RANK[c.severity] >= C.RANK["warning"]),
                 key=lambda c: (-C.RANK[c.severity], c.id))
    return {
        "session": e.session, "take": e.take, "kind": e.kind, "pose": e.pose, "severity": severity,
        "n_fail": sum(c.severity in ("fail", "error") for c in checks),
        "n_warning": sum(c.severity == "warning" for c in checks),
        "failing": ",".join(c.id for c in bad),
        "stages_failed": ",".join(sorted(s for s, r in e.records.items() if r.get("status") != "ok")),
        "frames": None if ingest is None else ingest.frames,
        "rate_hz": None if ingest is None else _num(ingest.rate_hz),
        "kept_frames": None if clean is None else clean.kept_frames, "crop_start": crop[0], "crop_stop": crop[1],
        "gap_share_max": _num(_value(checks, "gap_share")), "longest_gap_s": _num(_value(checks, "longest_gap")),
        "fill_error_max_mm": _num(_value(checks, "fill_error")),
        "filled_share": _num(_detail(checks, "unfilled", "filled_share")),
        "unfilled_share_max": _num(_value(checks, "unfilled")),
        "spikes_removed": None if clean is None else clean.spikes_removed,
        "invalid_frames_share": _num(_value(checks, "invalid_frames")),
        "clap_offset_s": None if sync is None else _num(sync.offset_s),
        "clock_drift_ppm": None if sync is None else _num(sync.drift_ppm),
        "clap_confidence_min": _num(_value(checks, "clap_confidence")),
        "frames_without_video_share": _num(_value(checks, "frames_without_video")),
        "eye_gated_share": None if eyes is None else _num(eyes.gated_share),
        "camera_residual_deg": None if eyes is None else _num(eyes.camera_residual_deg),
    }


def take_figures(e: TakeEntry, tables: TakeTables, markerset: Any) -> tuple[list[Figure], list[str]]:
    """The take's plots and notes on plots that could not be drawn."""
    from gazepipe.report import take_plots as plots

    figs: list[Figure] = []
    notes: list[str] = []
    clean = e.qc(CleanQC)
    for cls in QC_TYPES.values():
        why = e.qc_error(cls)
        if why is not None:
            notes.append(f"{cls.stage} QC record unreadable, its plots drawn as if the stage had not run: {why}")
    raw = tables.raw
    salt = f"take:{e.key}:"
    if raw is not None and raw.n_frames:
        figs.append(Figure("Gap timeline", "Every marker's samples over the whole take, coloured by how they were "
                           "filled; red samples stayed gaps. Grey: the frames cropped out (before the first and "
                           "after the last rest), not in any dataset; black lines: the crop bounds.",
                           plots.gap_timeline(
                               raw.labels, raw.n_frames, raw.rate_hz, [] if clean is None else clean.gaps,
                               None if clean is None else clean.crop, raw.valid if clean is None else None,
                               salt + "gaps")))
        from gazepipe.stages.clean.stage import CleanParams

        # the parameters the clean unit ran with (its record's); the defaults where it has no record
        cp = {**dataclasses.asdict(CleanParams()), **e.params("clean")}
        speed = tables.rest_speed
        if speed is not None and clean is not None and np.isfinite(speed).any():
            figs.append(Figure("Speed and crop", "Mean speed of the subject's markers in the room, as the clean "
                               "stage measured it to find the rests, with the rest threshold, the rests and the "
                               "crop bounds.",
                               plots.speed_plot(speed, raw.rate_hz, clean.crop, clean.rests, cp["rest_speed_mm_s"],
                                                salt + "speed")))
        elif clean is None:
            notes.append("speed trace not drawn: the clean stage did not finish on this take")
        else:
            notes.append("speed trace not drawn: the clean stage recorded no speed (an output of an older gazepipe)")
    sync = e.qc(SyncQC)
    if sync is not None and raw is not None and markerset is not None and len(markerset.clapper) == 2 \
            and all(c in raw.labels for c in markerset.clapper):
        a, b = (raw.labels.index(c) for c in markerset.clapper)
        dist = np.linalg.norm(np.where(raw.valid[:, [a]] & raw.valid[:, [b]], raw.xyz[:, a] - raw.xyz[:, b], np.nan),
                              axis=1)
        off, ratio, claps = float(sync.offset_at_video_zero_s), float(sync.ratio), sync.claps
        figs.append(Figure("Clap alignment", "Clapper marker distance around each clap; blue: the mocap clap, "
                           "orange: the video clap mapped onto the mocap clock by the clock map.", plots.clap_plot(
                               dist, raw.rate_hz, [float(c.mocap_s) for c in claps],
                               [None if c.video_s is None else off + ratio * float(c.video_s)
                                for c in claps], salt + "clap")))
    if tables.eyes is not None and tables.eyes["time_s"].size:
        eq = e.qc(EyesQC)
        ey = tables.eyes
        figs.append(Figure("Eye confidence", "OpenFace confidence on the mocap frames (the lower of the two video "
                           "samples around each frame) against the gate; red: invalid frames, blue: frames bridged by slerp.",
                           plots.eye_plot(ey["time_s"], ey["confidence"], ey["valid"], ey["filled"],
                                          None if eq is None else eq.min_confidence, salt + "eyes")))
    return figs, notes


# ---------------------------------------------------------------------------------------------- datasets

def build_check(record: dict[str, Any] | None, built: bool) -> C.Check:
    """The engine's build of the dataset succeeded (its record) and left a dataset folder."""
    if record is None:
        return C.skipped("build", "no build record (built outside the engine)")
    if record.get("status") == "skipped":
        return C.Check("build", "skipped", f"dataset skipped: {record.get('reason', '?')}",
                       details={"skipped": record.get("reason", "")})
    if record.get("status") != "ok":
        return C.Check("build", "fail", f"build failed: {record.get('error', '?')}")
    if not built:
        return C.Check("build", "fail", "the build record says ok but the dataset folder is missing")
    n = len((record.get("components") or {}).get("takes") or [])
    return C.Check("build", "pass", f"built from {n} take(s)", value=n)


def dataset_checks(d: DatasetData, th: C.Thresholds, record: dict[str, Any] | None = None,
                   built: bool = True) -> list[C.Check]:
    out = [build_check(record, built)]
    if not built:
        return out
    if not d.info:
        return out + [C.Check("dataset_read", "error", "; ".join(d.errors) or "_dataset.json unreadable")]
    if d.errors:
        out.append(C.Check("dataset_read", "error", d.errors[0], value=len(d.errors), details={"errors": d.errors}))
    else:
        out.append(C.Check("dataset_read", "pass", f"_dataset.json, _common_metadata and {len(d.files)} take "
                           "file(s) read", value=0))
    out.append(D.check_schema(d.expected, d.common, d.files, d.common_error))
    out.append(D.check_splits(d.info, d.files))
    out.append(D.check_counts(d.info, d.files))
    out.append(D.check_stats(d.info, d.sample, th))
    out.append(D.check_skipped(d.info, (record or {}).get("left_out")))
    out.append(D.check_null_parameters(d.info))
    out.append(D.check_windowed_rows(d.info, th))
    return out


def dataset_figures(d: DatasetData) -> list[Figure]:
    """Feature distributions per pose: the scalar features together, each vector feature on its own."""
    smp = d.all_rows
    if smp is None:
        return []
    from gazepipe.report import plots

    names = d.info.get("features") or {}
    units = {str(k): str(v) for k, v in (d.info.get("units") or {}).items()}
    how = f"over {smp.pose.size} sampled rows of every split (mirrored copies included), one colour per pose"
    scalars = [c for c, v in smp.columns.items() if v.shape[1] == 1]
    figs = []
    if scalars:
        figs.append(Figure(f"{d.name}: scalar features per pose", f"Median (tick) and 5–95 % range (bar) {how}.",
                           plots.scalar_features_plot({c: smp.columns[c][:, 0] for c in scalars}, smp.pose,
                                                      f"dataset:{d.name}:scalars", units)))
    for col, vals in smp.columns.items():
        if col in scalars:
            continue
        figs.append(Figure(f"{d.name}: {col} per pose", f"Median (tick) and 5–95 % range (bar) of every element of "
                           f"{col} {how}; elements named as in _dataset.json, grouped by segment (or track) where "
                           "the names say so.",
                           plots.feature_plot(vals, smp.pose, names.get(col, []), f"{d.name} {col}",
                                              f"dataset:{d.name}:{col}", units.get(col, ""))))
    return figs


def dataset_figures_cached(d: DatasetData, cache: FigureCache) -> list[Figure]:
    """:func:`dataset_figures`, read back from ``cache`` when drawn before."""
    key = cache.dataset_key(d)
    cached = cache.get(key)
    if cached is not None:
        return cached[0]
    figs = dataset_figures(d)
    cache.put(key, figs, [])
    return figs


def dataset_part(layout: OutLayout, name: str, path: Path | None, record: dict[str, Any] | None,
                 th: C.Thresholds, figures: FigureCache, parts: DatasetCache,
                 plots_on: bool = True) -> tuple[dict[str, Any], dict[str, str], list[Figure]]:
    """One dataset's part of the report: its report.json entry, the split of each of its takes and its figures
    (none when ``plots_on`` is false); read back from the caches when computed before (by a worker of the run
    that built it), else computed from the dataset's folder ``path`` (``None``: only its build ``record``)."""
    key = parts.key(name, path, record, th)
    part = parts.get(key)
    if part is not None:
        cached = figures.get(part["figure_key"])
        if cached is not None or not plots_on:       # no plots: those drawn before for this dataset, or none
            return part["entry"], part["take_splits"], [] if cached is None else cached[0]
    d = load_dataset(path, th) if path is not None else DatasetData(name)
    checks = _sorted_checks(dataset_checks(d, th, record, path is not None))
    counts = d.info.get("counts") or {}
    entry = {"name": d.name, "severity": C.worst([c.severity for c in checks]),
             "schema_hash": D.schema_hash(d.expected) if d.expected is not None else None,
             "counts": {k: counts.get(k) for k in ("takes", "rows", "by_split", "by_pose")},
             "checks": [c.to_dict() for c in checks]}
    part = json.loads(json.dumps({"entry": entry, "take_splits": d.take_splits,
                                  "figure_key": figures.dataset_key(d)}, allow_nan=False))
    kept = figures.get(part["figure_key"])
    figs = dataset_figures_cached(d, figures) if plots_on else ([] if kept is None else kept[0])
    parts.put(key, part)
    return part["entry"], part["take_splits"], figs


# ----------------------------------------------------------------------------------------------- report

def _ref(scope: str, target: str, c: C.Check) -> dict[str, Any]:
    return {"scope": scope, "target": target, "id": c.id, "severity": c.severity, "message": c.message}


def _sorted_checks(checks: list[C.Check]) -> list[C.Check]:
    order = {c.id: i for i, c in enumerate(checks)}
    return sorted(checks, key=lambda c: (-C.RANK[c.severity], order[c.id]))


#: takes plotted when nothing else is asked for: the worst ones (``gazepipe run`` plots as many)
DEFAULT_PLOT_TAKES = 6
def take_rank_key(take: dict[str, Any]) -> tuple:
    """Sort key of a take (an entry of report.json's ``takes``), worst first (:func:`~gazepipe.report.checks.
    rank_key`)."""
    return C.rank_key(take["severity"], take["checks"], f"{take['session']}/{take['take']}")


def rank_takes(takes: list[dict[str, Any]]) -> list[str]:
    """The keys (``session/take``) of report.json's ``takes``, worst first (:func:`take_rank_key`)."""
    return [f"{t['session']}/{t['take']}" for t in sorted(takes, key=take_rank_key)]


def plot_limit(value: int | str | None) -> int | None:
    """``plot_takes`` as a number of takes, ``None`` for all (``"all"`` or ``None``)."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "all"):
        return None
    n = int(value)
    if n < 0:
        raise ValueError(f"plot_takes must be 0 or more, or 'all' (got {value!r})")
    return n


def match_takes(patterns: Sequence[str], keys: Sequence[str]) -> list[str]:
    """The take keys (``session/take``) that ``patterns`` name: a key, a take id (in any session) or a shell
    pattern of either (``shift_*``, ``session01/follow_*``); in the order of ``keys``. A pattern that names no
    take is a :class:`~gazepipe.errors.ConfigError` (exit 2)."""
    from fnmatch import fnmatchcase

    found: set[str] = set()
    for pat in patterns:
        hits = [k for k in keys if fnmatchcase(k, pat) or fnmatchcase(k.split("/", 1)[-1], pat)]
        if not hits:
            example = f" (e.g. {keys[0]})" if keys else " (it has none)"
            raise ConfigError(None, f"--plot-take {pat}: no take of the output folder is called that; name one as "
                              f"SESSION/TAKE or TAKE{example}, or a pattern such as 'shift_*'")
        found.update(hits)
    return [k for k in keys if k in found]


@dataclass(frozen=True)
class PlotRequest:
    """Which plots the page gets: none (``on`` false), else every dataset's and those of the ``limit`` worst
    takes (``None``: every take) plus the takes ``named`` (keys or patterns, :func:`match_takes`)."""

    on: bool = True
    limit: int | None = DEFAULT_PLOT_TAKES
    named: tuple[str, ...] = ()


def validate_output(out: str | Path, thresholds: C.Thresholds | None = None, fail_on: str = "fail",
                    lock: bool = True, plots_on: bool = True, plot_takes: int | str | None = DEFAULT_PLOT_TAKES,
                    plot_named: Sequence[str] = ()) -> ValidateResult:
    """Check everything in the output folder ``out`` and write ``out/qc/{report.json,takes.parquet,report.html}``.

    Parameters
    ----------
    thresholds : severity thresholds (:class:`gazepipe.report.checks.Thresholds`).
    fail_on : the gate: ``fail`` (checks at fail or error) or ``warning`` (warning or worse).
    lock : hold the output folder's lock while reading and writing (a running ``gazepipe run`` makes this raise
        :class:`~gazepipe.errors.LockedError`, exit 75).
    plots_on : draw the plots (off: nothing is drawn and nothing deleted; the page keeps the plots and 3D
        replays drawn before of the datasets and takes whose outputs are unchanged, read back from the caches).
    plot_takes : draw the plots of this many takes, the worst first (:func:`take_rank_key`; takes with nothing
        to draw, such as face takes, are passed over), or of every take (``"all"`` or ``None``). Every take is
        checked and keeps its checks table whatever the number; the page names the takes plotted and says how to
        plot the others. Drawing is most of a validation's time, so the default is a few.
    plot_named : also draw these takes (``session/take``, a take id or a shell pattern; :func:`match_takes`).

    report.json and takes.parquet do not depend on ``plots_on``, ``plot_takes`` and ``plot_named``.

    Raises :class:`~gazepipe.errors.ConfigError` when ``out`` is not a gazepipe output folder, or a name in
    ``plot_named`` matches no take.
    """
    if fail_on not in FAIL_ON:
        raise ValueError(f"fail_on must be one of {FAIL_ON}")
    request = PlotRequest(bool(plots_on), plot_limit(plot_takes), tuple(plot_named))
    layout = open_output(out)
    th = thresholds or C.Thresholds()
    if lock:
        with OutputLock(layout.lock):
            return _validate(layout, th, fail_on, request)
    return _validate(layout, th, fail_on, request)


@dataclass
class TakePass:
    """What the checks of every take found: sessions, takes, their report entries, rows and check references."""

    sessions: dict[str, Any]
    session_problems: list[str]
    entries: list[TakeEntry]
    takes_out: list[dict[str, Any]]
    rows: list[dict[str, Any]]
    refs: list[dict[str, Any]]


def _validate(layout: OutLayout, th: C.Thresholds, fail_on: str, plots: PlotRequest) -> ValidateResult:
    return finish_report(layout, th, fail_on, plots, take_pass(layout, th))


def take_pass(layout: OutLayout, th: C.Thresholds) -> TakePass:
    """Every take's checks (tables read one take at a time)."""
    sessions, session_problems = load_sessions(layout)
    states = unit_states(layout) if not session_problems else None
    takes_out: list[dict[str, Any]] = []
    rows: list[dict[str, Any]] = []
    refs: list[dict[str, Any]] = []
    entries = take_entries(layout, sessions)
    cache = CheckCache(layout)
    for e in entries:
        found = output_checks(layout, e, th, cache)
        stages = C.check_stages(e.records, None if states is None else states.get(e.key, []))
        checks = _sorted_checks([stages] + found)
        sev = C.worst([c.severity for c in checks])
        takes_out.append({"session": e.session, "take": e.take, "kind": e.kind, "pose": e.pose, "severity": sev,
                          "stages": _stage_states(e, None if states is None else states.get(e.key, [])),
                          "checks": [c.to_dict() for c in checks]})
        rows.append(take_row(e, checks, sev))
        refs.extend(_ref("take", e.key, c) for c in checks)
    cache.prune()
    return TakePass(sessions, session_problems, entries, takes_out, rows, refs)


def _stage_states(e: TakeEntry, states: list[dict[str, Any]] | None) -> dict[str, str]:
    """Each stage's status: its record's, or ``failed`` for a stage that failed while the run planned it (a
    missing or unreadable input: no record)."""
    out = {k: str(r.get("status", "?")) for k, r in e.records.items()}
    out.update({r["stage"]: "failed" for r in states or [] if r.get("state") == "failed" and r["stage"] not in out})
    return dict(sorted(out.items()))


def output_checks(layout: OutLayout, e: TakeEntry, th: C.Thresholds, cache: CheckCache) -> list[C.Check]:
    """:func:`take_output_checks` of one take, read back from ``cache`` when computed before (by a worker of the
    run that made the take, :func:`gazepipe.report.run_report.take_part`), else computed (tables read one take at a time) and cached."""
    key = cache.key(e, th)
    found = cache.get(key)
    if found is None:
        found = stored_checks(take_output_checks(e, load_take_tables(layout, e, arrays=False), th))
        cache.put(key, found)
    return found


def plot_choice(layout: OutLayout, tp: TakePass, plots: PlotRequest) -> tuple[list[str], list[str], list[str],
                                                                                 set[str]]:
    """Which takes get plots: the keys ranked worst first, the keys ``plots.named`` matched, the chosen keys in
    rank order and the drawable keys."""
    keys = [e.key for e in tp.entries]
    named = match_takes(plots.named, keys)        # raises before anything is drawn or written
    ranked = rank_takes(tp.takes_out)
    drawable = {e.key for e in tp.entries if has_plot_tables(layout, e)}
    if not plots.on:
        return ranked, named, [], drawable
    worst = [k for k in ranked if k in drawable]
    chosen = set(worst if plots.limit is None else worst[:plots.limit]) | (set(named) & drawable)
    return ranked, named, [k for k in ranked if k in chosen], drawable


#: a take's plots read its whole raw markers: longer takes (more frames x markers) are left out of the plots
PLOT_MAX_SAMPLES = 20_000_000


def take_figures_cached(layout: OutLayout, e: TakeEntry, markerset: Any,
                         cache: FigureCache) -> tuple[list[Figure], list[str]]:
    """:func:`take_figures` of one take, read back from ``cache`` when drawn before (by this process or by a
    worker of the run, :func:`gazepipe.report.run_report.draw_take_plots`), else drawn and cached."""
    cache_key = cache.take_key(e, markerset)
    cached = cache.get(cache_key)
    if cached is not None:
        return cached
    samples = count_rows(layout.table(e.session, e.take, "markers_raw")) or 0
    if samples > PLOT_MAX_SAMPLES:   # read whole, a take this long would cost the report gigabytes
        notes = [f"not drawn: {samples:,} marker samples, more than the {PLOT_MAX_SAMPLES:,} a take's plots read"]
        cache.put(cache_key, [], notes)
        return [], notes
    tables = load_take_tables(layout, e, only=PLOT_TABLES)
    figs, fig_notes = take_figures(e, tables, markerset)
    if not figs:
        why = "; ".join(f"{n} table unreadable" for n in sorted(tables.errors)) or "no frames"
        fig_notes.append(f"nothing drawn ({why})")
    del tables
    cache.put(cache_key, figs, fig_notes)
    return figs, fig_notes


def take_replay_cached(layout: OutLayout, e: TakeEntry, markerset: Any,
                       cache: ReplayCache) -> tuple[bytes | None, str | None]:
    """The take's 3D replay page (:mod:`gazepipe.report.replay_page`, loading ``qc/plotly.min.js`` from
    ``qc/replay/<session>/``), or why there is none; read back from ``cache`` when made before (by a worker of
    the run, :func:`gazepipe.report.run_report.draw_take_plots`), else made and cached. Never raises: a replay
    that cannot be made costs its link, not the report."""
    key = cache.key(e, markerset)
    got = cache.get(key)
    if got is not None:
        return got
    from gazepipe.report.replay import ReplayUnavailable, load_replay_inputs
    from gazepipe.report.replay_page import RELATIVE_PLOTLY, replay_html

    page: bytes | None = None
    why: str | None = None
    samples = count_rows(layout.table(e.session, e.take, "markers_raw")) or 0
    if samples > PLOT_MAX_SAMPLES:
        why = f"no 3D replay: {samples:,} marker samples, more than the {PLOT_MAX_SAMPLES:,} a take's plots read"
    else:
        try:
            page = replay_html(load_replay_inputs(layout, e, markerset), RELATIVE_PLOTLY)[0].encode("utf-8")
        except ReplayUnavailable as exc:
            why = f"no 3D replay: {exc}"
        except Exception as exc:  # a replay is a view: its failure is a note, never the report's
            why = f"no 3D replay (it could not be made: {type(exc).__name__}: {exc})"
    cache.put(key, page, why)
    return page, why


def _take_plots(layout: OutLayout, tp: TakePass, plots: PlotRequest, cache: FigureCache,
                replays: ReplayCache) -> tuple[dict[str, list[Figure]], list[str], PlotSelection,
                                               dict[tuple[str, str], bytes]]:
    """The plots and 3D replays of the takes ``plots`` asks for (their tables read again, one take at a time,
    unless made before), notes on plots that could not be drawn, and what the page says about the takes
    plotted and the others."""
    ranked, named, chosen, drawable = plot_choice(layout, tp, plots)
    if not plots.on:
        return _kept_take_plots(layout, tp, plots, ranked, named, drawable, cache, replays)
    by_key = {e.key: e for e in tp.entries}
    take_figs: dict[str, list[Figure]] = {}
    pages: dict[tuple[str, str], bytes] = {}
    plot_notes: list[str] = []
    for key in chosen:
        e = by_key[key]
        s = tp.sessions.get(e.session)
        markerset = s.markerset if s is not None else None
        figs, fig_notes = take_figures_cached(layout, e, markerset, cache)
        if figs:
            take_figs[key] = figs
        plot_notes.extend(f"{key}: {n}" for n in fig_notes)
        if e.kind != "face":
            page, why = take_replay_cached(layout, e, markerset, replays)
            if page is not None:
                pages[(e.session, e.take)] = page
            elif why:
                plot_notes.append(f"{key}: {why}")
    return take_figs, plot_notes, PlotSelection(
        True, plots.limit, tuple(ranked), plotted=tuple(k for k in ranked if k in take_figs), named=tuple(named),
        nothing_to_draw=tuple(k for k in ranked if k not in drawable),
        failed=tuple(k for k in chosen if k not in take_figs)), pages


def pages_on_disk(layout: OutLayout, tp: TakePass, replays: ReplayCache,
                  skip: Sequence[tuple[str, str]] = ()) -> dict[tuple[str, str], bytes]:
    """The replay pages ``qc/replay/`` holds (takes in ``skip`` apart) that are still their take's page: the
    replay cache has, for the take's outputs as they are now, a page of the same bytes. A page of a take gone,
    or of outputs since changed, is not among them."""
    from gazepipe.report.replay_page import REPLAY_DIR

    base = layout.root / "qc" / REPLAY_DIR
    by_key = {e.key: e for e in tp.entries}
    found: dict[tuple[str, str], bytes] = {}
    for path in sorted(base.glob("*/*.html")) if base.is_dir() else []:
        e = by_key.get(f"{path.parent.name}/{path.stem}")
        if e is None or (e.session, e.take) in skip:
            continue
        s = tp.sessions.get(e.session)
        got = replays.get(replays.key(e, s.markerset if s is not None else None))
        try:
            if got is not None and got[0] is not None and got[0] == path.read_bytes():
                found[(e.session, e.take)] = got[0]
        except OSError:
            continue
    return found


def _kept_take_plots(layout: OutLayout, tp: TakePass, plots: PlotRequest, ranked: list[str], named: list[str],
                     drawable: set[str], cache: FigureCache, replays: ReplayCache
                     ) -> tuple[dict[str, list[Figure]], list[str], PlotSelection, dict[tuple[str, str], bytes]]:
    """``--no-plots``: nothing drawn, nothing deleted. The takes whose replay page the report folder holds, made
    from their outputs as they are now (:func:`pages_on_disk`: the ones the report written before drew), keep
    that page and their plots (read back from the caches, never drawn)."""
    by_key = {e.key: e for e in tp.entries}
    pages = pages_on_disk(layout, tp, replays)
    take_figs: dict[str, list[Figure]] = {}
    for session, take in pages:
        e = by_key[f"{session}/{take}"]
        s = tp.sessions.get(e.session)
        figs = cache.get(cache.take_key(e, s.markerset if s is not None else None))
        if figs is not None and figs[0]:
            take_figs[e.key] = figs[0]
    return take_figs, [], PlotSelection(
        False, plots.limit, tuple(ranked), plotted=tuple(k for k in ranked if k in take_figs), named=tuple(named),
        nothing_to_draw=tuple(k for k in ranked if k not in drawable)), pages


def finish_report(layout: OutLayout, th: C.Thresholds, fail_on: str, plots: PlotRequest,
                  tp: TakePass) -> ValidateResult:
    """Add the plots and the datasets to the checks of every take, and write ``qc/``."""
    session_problems, takes_out, rows, refs = tp.session_problems, tp.takes_out, tp.rows, list(tp.refs)
    cache = FigureCache(layout)
    replay_cache = ReplayCache(layout)
    take_figs, plot_notes, selection, pages = _take_plots(layout, tp, plots, cache, replay_cache)
    datasets_out: list[dict[str, Any]] = []
    ds_figs: dict[str, list[Figure]] = {}
    splits: dict[str, dict[str, str]] = {}
    dirs = {p.name: p for p in dataset_dirs(layout)}
    records = dataset_records(layout)
    parts = DatasetCache(layout)
    for name in sorted(set(dirs) | set(records)):
        entry, take_splits, figs = dataset_part(layout, name, dirs.get(name), records.get(name), th, cache, parts,
                                                plots.on)
        splits[name] = take_splits
        ds_figs[name] = figs
        datasets_out.append(entry)
        refs.extend(_ref("dataset", name, C.Check(**c)) for c in entry["checks"])
    parts.prune()

    output_checks = [D.check_split_consistency(splits)]
    if session_problems:
        output_checks.append(C.Check("sessions_readable", "warning", session_problems[0],
                                     value=len(session_problems), details={"problems": session_problems}))
    refs.extend(_ref("output", "output", c) for c in output_checks)

    hit = [r for r in refs if r["severity"] in GATE[fail_on]]
    failing = sorted((r for r in refs if C.RANK[r["severity"]] >= C.RANK["warning"]),
                     key=lambda r: (-C.RANK[r["severity"]], r["scope"] != "output", r["target"], r["id"]))
    counts = {s: sum(r["severity"] == s for r in refs) for s in C.SEVERITIES}
    report = {
        "schema": "gazepipe.qc_report", "schema_version": REPORT_SCHEMA_VERSION, "gazepipe_version": __version__,
        "gate": {"fail_on": fail_on, "passed": not hit, "hit": hit},
        "summary": {"takes": len(takes_out), "datasets": len(datasets_out), "checks": counts,
                    "takes_by_severity": {s: sum(t["severity"] == s for t in takes_out) for s in C.SEVERITIES},
                    "failing": failing},
        "thresholds": th.to_dict(),
        "takes": takes_out, "datasets": datasets_out,
        "output_checks": [c.to_dict() for c in output_checks],
        "notes": list(session_problems),
    }
    table = pa.Table.from_pylist(rows, schema=TAKES_SCHEMA) if rows else TAKES_SCHEMA.empty_table()
    from gazepipe.report.replay_page import REPLAY_DIR, page_path, write_report_replays

    links = {f"{s}/{t}": f"{REPLAY_DIR}/{s}/{t}.html" for s, t in pages}
    html = render_html(report, take_figs, ds_figs, plot_notes, plots=selection, replays=links)
    qc = layout.root / "qc"
    qc.mkdir(exist_ok=True)
    layout.tmp.mkdir(parents=True, exist_ok=True)
    # the pages of takes not drawn this time stay while they are their take's page (validate deletes no view of
    # the current outputs); stale ones go, and with --no-plots nothing goes
    kept = pages_on_disk(layout, tp, replay_cache, skip=list(pages)) if plots.on else {}
    replay_paths = write_report_replays(qc, layout.tmp, pages, prune=plots.on,
                                        keep=[page_path(qc, REPLAY_DIR, s, t) for s, t in kept])
    paths = [qc / "report.json", qc / "takes.parquet", qc / "report.html"]
    layout.write_bytes(paths[0], (json.dumps(report, indent=1, sort_keys=True, allow_nan=False,
                                             ensure_ascii=False) + "\n").encode())
    with atomic_path(paths[1], layout.tmp) as tmp:
        write_table(table, tmp, TAKES_SCHEMA)
    layout.write_bytes(paths[2], html.encode())
    if plots.on:
        cache.prune()
        replay_cache.prune()
    n_figs = sum(len(v) for v in take_figs.values()) + sum(len(v) for v in ds_figs.values())
    return ValidateResult(report=report, paths=paths, passed=not hit, takes=table, html=html, figures=n_figs,
                          notes=plot_notes, plotted=list(selection.plotted), replays=replay_paths)


__all__ = ["DEFAULT_PLOT_TAKES", "FAIL_ON", "ValidateResult", "dataset_checks", "match_takes",
           "rank_takes", "take_checks", "take_rank_key", "validate_output"]
