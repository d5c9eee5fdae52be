"""Quality checks of the training datasets (``OUT/datasets/<name>/``), pure functions of _dataset.json and facts
gathered from the take files by :mod:`gazepipe.report.collect`.

=====================  =========================================  ===============================================
check                  warning                                    fail
=====================  =========================================  ===============================================
``dataset_read``       –                                          (error) _dataset.json, ``_common_metadata`` or a
                                                                  take file cannot be read
``schema_hash``        –                                          a file's Arrow schema differs from the one the
                                                                  code builds from _dataset.json's sizes
``split_disjoint``     –                                          a take has rows in two splits, or its rows'
                                                                  split differs from _dataset.json's
``counts``             a split is empty                           takes / rows per split and per pose in the
                                                                  files differ from _dataset.json's counts
``stats_sanity``       – (constant elements, and elements null    a mean or std is not finite; the training rows
                       in every training row, are listed)         counted differ; recomputed mean or variance on
                                                                  a seeded sample of training rows (all rows when
                                                                  fewer than ``stats_sample_rows``) differs by
                                                                  more than ``stats_max_z`` standard errors
``skipped_takes``      takes left out of the build                –
``null_parameters``    rows with null parameters (gaze_map: a     –
                       segment's P+ or start, the eyes' or the
                       overshoot's, NaN and False in ``known`` /
                       ``start_known``), counted per entry and
                       take with the first reason (a start null
                       because never reached: counted, no warning)
``windowed_rows``      under ``windowed_rows_warn`` of the rows   –
                       lie in segments at least one window long
                       (the rest feed no training window)
``split_consistent``   –                                          (output scope) a take in different splits in
                                                                  two datasets
=====================  =========================================  ===============================================

Standard errors of the sample checks: mean, σ·√((1 − n/N)/n) with σ the stored std; variance (from n ≥ 30),
√((m₄ − s⁴)(1 − n/N)/n) with s and m₄ the sample's std and fourth central moment (rows drawn without
replacement from the N training rows). A full sample (n = N) must match to float rounding (10⁻⁶ relative).
Null (NaN) values are left out element by element, as the statistics leave them out: n is an element's values
in the sample, N its stored ``count`` (the training rows without one).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe.report.checks import Check, Thresholds, skipped

SPLITS = ("train", "val", "test")


def _type_str(t: pa.DataType) -> str:
    """A type's text without list item names (Parquet stores ``element`` where Arrow says ``item``; Arrow's type
    equality ignores that name too)."""
    if pa.types.is_fixed_size_list(t):
        return f"fixed_size_list<{_type_str(t.value_type)}>[{t.list_size}]"
    if pa.types.is_list(t) or pa.types.is_large_list(t):
        return f"{'large_' if pa.types.is_large_list(t) else ''}list<{_type_str(t.value_type)}>"
    return str(t)


def schema_hash(schema: pa.Schema) -> str:
    """sha256 (first 16 hex digits) of an Arrow schema's fields (name, type, nullability) and its table name and
    schema version tags; the per-file ``gazepipe.meta`` is left out."""
    md = schema.metadata or {}
    parts = [f"{f.name}:{_type_str(f.type)}:{f.nullable}" for f in schema]
    parts.append(f"table={md.get(b'gazepipe.table', b'').decode()}")
    parts.append(f"version={md.get(b'gazepipe.schema_version', b'').decode()}")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


@dataclass
class FileFacts:
    """What one take file holds: its path relative to the dataset (``<folder>/<session>/<take>.parquet``: the
    split folder, session and take it names), the identifiers inside it (``*_column``, "" when they are not one
    value), rows per split, schema hash."""

    path: str
    session: str
    take: str
    folder: str = ""
    subject: str = ""
    pose: str = ""
    session_column: str = ""
    take_column: str = ""
    rows_by_split: dict[str, int] = field(default_factory=dict)
    schema_hash: str = ""
    error: str = ""


@dataclass
class StatsSample:
    """A seeded sample of training rows: per feature column an (n, D) float64 array, the pose of each row,
    and the number of training rows overall and per pose it was drawn from."""

    columns: dict[str, np.ndarray]
    pose: np.ndarray
    n_total: int
    n_total_by_pose: dict[str, int]


def check_schema(expected: pa.Schema | None, common: pa.Schema | None, files: list[FileFacts],
                 common_error: str = "") -> Check:
    if expected is None:
        return Check("schema_hash", "error", "no schema can be built from _dataset.json (name or sizes missing)")
    want = schema_hash(expected)
    bad: dict[str, str] = {}
    if common is None:
        bad["_common_metadata"] = common_error or "missing"
    elif schema_hash(common) != want:
        bad["_common_metadata"] = schema_hash(common)
    for f in files:
        if f.schema_hash and f.schema_hash != want:
            bad[f.path] = f.schema_hash
    details = {"expected": want, "mismatched": bad, "files": len(files)}
    if bad:
        first = next(iter(sorted(bad)))
        return Check("schema_hash", "fail", f"{len(bad)} file(s) differ from the schema in code, e.g. {first}",
                     value=want, details=details)
    return Check("schema_hash", "pass", f"_common_metadata and {len(files)} take file(s) match schema {want}",
                 value=want, details=details)


def check_splits(info: dict[str, Any], files: list[FileFacts]) -> Check:
    """A take (session, take) has its rows in one split, the one its folder names and _dataset.json lists it
    under; the session and take inside the file are the ones its path names."""
    listed: dict[str, str] = {}
    for split, takes in (info.get("splits", {}).get("takes") or {}).items():
        for t in takes:
            listed[str(t)] = split
    problems: list[str] = []
    seen: dict[str, set[str]] = {}
    for f in files:
        tid = f"{f.session}/{f.take}"
        splits = {s for s, n in f.rows_by_split.items() if n}
        seen.setdefault(tid, set()).update(splits)
        if f.folder and splits and splits != {f.folder}:
            problems.append(f"{f.path}: rows in {sorted(splits)}, the file lies in folder {f.folder!r}")
        for what, got, want in (("session", f.session_column, f.session), ("take", f.take_column, f.take)):
            if got and got != want:
                problems.append(f"{f.path}: column {what!r} holds {got!r}, the path says {want!r}")
    for tid, splits in sorted(seen.items()):
        if len(splits) > 1:
            problems.append(f"take {tid} has rows in {sorted(splits)}")
        elif splits and tid in listed and listed[tid] not in splits:
            problems.append(f"take {tid}: rows in {sorted(splits)[0]}, _dataset.json lists it in {listed[tid]}")
    if problems:
        return Check("split_disjoint", "fail", problems[0] + (f" (+{len(problems) - 1} more)" if len(problems) > 1
                                                              else ""), value=len(problems),
                     details={"problems": problems})
    per = {s: sum(1 for v in seen.values() if v == {s}) for s in SPLITS}
    return Check("split_disjoint", "pass", "every take in one split: " + ", ".join(f"{n} {s}" for s, n in per.items()),
                 value=0, details={"takes_per_split": per})


def check_counts(info: dict[str, Any], files: list[FileFacts]) -> Check:
    counts = info.get("counts", {})
    by_split = {s: {"takes": 0, "rows": 0} for s in SPLITS}
    by_pose: dict[str, dict[str, int]] = {}
    for f in files:
        rows = sum(f.rows_by_split.values())
        for s, n in f.rows_by_split.items():
            if n:
                by_split.setdefault(s, {"takes": 0, "rows": 0})
                by_split[s]["takes"] += 1
                by_split[s]["rows"] += n
        p = by_pose.setdefault(f.pose, {"takes": 0, "rows": 0})
        p["takes"] += 1
        p["rows"] += rows
    found = {"takes": len(files), "rows": sum(sum(f.rows_by_split.values()) for f in files),
             "by_split": by_split, "by_pose": dict(sorted(by_pose.items()))}
    problems = []
    if counts.get("takes") != found["takes"]:
        problems.append(f"{found['takes']} take files, _dataset.json counts {counts.get('takes')}")
    if counts.get("rows") != found["rows"]:
        problems.append(f"{found['rows']} rows in the files, _dataset.json counts {counts.get('rows')}")
    for s in SPLITS:
        want = (counts.get("by_split") or {}).get(s)
        if want is not None and (want.get("takes"), want.get("rows")) != (by_split[s]["takes"], by_split[s]["rows"]):
            problems.append(f"split {s}: files hold {by_split[s]['takes']} takes / {by_split[s]['rows']} rows, "
                            f"_dataset.json {want.get('takes')} / {want.get('rows')}")
    for p, want in sorted((counts.get("by_pose") or {}).items()):
        got = by_pose.get(p, {"takes": 0, "rows": 0})
        if (want.get("takes"), want.get("rows")) != (got["takes"], got["rows"]):
            problems.append(f"pose {p}: files hold {got['takes']} takes / {got['rows']} rows, _dataset.json "
                            f"{want.get('takes')} / {want.get('rows')}")
    details = {"found": found, "problems": problems}
    summary = "; ".join(f"{s} {by_split[s]['takes']} takes / {by_split[s]['rows']} rows" for s in SPLITS)
    if problems:
        return Check("counts", "fail", problems[0], value=len(problems), details=details)
    empty = [s for s in SPLITS if by_split[s]["takes"] == 0]
    if empty:
        return Check("counts", "warning", f"empty split(s) {', '.join(empty)}; {summary}", value=0, details=details)
    return Check("counts", "pass", summary, value=0, details=details)


def _stat_arrays(block: dict[str, Any], column: str) -> tuple[np.ndarray, np.ndarray] | None:
    s = block.get(column)
    if not isinstance(s, dict) or "mean" not in s or "std" not in s:
        return None
    return (np.array([np.nan if x is None else x for x in s["mean"]], dtype=np.float64),
            np.array([np.nan if x is None else x for x in s["std"]], dtype=np.float64))


def _stat_count(block: dict[str, Any], column: str) -> np.ndarray | None:
    """The stored per-element count of values that are not null, or None (statistics without one)."""
    c = (block.get(column) or {}).get("count")
    return np.array([0 if x is None else x for x in c], dtype=np.float64) if isinstance(c, list) else None


def _compare(values: np.ndarray, n_total: int, mean: np.ndarray, std: np.ndarray,
             max_z: float, count: np.ndarray | None = None) -> tuple[float, str]:
    """Largest z of the sample's mean and variance against the stored ones, and which it was. NaN values are
    left out per element; ``count`` (D,) is each element's values among the ``n_total`` training rows."""
    if values.shape[0] == 0 or values.shape[1] != mean.size:
        return (float("inf"), f"{values.shape[1]} values per row, statistics have {mean.size}")
    ok = ~np.isnan(values)
    n = ok.sum(axis=0).astype(np.float64)                  # per element
    total = np.full(mean.size, float(n_total)) if count is None or count.size != mean.size else count
    if (n > total).any():
        i = int(np.argmax(n - total))
        return (float("inf"), f"element {i}: {int(n[i])} values in the sample, statistics count {int(total[i])}")
    nn = np.maximum(n, 1.0)
    m = np.where(ok, values, 0.0).sum(axis=0) / nn
    dev = np.where(ok, values - m, 0.0)
    v = (dev ** 2).sum(axis=0) / nn
    full = n >= total
    slack = 1e-6 * (np.abs(mean) + std) + 1e-9
    fpc = np.maximum(1.0 - n / np.maximum(total, 1.0), 0.0)
    # the stored std sets the mean's standard error (a wrong std is the variance test's business); the
    # variance's standard error needs the fourth moment, estimated only from 30 values up
    z_m = np.where(full, np.abs(m - mean) / slack, np.abs(m - mean) / (std * np.sqrt(fpc / nn) + slack))
    m4 = (dev ** 4).sum(axis=0) / nn
    se_v = np.sqrt(np.maximum(m4 - v**2, 0.0) * fpc / nn) + slack * (std + 1e-9)
    z_v = np.where(full, np.abs(v - std**2) / (1e-6 * (std**2 + np.abs(mean) * std) + 1e-12),
                   np.where(n >= 30, np.abs(v - std**2) / se_v, 0.0))
    z_m, z_v = np.where(n > 0, z_m, 0.0), np.where(n > 0, z_v, 0.0)
    i_m, i_v = int(np.argmax(z_m)), int(np.argmax(z_v))
    if z_m[i_m] >= z_v[i_v]:
        return float(z_m[i_m]), f"mean of element {i_m}: {m[i_m]:.6g} vs {mean[i_m]:.6g}"
    return float(z_v[i_v]), f"std of element {i_v}: {np.sqrt(v[i_v]):.6g} vs {std[i_v]:.6g}"


def check_stats(info: dict[str, Any], sample: StatsSample | None, th: Thresholds) -> Check:
    stats = info.get("stats")
    if not isinstance(stats, dict) or "overall" not in stats:
        return Check("stats_sanity", "fail", "_dataset.json has no normalisation statistics")
    columns = list((info.get("features") or {}).keys())
    blocks = {"overall": stats["overall"], **{f"pose {p}": b for p, b in sorted(stats.get("per_pose", {}).items())}}
    nonfinite, constant, missing, unknown = _stat_problems(blocks, columns)
    details: dict[str, Any] = {"nonfinite": nonfinite, "constant": constant, "missing": missing,
                               "null_in_every_training_row": unknown}
    problems = [f"non-finite statistics in {nonfinite[0]}"] if nonfinite else []
    if missing:
        problems.append(f"no statistics for {missing[0]}")
    worst_z = 0.0
    if sample is not None:
        rows = stats["overall"].get("rows")
        details["training_rows"] = sample.n_total
        details["sample_rows"] = int(sample.pose.size)
        if rows != sample.n_total:
            problems.append(f"statistics count {rows} training rows, the files hold {sample.n_total}")
        worst_z, worst_what = _recomputed(blocks, columns, sample, th, problems)
        details["worst_z"] = worst_z
        details["worst"] = worst_what
        if worst_z > th.stats_max_z:
            problems.append(f"recomputed statistics disagree ({worst_what}, {worst_z:.1f} standard errors)")
    if problems:
        return Check("stats_sanity", "fail", problems[0], value=worst_z, threshold={"max_z": th.stats_max_z},
                     details=details)
    how = "" if sample is None else f"; recomputed on {sample.pose.size} of {sample.n_total} training rows, " \
        f"worst {worst_z:.1f} standard errors"
    # an element constant over the training rows carries no information, and the readers normalise it by 1
    # rather than blow it up: a fact to show (e.g. a segment that never reaches gaze_map's start speed, a
    # blendshape the tracker never moves), not a problem
    note = f"; constant (std 0, normalised by 1): {', '.join(constant[:4])}" if constant else "; std > 0"
    if unknown:
        note += f"; null in every training row (mean 0, std 0): {', '.join(unknown[:4])}"
    return Check("stats_sanity", "pass", f"finite{note}{how}", value=worst_z,
                 threshold={"max_z": th.stats_max_z}, details=details)


def _stat_problems(blocks: dict[str, Any], columns: list[str]) -> tuple[list[str], list[str], list[str], list[str]]:
    """What the statistics blocks (overall, per pose) say of themselves: columns with non-finite statistics,
    elements constant over the training rows, columns without statistics, elements null in every training row
    (the last two overall only)."""
    nonfinite, constant, missing, unknown = [], [], [], []
    for where, block in blocks.items():
        for c in columns:
            arr = _stat_arrays(block, c)
            if arr is None:
                missing.append(f"{where} {c}")
                continue
            mean, std = arr
            if not (np.isfinite(mean).all() and np.isfinite(std).all()):
                nonfinite.append(f"{where} {c}")
            elif where == "overall":
                count = _stat_count(block, c)
                none = np.zeros(std.size, bool) if count is None or count.size != std.size else count == 0
                if none.any():
                    unknown.append(f"{c}[{', '.join(str(i) for i in np.flatnonzero(none)[:8])}]")
                if np.any((std <= 0) & ~none):
                    constant.append(f"{c}[{', '.join(str(i) for i in np.flatnonzero((std <= 0) & ~none)[:8])}]")
    return nonfinite, constant, missing, unknown


def _recomputed(blocks: dict[str, Any], columns: list[str], sample: StatsSample, th: Thresholds,
                problems: list[str]) -> tuple[float, str]:
    """The statistics recomputed on the sampled training rows against the blocks': the worst disagreement
    (standard errors) and where it is; a per-pose block whose row count differs from the files' joins
    ``problems``."""
    worst_z, worst_what = 0.0, ""
    for where, block in blocks.items():
        pose = None if where == "overall" else where[5:]
        sel = np.ones(sample.pose.size, bool) if pose is None else sample.pose == pose
        n_total = sample.n_total if pose is None else sample.n_total_by_pose.get(pose, 0)
        if pose is not None and block.get("rows") != n_total:
            problems.append(f"{where}: statistics count {block.get('rows')} training rows, files {n_total}")
        if not sel.any():
            continue
        for c in columns:
            arr = _stat_arrays(block, c)
            if arr is None or c not in sample.columns or not np.isfinite(arr[0]).all():
                continue
            z, what = _compare(sample.columns[c][sel], n_total, arr[0], arr[1], th.stats_max_z,
                               _stat_count(block, c))
            if z > worst_z:
                worst_z, worst_what = z, f"{where} {c} {what}"
    return worst_z, worst_what


def check_skipped(info: dict[str, Any], left_out: list[dict[str, Any]] | None = None) -> Check:
    """Every take the dataset applies to and has no rows of: those the build left out (``info["skipped"]``: no
    usable rows) and those that could not feed it (``left_out``, from the build's record: a stage it needs
    failed or never ran)."""
    sk = list(left_out or []) + list(info.get("skipped") or [])
    if not sk:
        return Check("skipped_takes", "pass", "no take left out", value=0)
    first = sk[0]
    return Check("skipped_takes", "warning", f"{len(sk)} take(s) left out, e.g. {first.get('session')}/"
                 f"{first.get('take')}: {first.get('reason')}", value=len(sk), details={"skipped": sk})


def check_null_parameters(info: dict[str, Any]) -> Check:
    """Rows that keep their take with some parameters null (gaze_map: a segment's P+ or start time, the eyes'
    P+, the overshoot; ``counts.null_segments`` and each take's ``null_segments`` / ``null_reasons``): a
    warning that counts them, never a failure (the rest of those rows is computed). A start time that is null
    because the segment never reached the start speed (each take's ``no_start``) is the rule, not a failure:
    counted in the details and the message, never a warning."""
    counts = info.get("counts") or {}
    if "null_segments" not in counts:
        return skipped("null_parameters", "rows of this dataset have no null parameters")
    per_take = {t: q.get("null_segments") or [] for t, q in (counts.get("per_take") or {}).items()
                if isinstance(q, dict)}
    no_start = {t: q.get("no_start") or [] for t, q in (counts.get("per_take") or {}).items()
                if isinstance(q, dict) and q.get("no_start")}
    takes = sorted(t for t, v in per_take.items() if v)
    by = dict(sorted((counts.get("null_segments") or {}).items(), key=lambda kv: (-kv[1], kv[0])))
    details = {"null_segments": by, "takes": {t: per_take[t] for t in takes},
               "reasons": {t: (counts["per_take"][t].get("null_reasons") or {}) for t in takes},
               "no_start": no_start}
    n_no = sum(len(v) for v in no_start.values())
    tail = (f"; {n_no} start time(s) null in {len(no_start)} take(s) because the segment never reached the start "
            "speed (the rule, not a failure)" if n_no else "")
    if not takes:
        return Check("null_parameters", "pass", f"every parameter of the {len(per_take)} take(s) computed{tail}",
                     value=0, details=details)
    first = takes[0]
    reason = next(iter(details["reasons"][first].values()), "")
    return Check("null_parameters", "warning",
                 f"{len(takes)} of {len(per_take)} take(s) have null parameters ("
                 + ", ".join(f"{k} {v}" for k, v in list(by.items())[:6])
                 + f"); their other values stand. E.g. {first}: {', '.join(per_take[first])}"
                 + (f" ({reason})" if reason else "") + tail, value=len(takes), details=details)


def check_windowed_rows(info: dict[str, Any], th: Thresholds) -> Check:
    """Share of a windowed dataset's rows in segments (runs of usable frames) at least one window long: a
    window never spans a break, so the other rows feed no training window."""
    counts, window = info.get("counts") or {}, info.get("window")
    if window is None or "rows_in_segments_with_a_window" not in counts or not counts.get("rows"):
        return skipped("windowed_rows", "no windows in this dataset")
    # the segment counts are over the takes' own rows: mirrored copies (in "rows") double both alike
    rows, inside = int(counts.get("rows_in_segments", counts["rows"])), int(counts["rows_in_segments_with_a_window"])
    share = inside / rows
    sev = "warning" if th.windowed_rows_warn is not None and share < th.windowed_rows_warn else "pass"
    return Check("windowed_rows", sev, f"{counts.get('segments_with_a_window')} of {counts.get('segments')} "
                 f"segments ({inside} of {rows} rows, {100 * share:.0f} %) are at least one {window}-frame window "
                 "long" + ("; the other rows feed no training window (longer takes, or fewer gaps in the eyes and "
                           "video, give more)" if sev == "warning" else ""), value=share,
                 threshold={"warning": th.windowed_rows_warn, "fail": None})


def check_split_consistency(splits: dict[str, dict[str, str]]) -> Check:
    """``splits``: dataset name → {take key → split}. A take must be in the same split in every dataset."""
    if not splits:
        return skipped("split_consistent", "no dataset")
    by_take: dict[str, dict[str, str]] = {}
    for ds, takes in sorted(splits.items()):
        for t, s in takes.items():
            by_take.setdefault(t, {})[ds] = s
    bad = {t: d for t, d in sorted(by_take.items()) if len(set(d.values())) > 1}
    if bad:
        t, d = next(iter(bad.items()))
        return Check("split_consistent", "fail", f"take {t} is in different splits: "
                     + ", ".join(f"{k} {v}" for k, v in d.items()), value=len(bad), details={"takes": bad})
    return Check("split_consistent", "pass", f"{len(by_take)} take(s) in the same split in every dataset", value=0)
