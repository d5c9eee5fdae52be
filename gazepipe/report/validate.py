"""``gazepipe validate``: run every check on an output folder and write ``qc/report.json``, ``qc/takes.parquet``
and ``qc/report.html``.

Takes are processed one at a time (their tables are dropped after their checks and plots), datasets one at a
time. Same output folder, same thresholds → byte-identical files: nothing in them depends on the clock, the
machine or the folder's absolute path.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe import __version__
from gazepipe.io.parquet import write_table
from gazepipe.pipeline.atomic import atomic_path
from gazepipe.pipeline.lock import OutputLock
from gazepipe.pipeline.state import OutLayout
from gazepipe.report import checks as C
from gazepipe.report import checks_datasets as D
from gazepipe.report.collect import (
    DatasetData,
    TakeEntry,
    TakeTables,
    dataset_dirs,
    dataset_records,
    load_dataset,
    load_sessions,
    load_take_tables,
    open_output,
    speed_trace,
    take_entries,
    unit_states,
)
from gazepipe.report.html import Figure, render_html
from gazepipe.report.schema import REPORT_SCHEMA_VERSION, TAKES_SCHEMA

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


# ------------------------------------------------------------------------------------------------- takes

def take_checks(e: TakeEntry, tables: TakeTables, th: C.Thresholds,
                states: list[dict[str, Any]] | None = None) -> list[C.Check]:
    """Every check of one take (pure: records, unit states and arrays in, checks out)."""
    ingest, clean, frames_qc = e.qc("ingest"), e.qc("clean"), e.qc("frames")
    n_frames = (ingest or {}).get("frames")
    rate = (ingest or {}).get("rate_hz")
    out = [C.check_stages(e.records, states), C.check_stage_warnings(e.records)]
    for name, err in sorted(tables.errors.items()):
        out.append(C.Check(f"table_{name}", "error", f"{name} table unreadable: {err}"))
    if e.kind == "face":
        return out + C.face_checks(e.qc("face"), th)
    out.append(C.check_gap_share(ingest, th))
    out.append(C.check_longest_gap(clean, th))
    out.append(C.check_fill_error(clean, th))
    if "markers" in tables.errors:
        out.append(C.Check("unfilled", "error", "cleaned markers table unreadable"))
    else:
        out.append(C.check_unfilled(tables.fill, tables.fill_labels, th) if clean is not None
                   else C.skipped("unfilled", "no clean record"))
    out.append(C.check_spikes(clean, n_frames, th))
    out.append(C.check_crop(clean, e.kind, n_frames, rate, th))
    kept = (clean or {}).get("kept_frames")
    if e.kind in ("gaze_follow", "gaze_shift"):
        out.append(C.check_invalid_frames(frames_qc, kept, th))
    out.extend(C.sync_checks(e.qc("sync"), e.has_video, n_frames, rate, th))
    if e.kind == "gaze_follow":
        out.extend(C.eyes_checks(e.qc("eyes"), e.has_eyes, th))
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
    ingest, clean = e.qc("ingest") or {}, e.qc("clean") or {}
    crop = clean.get("crop") or [None, None]
    bad = sorted((c for c in checks if C.RANK[c.severity] >= C.RANK["warning"]),
                 key=lambda c: (-C.RANK[c.severity], c.id))
    sync = e.qc("sync") or {}
    eyes = e.qc("eyes") or {}
    return {
        "session": e.session, "take": e.take, "kind": e.kind, "pose": e.pose, "severity": severity,
        "n_fail": sum(c.severity in ("fail", "error") for c in checks),
        "n_warning": sum(c.severity == "warning" for c in checks),
        "failing": ",".join(c.id for c in bad),
        "stages_failed": ",".join(sorted(s for s, r in e.records.items() if r.get("status") != "ok")),
        "frames": ingest.get("frames"), "rate_hz": _num(ingest.get("rate_hz")),
        "kept_frames": clean.get("kept_frames"), "crop_start": crop[0], "crop_stop": crop[1],
        "gap_share_max": _num(_value(checks, "gap_share")), "longest_gap_s": _num(_value(checks, "longest_gap")),
        "fill_error_max_mm": _num(_value(checks, "fill_error")),
        "filled_share": _num(_detail(checks, "unfilled", "filled_share")),
        "unfilled_share_max": _num(_value(checks, "unfilled")),
        "spikes_removed": clean.get("spikes_removed"),
        "invalid_frames_share": _num(_value(checks, "invalid_frames")),
        "clap_offset_s": _num(sync.get("offset_s")), "clock_drift_ppm": _num(sync.get("drift_ppm")),
        "clap_confidence_min": _num(_value(checks, "clap_confidence")),
        "frames_without_video_share": _num(_value(checks, "frames_without_video")),
        "eye_gated_share": _num(eyes.get("gated_share")), "camera_residual_deg": _num(eyes.get("camera_residual_deg")),
    }


def take_figures(e: TakeEntry, tables: TakeTables, markerset: Any) -> tuple[list[Figure], list[str]]:
    """The take's plots and notes on plots that could not be drawn."""
    from gazepipe.report import plots  # matplotlib: loaded only when something is drawn

    figs: list[Figure] = []
    notes: list[str] = []
    clean = e.qc("clean")
    raw = tables.raw
    salt = f"take:{e.key}:"
    if raw is not None and raw.n_frames:
        figs.append(Figure("Gap timeline", "Every marker's samples over the whole take, coloured by how they were "
                           "filled; red samples stayed gaps.", plots.gap_timeline(
                               raw.labels, raw.n_frames, raw.rate_hz, (clean or {}).get("gaps", []),
                               (clean or {}).get("crop"), raw.valid if clean is None else None, salt + "gaps")))
        cp = e.params("clean")
        # drawn for a take whose clean stage failed too: a take whose rests were not found shows why
        speed = speed_trace(raw, markerset, cp.get("rest_filter_hz", 1.75))
        if speed is not None and np.isfinite(speed).any():
            failed = "" if clean is not None else " The clean stage failed on this take: no rests or crop."
            figs.append(Figure("Speed and crop", "Mean speed of the subject's markers in the room, recomputed from "
                               "the raw markers (gaps unfilled, so it can differ slightly from the speed the crop "
                               "used), with the rest threshold, the rests and the crop bounds." + failed,
                               plots.speed_plot(speed, raw.rate_hz, (clean or {}).get("crop"),
                                                (clean or {}).get("rests", []), cp.get("rest_speed_mm_s"),
                                                salt + "speed")))
        else:
            notes.append("speed trace not drawn: the session's markerset cannot be read")
    sync = e.qc("sync")
    if sync is not None and raw is not None and markerset is not None and len(markerset.clapper) == 2 \
            and all(c in raw.labels for c in markerset.clapper):
        a, b = (raw.labels.index(c) for c in markerset.clapper)
        dist = np.linalg.norm(np.where(raw.valid[:, [a]] & raw.valid[:, [b]], raw.xyz[:, a] - raw.xyz[:, b], np.nan),
                              axis=1)
        off = float(sync.get("offset_at_video_zero_s", sync.get("offset_s", 0.0)))
        ratio = float(sync.get("ratio", 1.0))
        claps = sync.get("claps", [])
        figs.append(Figure("Clap alignment", "Clapper marker distance around each clap; blue: the mocap clap, "
                           "orange: the video clap mapped onto the mocap clock by the clock map.", plots.clap_plot(
                               dist, raw.rate_hz, [float(c["mocap_s"]) for c in claps],
                               [None if c.get("video_s") is None else off + ratio * float(c["video_s"])
                                for c in claps], salt + "clap")))
    if tables.eyes is not None and tables.eyes["time_s"].size:
        eq = e.qc("eyes") or {}
        ey = tables.eyes
        figs.append(Figure("Eye confidence", "OpenFace confidence on the mocap frames (the lower of the two video "
                           "samples around each frame) against the gate; red: invalid frames, blue: frames bridged by slerp.",
                           plots.eye_plot(ey["time_s"], ey["confidence"], ey["valid"], ey["filled"],
                                          eq.get("min_confidence"), salt + "eyes")))
    return figs, notes


# ---------------------------------------------------------------------------------------------- datasets

def build_check(record: dict[str, Any] | None, built: bool) -> C.Check:
    """The engine's build of the dataset succeeded (its record) and left a dataset folder."""
    if record is None:
        return C.skipped("build", "no build record (built outside the engine)")
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
        return out + [C.Check("dataset_read", "error", "; ".join(d.errors) or "dataset.json unreadable")]
    if d.errors:
        out.append(C.Check("dataset_read", "error", d.errors[0], value=len(d.errors), details={"errors": d.errors}))
    else:
        out.append(C.Check("dataset_read", "pass", f"dataset.json, _common_metadata and {len(d.files)} take "
                           "file(s) read", value=0))
    out.append(D.check_schema(d.expected, d.common, d.files, d.common_error))
    out.append(D.check_splits(d.info, d.files))
    out.append(D.check_counts(d.info, d.files))
    out.append(D.check_stats(d.info, d.sample, th))
    out.append(D.check_skipped(d.info))
    out.append(D.check_windowed_rows(d.info, th))
    return out


def dataset_figures(d: DatasetData) -> list[Figure]:
    """Feature distributions per pose: the scalar features together, each vector feature on its own."""
    smp = d.all_rows
    if smp is None:
        return []
    from gazepipe.report import plots

    names = d.info.get("features") or {}
    how = f"over {smp.pose.size} sampled rows of every split (mirrored copies included), one colour per pose"
    scalars = [c for c, v in smp.columns.items() if v.shape[1] == 1]
    figs = []
    if scalars:
        figs.append(Figure(f"{d.name}: scalar features per pose", f"Median (tick) and 5–95 % range (bar) {how}.",
                           plots.scalar_features_plot({c: smp.columns[c][:, 0] for c in scalars}, smp.pose,
                                                      f"dataset:{d.name}:scalars")))
    for col, vals in smp.columns.items():
        if col in scalars:
            continue
        figs.append(Figure(f"{d.name}: {col} per pose", f"Median (tick) and 5–95 % range (bar) of every element of "
                           f"{col} {how}.", plots.feature_plot(vals, smp.pose, names.get(col, []),
                                                               f"{d.name} {col}", f"dataset:{d.name}:{col}")))
    return figs


# ----------------------------------------------------------------------------------------------- report

def _ref(scope: str, target: str, c: C.Check) -> dict[str, Any]:
    return {"scope": scope, "target": target, "id": c.id, "severity": c.severity, "message": c.message}


def _sorted_checks(checks: list[C.Check]) -> list[C.Check]:
    order = {c.id: i for i, c in enumerate(checks)}
    return sorted(checks, key=lambda c: (-C.RANK[c.severity], order[c.id]))


def validate_output(out: str | Path, thresholds: C.Thresholds | None = None, fail_on: str = "fail",
                    lock: bool = True, plots_on: bool = True, plot_takes: int = 100) -> ValidateResult:
    """Check everything in the output folder ``out`` and write ``out/qc/{report.json,takes.parquet,report.html}``.

    Parameters
    ----------
    thresholds : severity thresholds (:class:`gazepipe.report.checks.Thresholds`).
    fail_on : the gate: ``fail`` (checks at fail or error) or ``warning`` (warning or worse).
    lock : hold the output folder's lock while reading and writing (a running ``gazepipe run`` makes this raise
        :class:`~gazepipe.errors.LockedError`, exit 75).
    plots_on : draw the plots (off: the HTML page has the tables only).
    plot_takes : draw the plots of at most this many takes, the worst first (the page of a corpus of thousands
        of takes stays readable and small); every take keeps its checks table.

    report.json and takes.parquet do not depend on ``plots_on`` and ``plot_takes``.

    Raises :class:`~gazepipe.errors.ConfigError` when ``out`` is not a gazepipe output folder.
    """
    if fail_on not in FAIL_ON:
        raise ValueError(f"fail_on must be one of {FAIL_ON}")
    layout = open_output(out)
    th = thresholds or C.Thresholds()
    limit = int(plot_takes) if plots_on else 0
    if lock:
        with OutputLock(layout.lock):
            return _validate(layout, th, fail_on, limit)
    return _validate(layout, th, fail_on, limit)


class ReportInBackground:
    """The checks of every take computed in a thread from now on, while the caller does other work (a run builds
    its datasets); :meth:`finish` adds the plots (drawn then: matplotlib's memory is not added to the caller's
    peak) and the datasets and writes the files, as :func:`validate_output` would have.

    The caller keeps every take's outputs as they are until :meth:`finish` (a run holds the folder's lock; only
    the datasets may change meanwhile) and holds the lock itself when it needs one.
    """

    def __init__(self, out: str | Path, thresholds: C.Thresholds | None = None, plot_takes: int = 100) -> None:
        import threading

        self.layout = open_output(out)
        self.th = thresholds or C.Thresholds()
        self.plot_takes = int(plot_takes)
        self._done: _TakePass | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="gazepipe-report-takes", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._done = _take_pass(self.layout, self.th)
        except BaseException as exc:  # handed to the caller by finish()
            self._error = exc

    def finish_quietly(self) -> None:
        """Wait for the take checks and drop them (the report turned out not to be needed)."""
        self._thread.join()

    def finish(self, fail_on: str = "fail") -> ValidateResult:
        """Wait for the take checks (raising their error, if any), then draw the plots, check the datasets and
        write ``qc/``."""
        if fail_on not in FAIL_ON:
            raise ValueError(f"fail_on must be one of {FAIL_ON}")
        self._thread.join()
        if self._error is not None:
            raise self._error
        assert self._done is not None
        return _finish(self.layout, self.th, fail_on, self.plot_takes, self._done)


@dataclass
class _TakePass:
    """What the checks of every take found: sessions, takes, their report entries, rows and check references."""

    sessions: dict[str, Any]
    session_problems: list[str]
    entries: list[TakeEntry]
    takes_out: list[dict[str, Any]]
    rows: list[dict[str, Any]]
    refs: list[dict[str, Any]]


def _validate(layout: OutLayout, th: C.Thresholds, fail_on: str, plot_takes: int) -> ValidateResult:
    return _finish(layout, th, fail_on, plot_takes, _take_pass(layout, th))


def _take_pass(layout: OutLayout, th: C.Thresholds) -> _TakePass:
    """Every take's checks (tables read one take at a time)."""
    sessions, session_problems = load_sessions(layout)
    states = unit_states(layout) if not session_problems else None
    takes_out: list[dict[str, Any]] = []
    rows: list[dict[str, Any]] = []
    refs: list[dict[str, Any]] = []
    entries = take_entries(layout, sessions)
    for e in entries:
        tables = load_take_tables(layout, e, arrays=False)
        checks = _sorted_checks(take_checks(e, tables, th, None if states is None else states.get(e.key, [])))
        sev = C.worst([c.severity for c in checks])
        takes_out.append({"session": e.session, "take": e.take, "kind": e.kind, "pose": e.pose, "severity": sev,
                          "stages": {k: r.get("status", "?") for k, r in sorted(e.records.items())},
                          "checks": [c.to_dict() for c in checks]})
        rows.append(take_row(e, checks, sev))
        refs.extend(_ref("take", e.key, c) for c in checks)
        del tables

    return _TakePass(sessions, session_problems, entries, takes_out, rows, refs)


def _take_plots(layout: OutLayout, tp: _TakePass, plot_takes: int) -> tuple[dict[str, list[Figure]], list[str]]:
    """The plots of the ``plot_takes`` worst takes (their tables read again, one take at a time), and notes."""
    take_figs: dict[str, list[Figure]] = {}
    plot_notes: list[str] = []
    ranked = sorted(zip(tp.entries, tp.takes_out, strict=True),
                    key=lambda et: (-C.RANK[et[1]["severity"]], et[0].key))
    for e, _ in ranked[:plot_takes]:
        s = tp.sessions.get(e.session)
        figs, fig_notes = take_figures(e, load_take_tables(layout, e), s.markerset if s is not None else None)
        take_figs[e.key] = figs
        plot_notes.extend(f"{e.key}: {n}" for n in fig_notes)
    if 0 < plot_takes < len(tp.entries):
        plot_notes.insert(0, f"plots drawn for the {plot_takes} worst of {len(tp.entries)} takes (--plot-takes)")
    elif plot_takes == 0 and tp.entries:
        plot_notes.insert(0, "plots left out (--no-plots)")
    return take_figs, plot_notes


def _finish(layout: OutLayout, th: C.Thresholds, fail_on: str, plot_takes: int, tp: _TakePass) -> ValidateResult:
    session_problems, takes_out, rows, refs = tp.session_problems, tp.takes_out, tp.rows, list(tp.refs)
    take_figs, plot_notes = _take_plots(layout, tp, plot_takes)
    datasets_out: list[dict[str, Any]] = []
    ds_figs: dict[str, list[Figure]] = {}
    splits: dict[str, dict[str, str]] = {}
    dirs = {p.name: p for p in dataset_dirs(layout)}
    records = dataset_records(layout)
    for name in sorted(set(dirs) | set(records)):
        d = load_dataset(dirs[name], th) if name in dirs else DatasetData(name)
        checks = _sorted_checks(dataset_checks(d, th, records.get(name), name in dirs))
        splits[d.name] = d.take_splits
        ds_figs[d.name] = dataset_figures(d) if plot_takes > 0 else []
        counts = d.info.get("counts") or {}
        datasets_out.append({"name": d.name, "severity": C.worst([c.severity for c in checks]),
                             "schema_hash": D.schema_hash(d.expected) if d.expected is not None else None,
                             "counts": {k: counts.get(k) for k in ("takes", "rows", "by_split", "by_pose")},
                             "checks": [c.to_dict() for c in checks]})
        refs.extend(_ref("dataset", d.name, c) for c in checks)

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
    html = render_html(report, take_figs, ds_figs, plot_notes)
    qc = layout.root / "qc"
    qc.mkdir(exist_ok=True)
    layout.tmp.mkdir(parents=True, exist_ok=True)
    paths = [qc / "report.json", qc / "takes.parquet", qc / "report.html"]
    layout.write_bytes(paths[0], (json.dumps(report, indent=1, sort_keys=True, allow_nan=False,
                                             ensure_ascii=False) + "\n").encode())
    with atomic_path(paths[1], layout.tmp) as tmp:
        write_table(table, tmp, TAKES_SCHEMA)
    layout.write_bytes(paths[2], html.encode())
    n_figs = sum(len(v) for v in take_figs.values()) + sum(len(v) for v in ds_figs.values())
    return ValidateResult(report=report, paths=paths, passed=not hit, takes=table, html=html, figures=n_figs,
                          notes=plot_notes)


__all__ = ["FAIL_ON", "ReportInBackground", "ValidateResult", "dataset_checks", "take_checks", "validate_output"]
