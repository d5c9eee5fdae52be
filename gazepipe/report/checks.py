"""Quality checks of one take, as pure functions of its unit records and tables (``gazepipe validate``).

A stage's QC comes in as its QC dataclass (:class:`~gazepipe.stages.sync.qc.SyncQC`, …), read by attribute;
``None`` when the stage did not run ok on the take. A record whose QC does not parse never gets here: its checks
are ``error`` (:func:`qc_record_errors`).

Every check returns :class:`Check` results with a severity: ``pass``, ``warning``, ``fail``, ``error`` (the
check could not be evaluated: an unreadable table, a record without the keys it needs) or ``skipped`` (not
applicable: the take has no video, no eye tracking, …). Dataset checks are in
:mod:`gazepipe.report.checks_datasets`.

Thresholds (:class:`Thresholds`; every one is a parameter, stored in ``report.json``):

======================================  ==============  ===========  =============================================
check                                   warning         fail         measured on
======================================  ==============  ===========  =============================================
``stages``                              a unit is       a unit       every unit record of the take (status), and
                                        stale or never  failed       whether it is up to date with its inputs now
                                        ran
``stage_warnings``                      a stage warned  –            the warnings each stage recorded (a file
                                                                     100 % invalid, head tracking off, …)
``gap_share``                           > 20 %          –            per marker, share of the take's frames that
                                                                     were gaps at ingest (worst marker)
``longest_gap``                         > 1.0 s         –            per marker, longest gap after spike removal
``fill_error``                          > 10 mm         –            per filled gap, its estimated error (the one
                                                                     its keep/reject decision used, quoted by the
                                                                     markers table and the replay)
``unfilled``                            > 5 %           > 30 %       per marker, unfilled share of the kept
                                                                     (cropped) frames (worst marker): at most
                                                                     a warning; the fail grades the share of
                                                                     kept frames that lose their dataset rows
                                                                     where a marker is unfilled (joints row
                                                                     without rotations or target)
``spikes``                              > 1 %           –            per marker, share of samples removed as spikes
``swaps``                               a stretch not   –            label swaps per marker pair: repaired (their
                                        provable                     samples coded ``swap_repaired``), or made gaps
``crop``                                kept < 0.5 s,   –            crop bounds and rests of the clean stage
                                        a missing rest
``invalid_frames``                      > 20 %          > 60 %       kept frames without a character frame or
                                                                     segment rotation (frames stage)
``clap_confidence``                     < 0.5           –            lowest mocap or video clap confidence
``clock_drift``                         |drift| >       –            sync: 2+ claps: |ratio − 1| (a camera
                                        2000 ppm                     labelled 60 fps running at 59.94 is 1000 ppm,
                                                                     corrected by the clock map); skipped with
                                                                     one clap (not measurable)
``clap_residual``                       > 1 frame       –            sync: largest clap-pair misfit (3+ claps)
``clock_map``                           –               > 5 ms       sync: how far the clock map may be off over
                                                                     the crop (clean) mapped onto the video clock,
                                                                     or the whole video without a crop: each
                                                                     clap's timing carried through the weighted
                                                                     fit, with the ratio's prior (a 90 %
                                                                     bound); names the clap that limits it
``frames_without_video``                > 5 %           > 50 %       sync: mocap frames outside the video
``eye_gated``                           > 30 %          > 60 %       eyes: share of video samples gated out
``eye_longest_invalid``                 > 1.0 s         –            eyes: longest invalid run after slerp fill
``camera_residual``                     > 3°            > 10°        eyes: camera-rotation residual angle
``face_unmatched``                      > 5 %           > 50 %       face: tracked frames without a clean frame
``face_dropped``                        > 5 %           –            face: dropped capture frames of either track
======================================  ==============  ===========  =============================================

``clap_offset`` is reported (value only) and passes whenever the sync stage found a clock map.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gazepipe.model import FILL_CODES
from gazepipe.stages.clean.qc import CleanQC
from gazepipe.stages.eyes.qc import EyesQC
from gazepipe.stages.face.qc import FaceQC
from gazepipe.stages.frames.qc import FramesQC
from gazepipe.stages.ingest_qc import IngestQC
from gazepipe.stages.sync.qc import SyncQC

SEVERITIES = ("skipped", "pass", "warning", "fail", "error")
#: sort rank: failing checks first
RANK = {"error": 4, "fail": 3, "warning": 2, "pass": 1, "skipped": 0}
UNFILLED = FILL_CODES["unfilled"]
MEASURED = FILL_CODES["measured"]
SWAP_REPAIRED = FILL_CODES["swap_repaired"]     # measured, under its right name: not a fill


@dataclass(frozen=True)
class Thresholds:
    """Severity thresholds of every check (see the table in the module docstring). ``None`` disables one."""

    gap_share_warn: float | None = 0.20
    longest_gap_warn_s: float | None = 1.0
    fill_error_warn_mm: float | None = 10.0
    unfilled_warn: float | None = 0.05
    unfilled_fail: float | None = 0.30
    spikes_warn: float | None = 0.01
    kept_min_s: float | None = 0.5
    invalid_frames_warn: float | None = 0.20
    invalid_frames_fail: float | None = 0.60
    clap_confidence_warn: float | None = 0.5
    drift_warn_ppm: float | None = 2000.0
    clap_residual_warn_frames: float | None = 1.0
    clock_bound_fail_ms: float | None = 5.0
    no_video_warn: float | None = 0.05
    no_video_fail: float | None = 0.50
    eye_gated_warn: float | None = 0.30
    eye_gated_fail: float | None = 0.60
    eye_longest_invalid_warn_s: float | None = 1.0
    camera_residual_warn_deg: float | None = 3.0
    camera_residual_fail_deg: float | None = 10.0
    face_unmatched_warn: float | None = 0.05
    face_unmatched_fail: float | None = 0.50
    face_dropped_warn: float | None = 0.05
    windowed_rows_warn: float | None = 0.5
    stats_sample_rows: int = 20000
    stats_max_z: float = 6.0
    stats_seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> Thresholds:
        known = {f.name for f in dataclasses.fields(cls)}
        bad = sorted(set(values) - known)
        if bad:
            raise KeyError(bad[0])
        return cls(**values)


@dataclass
class Check:
    """One check's outcome.

    Attributes
    ----------
    id : the check's name (``gap_share``, ``split_disjoint`` …).
    severity : one of :data:`SEVERITIES`.
    message : one line for people.
    value : the measured number (or ``None``).
    threshold : ``{"warning": x, "fail": y}`` as applied (``None`` entries: not used).
    details : JSON-able facts behind the value (per-marker values, offending takes …).
    """

    id: str
    severity: str
    message: str
    value: float | int | str | None = None
    threshold: dict[str, Any] | None = None
    details: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "severity": self.severity, "message": self.message, "value": _clean(self.value),
                "threshold": self.threshold, "details": _clean(self.details)}


def _clean(v: Any) -> Any:
    """JSON-safe copy: numpy scalars to Python, non-finite floats to None."""
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v


def worst(severities: Sequence[str]) -> str:
    """The most severe of ``severities`` (``skipped`` for none)."""
    return max(severities, key=RANK.__getitem__, default="skipped")


def grade(value: float, warn: float | None, fail: float | None, *, below: bool = False) -> str:
    """``fail`` / ``warning`` / ``pass`` for ``value`` above (``below=True``: under) the thresholds."""
    def hit(t: float | None) -> bool:
        return t is not None and (value < t if below else value > t)
    if hit(fail):
        return "fail"
    if hit(warn):
        return "warning"
    return "pass"


#: checks whose value is worse the lower it is (the others: the higher)
_LOWER_IS_WORSE = frozenset({"clap_confidence"})


def threshold_reach(c: dict[str, Any]) -> float:
    """How far a check's value (a report.json check) has gone towards its warning threshold (its fail threshold
    when it has no warning one): 0.5 halfway, 1 at it, 2 twice past it; 0 for a check without a number or a
    threshold."""
    value, thr = c.get("value"), c.get("threshold") or {}
    limit = thr.get("warning") if thr.get("warning") is not None else thr.get("fail")
    if isinstance(value, bool) or not isinstance(value, int | float) or not isinstance(limit, int | float) \
            or not np.isfinite(value) or limit <= 0:
        return 0.0
    if c["id"] in _LOWER_IS_WORSE:
        return float(limit) / value if value > 0 else float("inf")
    return max(float(value), 0.0) / float(limit)


def rank_key(severity: str, checks: Sequence[dict[str, Any]], name: str) -> tuple:
    """Sort key of a take or dataset of the report, worst first: its severity (error, fail, warning, pass), then
    its number of checks at fail or error, then of warnings, then the check nearest to (or furthest past) its
    threshold (:func:`threshold_reach`), then its name. The plots and the summary table both rank by it."""
    return (-RANK[severity], -sum(c["severity"] in ("fail", "error") for c in checks),
            -sum(c["severity"] == "warning" for c in checks), -max(map(threshold_reach, checks), default=0.0),
            name)


def _thr(warn: float | None, fail: float | None = None) -> dict[str, Any]:
    return {"warning": warn, "fail": fail}


def _pct(x: float) -> str:
    return f"{100.0 * x:.1f} %"


def skipped(check_id: str, why: str) -> Check:
    return Check(check_id, "skipped", f"not applicable: {why}")


#: the stages whose QC each take check reads: its own stage first, then those it takes counts from (the ingest's
#: frames and rate, the clean stage's kept frames)
CHECK_READS: dict[str, tuple[str, ...]] = {
    "gap_share": ("ingest",), "longest_gap": ("clean",), "fill_error": ("clean",), "spikes": ("clean", "ingest"),
    "swaps": ("clean",), "crop": ("clean", "ingest"), "invalid_frames": ("frames", "clean"),
    "clap_offset": ("sync",), "clap_confidence": ("sync",), "clock_drift": ("sync",),
    "clap_residual": ("sync", "ingest"), "clock_map": ("sync", "clean"), "frames_without_video": ("sync", "ingest"),
    "eye_gated": ("eyes",), "eye_longest_invalid": ("eyes",), "camera_residual": ("eyes",),
    "face_unmatched": ("face",), "face_dropped": ("face",),
}


def qc_record_errors(checks: list[Check], errors: dict[str, str], parsed: set[str]) -> list[Check]:
    """``checks`` with each check that reads a QC record that does not parse made an ``error`` naming the record
    file and the key (``errors``: stage → why, one line): always when it is the check's own stage's record; when
    it is a record the check takes counts from, if the check's own stage's QC is there (``parsed``: the stages
    whose QC parsed), so a check never passes, or is skipped, for want of a key."""
    out = []
    for c in checks:
        reads = CHECK_READS.get(c.id, ())
        bad = [s for i, s in enumerate(reads) if s in errors and (i == 0 or reads[0] in parsed)]
        if bad:
            c = Check(c.id, "error", f"{bad[0]} QC record unreadable: {errors[bad[0]]}",
                      details={"unreadable_qc": {s: errors[s] for s in bad}})
        out.append(c)
    return out


# ------------------------------------------------------------------------------------------------ stages

def check_stages(records: dict[str, dict[str, Any]], states: list[dict[str, Any]] | None = None) -> Check:
    """Every unit of the take ran ok and is up to date.

    ``records``: stage name → unit record. ``states``: the take's rows of
    :func:`gazepipe.pipeline.status.collect_status` (stage, state ok | failed | stale | pending, detail), or
    ``None`` when the sessions cannot be read now (freshness is then not checked).
    """
    failed = {s: r.get("error", "") for s, r in records.items() if r.get("status") != "ok"}
    # a take that fails while the run plans it (a missing or unreadable input) leaves no record: its state says so
    failed.update({r["stage"]: r.get("detail", "") for r in states or []
                   if r.get("state") == "failed" and r.get("stage") not in records})
    details: dict[str, Any] = {"ran": sorted(records)}
    if failed:
        first = next(iter(sorted(failed)))
        details["failed"] = failed
        return Check("stages", "fail", f"stage {first} failed: {failed[first]}", value=len(failed), details=details)
    behind = {r["stage"]: f"{r['state']}: {r.get('detail', '')}".rstrip(": ")
              for r in states or [] if r.get("state") in ("stale", "pending")}
    if behind:
        details["not_up_to_date"] = behind
        first = next(iter(behind))
        what = "never ran" if behind[first].startswith("pending") else behind[first]
        return Check("stages", "warning", f"{len(behind)} stage(s) not up to date with the inputs, e.g. {first} "
                     f"({what})", value=len(behind), details=details)
    if not records:
        return Check("stages", "warning", "no stage has run on this take", details=details)
    fresh = "" if states is None else ", up to date"
    return Check("stages", "pass", f"{len(records)} stage(s) ok{fresh}: {', '.join(sorted(records))}", value=0,
                 details=details)


def check_stage_warnings(records: dict[str, dict[str, Any]]) -> Check:
    """The warnings the take's stages recorded, so none goes unseen."""
    per = {s: list(r.get("warnings") or []) for s, r in sorted(records.items()) if r.get("warnings")}
    n = sum(len(w) for w in per.values())
    if not n:
        return Check("stage_warnings", "pass", "no stage warning", value=0)
    stage, first = next((s, w[0]) for s, w in per.items())
    more = f" (+{n - 1} more)" if n > 1 else ""
    return Check("stage_warnings", "warning", f"{stage}: {first}{more}", value=n, details={"warnings": per})


# ------------------------------------------------------------------------------------------------ markers

def check_gap_share(ingest_qc: IngestQC | None, th: Thresholds) -> Check:
    """Worst marker's share of frames that were gaps at ingest."""
    gf = None if ingest_qc is None else ingest_qc.gap_fraction
    if not gf:
        return skipped("gap_share", "no ingest record with gap shares")
    worst_m = max(sorted(gf), key=lambda k: gf[k])
    v = float(gf[worst_m])
    over = sorted(k for k, x in gf.items() if th.gap_share_warn is not None and x > th.gap_share_warn)
    sev = grade(v, th.gap_share_warn, None)
    msg = f"largest gap share {_pct(v)} ({worst_m})"
    if over and th.gap_share_warn is not None:
        msg += f"; {len(over)} marker(s) above {_pct(th.gap_share_warn)}"
    return Check("gap_share", sev, msg, value=v, threshold=_thr(th.gap_share_warn),
                 details={"per_marker": dict(sorted(gf.items())), "over": over})


def check_longest_gap(clean_qc: CleanQC | None, th: Thresholds) -> Check:
    markers = None if clean_qc is None else clean_qc.markers
    if not markers:
        return skipped("longest_gap", "no clean record")
    per = {k: float(v.longest_gap_s) for k, v in sorted(markers.items())}
    worst_m = max(per, key=lambda k: per[k])
    v = per[worst_m]
    return Check("longest_gap", grade(v, th.longest_gap_warn_s, None), f"longest gap {v:.2f} s ({worst_m})",
                 value=v, threshold=_thr(th.longest_gap_warn_s), details={"per_marker_s": per})


def check_fill_error(clean_qc: CleanQC | None, th: Thresholds) -> Check:
    """The estimated error of every filled gap, the worst one graded: the estimate the filler kept or rejected the
    fill on (``GapQC.error_mm``), the very figure the markers table's ``fill_error_mm`` and the replay quote.
    Gaps left unfilled are counted by reason (those without an error estimate apart)."""
    if clean_qc is None:
        return skipped("fill_error", "no clean record")
    gaps = clean_qc.gaps
    errs = [(e, g) for g in gaps if g.method != "unfilled" and (e := g.error_mm) is not None and np.isfinite(e)]
    methods = Counter(g.method for g in gaps)
    unfilled = dict(sorted(Counter(g.reason for g in gaps if g.method == "unfilled").items()))
    details: dict[str, Any] = {"gaps_by_method": dict(sorted(methods.items())), "unfilled_by_reason": unfilled}
    left = sum(unfilled.values())
    why = "" if not left else f"; {left} gap(s) left unfilled, e.g. {max(unfilled, key=lambda k: unfilled[k])}"
    if not errs:
        return Check("fill_error", "pass", f"{len(gaps)} gap(s), none filled{why}", details=details)
    e, g = max(errs, key=lambda eg: eg[0])
    over = sum(1 for x, _ in errs if th.fill_error_warn_mm is not None and x > th.fill_error_warn_mm)
    msg = f"worst fill estimated error {e:.1f} mm ({g.marker} frames {g.start}-{g.stop}, {g.method})"
    if over:
        msg += f"; {over} gap(s) above {th.fill_error_warn_mm:g} mm"
    msg += why
    return Check("fill_error", grade(e, th.fill_error_warn_mm, None), msg, value=float(e),
                 threshold=_thr(th.fill_error_warn_mm),
                 details={**details, "over": over, "median_mm": float(np.median([x for x, _ in errs]))})


def fill_shares(fill: np.ndarray, labels: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per marker, the share of rows of each fill method; ``fill`` (T, M) int8 fill codes."""
    n = max(fill.shape[0], 1)
    return {lab: {name: float(np.count_nonzero(fill[:, m] == code)) / n for name, code in FILL_CODES.items()}
            for m, lab in enumerate(labels)}


def check_unfilled(fill: np.ndarray | None, labels: Sequence[str], th: Thresholds, *,
                   kept_frames: np.ndarray | None = None, row_frames: np.ndarray | None = None,
                   feeds: bool = True) -> Check:
    """Unfilled markers of the kept frames, graded by what they cost the datasets.

    A marker left unfilled costs a dataset row only on a frame whose joints row can then give none (no
    character frame, a segment's rotation missing, no target direction): a frame whose rotations were still
    computed, e.g. from the segment's other markers, loses nothing. The worst marker's unfilled share of the
    kept frames is at most a warning (above ``unfilled_warn``); the share of the take's kept frames that are
    unfilled somewhere and give no row is graded against ``unfilled_warn`` and ``unfilled_fail``. Without a
    joints table (the frames stage did not run) every unfilled frame counts as lost; a take that feeds no
    dataset (``feeds=False``: a neutral take) loses none.

    Parameters
    ----------
    fill : (T, M) fill codes of the cleaned ``markers`` table (kept frames).
    labels : the M marker names.
    th : the thresholds.
    kept_frames : (T,) frame numbers of the fill rows.
    row_frames : frame numbers of the joints rows that can give dataset rows, or ``None`` without a joints table.
    feeds : whether the take feeds a dataset.
    """
    thr = {"warning": th.unfilled_warn, "fail": th.unfilled_fail,
           "rule": "a marker's unfilled share is at most a warning; the take fails on the share of its kept "
                   "frames that lose their dataset rows where a marker is unfilled"}
    if fill is None:
        return skipped("unfilled", "no cleaned markers table")
    if fill.shape[0] == 0:
        return Check("unfilled", "fail", "the cleaned take kept no frame", value=1.0, threshold=thr)
    unfilled = fill == UNFILLED
    share = np.count_nonzero(unfilled, axis=0) / fill.shape[0]
    m = int(np.argmax(share))
    v = float(share[m])
    per = {lab: float(s) for lab, s in zip(labels, share, strict=True)}
    filled = float(np.count_nonzero((fill != MEASURED) & (fill != UNFILLED) & (fill != SWAP_REPAIRED)) / fill.size)
    if not feeds:
        lost = np.zeros(fill.shape[0], dtype=bool)
        cost = "the take feeds no dataset: no row lost"
    elif row_frames is None or kept_frames is None:
        lost = unfilled.any(axis=1)
        cost = "no joints table: every frame with an unfilled marker counted as lost"
    else:
        lost = unfilled.any(axis=1) & ~np.isin(np.asarray(kept_frames), row_frames)
        cost = ""
    lost_share = float(np.count_nonzero(lost)) / fill.shape[0]
    lost_per = {lab: float(np.count_nonzero(unfilled[:, k] & lost)) / fill.shape[0]
                for k, lab in enumerate(labels) if share[k]}
    if not cost:
        cost = (f"costs {_pct(lost_share)} of the take's dataset rows (kept frames with a marker unfilled and no complete joints row)"
                if lost_share else "costs no dataset row (the frames' rotations were still computed)")
    sev = worst([grade(v, th.unfilled_warn, None), grade(lost_share, th.unfilled_warn, th.unfilled_fail)]
                if lost_share else [grade(v, th.unfilled_warn, None)])
    msg = (f"largest unfilled share of kept frames {_pct(v)} ({labels[m]}), {cost}; {_pct(filled)} of kept "
           "samples filled")
    return Check("unfilled", sev, msg, value=v, threshold=thr,
                 details={"per_marker": per, "filled_share": filled, "rows_lost_share": lost_share,
                          "rows_lost_per_marker": lost_per,
                          "unfilled_share_all": float(np.count_nonzero(unfilled) / fill.size)})


def check_spikes(clean_qc: CleanQC | None, frames: int | None, th: Thresholds) -> Check:
    markers = None if clean_qc is None else clean_qc.markers
    if not markers or not frames:
        return skipped("spikes", "no clean record")
    per = {k: int(v.spikes_removed) for k, v in sorted(markers.items())}
    worst_m = max(per, key=lambda k: per[k])
    v = per[worst_m] / frames
    total = sum(per.values())
    msg = f"{total} spike sample(s) removed; worst {worst_m} {_pct(v)} of its samples" if total else \
        "no spike removed"
    return Check("spikes", grade(v, th.spikes_warn, None), msg, value=v,
                 threshold=_thr(th.spikes_warn), details={"per_marker": {k: n for k, n in per.items() if n}})


def check_swaps(clean_qc: CleanQC | None) -> Check:
    """Label swaps the clean stage found, on any markers the table carries (listed in the markerset or not):
    repaired ones pass (their samples are measured, under the right names, coded ``swap_repaired`` on the gap
    timeline); a stretch it could not prove, made gaps, is a warning. The message counts stretches and samples,
    repaired and made gaps apart, per pair."""
    if clean_qc is None:
        return skipped("swaps", "no clean record of label swaps")
    if clean_qc.swaps_not_checked:
        return skipped("swaps", clean_qc.swaps_not_checked)
    pairs = clean_qc.swap_pairs
    repaired = sum(c.repaired for c in pairs.values())
    removed = sum(c.removed for c in pairs.values())
    if not pairs:
        return Check("swaps", "pass", "no label swap found", value=0.0)
    if any(c.repaired_samples is None or c.removed_samples is None for c in pairs.values()):
        # a record from a clean stage older than version 26 counted stretches only
        by_pair = ", ".join(f"{k} {c.repaired + c.removed}" for k, c in sorted(pairs.items()))
        msg = f"{repaired} label-swap stretch(es) repaired ({by_pair})"
        lost = ""
    else:
        by_pair = ", ".join(f"{k} {c.repaired_samples}" + (f"+{c.removed_samples} made gaps" if c.removed_samples
                                                             else "") for k, c in sorted(pairs.items()))
        msg = (f"{repaired} label-swap stretch(es) repaired, "
               f"{sum(c.repaired_samples or 0 for c in pairs.values())} sample(s) put back under their names "
               f"(per pair: {by_pair})")
        lost = f", {sum(c.removed_samples or 0 for c in pairs.values())},"
    if removed:
        msg += f"; {removed} stretch(es) not provable: both markers' samples there{lost} became gaps"
    return Check("swaps", "warning" if removed else "pass", msg, value=float(repaired + removed),
                 details={"per_pair": {k: c.to_record() for k, c in pairs.items()}})


def check_crop(clean_qc: CleanQC | None, kind: str, frames: int | None, rate_hz: float | None,
               th: Thresholds) -> Check:
    """Crop bounds from rests: long enough, and bounded by the rests the kind needs."""
    if clean_qc is None:
        return skipped("crop", "no clean record")
    a, b = clean_qc.crop
    rests = [list(r) for r in clean_qc.rests]
    kept_s = (b - a) / rate_hz if rate_hz else None
    problems = []
    if kind not in ("neutral", "gaze_shift") and frames:
        if a == 0:
            problems.append("no leading rest")
        if b >= frames:
            problems.append("no trailing rest")
    if kind == "gaze_shift" and len(rests) > 2:
        problems.append(f"{len(rests)} rests, cropped between the first two")
    if kind == "gaze_shift" and len(rests) < 2:
        problems.append(f"{len(rests)} rest(s) found, a gaze shift needs two: kept whole, no gaze_map row")
    short = kept_s is not None and th.kept_min_s is not None and kept_s < th.kept_min_s
    if short:
        problems.append(f"kept only {kept_s:.2f} s")
    for bound, hidden in zip(("start", "end"), clean_qc.crop_hidden or (0, 0), strict=True):
        if hidden:
            problems.append(f"its {bound} may be off by up to {hidden} frame(s): too few markers seen there")
    msg = f"kept frames [{a}, {b})" + (f" = {kept_s:.2f} s" if kept_s is not None else "") + \
        (f" of {frames}" if frames else "") + f", {len(rests)} rest(s)"
    if problems:
        msg += ": " + "; ".join(problems)
    return Check("crop", "warning" if problems else "pass", msg, value=kept_s,
                 threshold={"kept_min_s": th.kept_min_s}, details={"crop": [a, b], "rests": rests})


def check_invalid_frames(frames_qc: FramesQC | None, kept: int | None, th: Thresholds) -> Check:
    if frames_qc is None:
        return skipped("invalid_frames", "no frames record")
    n = int(frames_qc.invalid_frames)
    v = n / kept if kept else 0.0
    return Check("invalid_frames", grade(v, th.invalid_frames_warn, th.invalid_frames_fail),
                 f"{n} of {kept} kept frames ({_pct(v)}) without a full set of segment rotations", value=v,
                 threshold=_thr(th.invalid_frames_warn, th.invalid_frames_fail))


# --------------------------------------------------------------------------------------------------- sync

def _clap_on(qc: SyncQC, j: int) -> str:
    """Clap ``j`` (1-based) as a check names it: its number, mocap time and how its pair is timed."""
    c = qc.claps[j - 1]
    how = {"displacement": "the arm followed into contact", "match": "its motion matched to the mocap's",
           "burst": "the closing burst's end alone"}.get(c.video_timed_by or "", c.video_timed_by or "no video")
    return (f"clap {j} (mocap {float(c.mocap_s):.2f} s, timed to ±{c.timing_ms:.1f} ms: mocap "
            f"±{float(c.mocap_timing_ms):.1f}, video ±{float(c.video_timing_ms or 0.0):.1f} by {how})")


def check_clock_map(sync_qc: SyncQC, th: Thresholds, crop_s: tuple[float, float] | None = None) -> Check:
    """Whether the clock map can be shown within ``clock_bound_fail_ms`` over the span that feeds the datasets
    (SPEC §3.4): ``crop_s`` (the first and last kept mocap frame's time, s) mapped onto the video clock and
    kept within the video, or the whole video without a crop. The bound is the sync's fit carried to that
    span's ends (:meth:`SyncQC.bound_over`); the message names the claps the map rests on and, when it fails, the
    clap whose timing limits it (or the nominal rate, when one clap stands alone) and any clap set aside."""
    v0, v1 = (float(x) for x in sync_qc.video_span_s)
    where = "the video"
    span = (v0, v1)
    if crop_s is not None:
        a, b = ((t - float(sync_qc.offset_at_video_zero_s)) / float(sync_qc.ratio) for t in crop_s)
        if max(a, v0) < min(b, v1):
            span, where = (max(a, v0), min(b, v1)), "the crop"
    bound, at, limiting = sync_qc.bound_over(span)
    used = [int(j) for j in sync_qc.claps_used]
    on = ", ".join(f"clap {j} (mocap {float(sync_qc.claps[j - 1].mocap_s):.2f} s)" for j in used
                   if 0 < j <= len(sync_qc.claps))
    alone = " and the nominal rate" if len(used) == 1 else ""
    msg = f"clock map within {bound:.1f} ms over {where} (video {span[0]:.1f}–{span[1]:.1f} s), from {on or 'no clap'}{alone}"
    left = [w for w in sync_qc.warnings if "clap" in w]
    sev = grade(bound, None, th.clock_bound_fail_ms)
    if sev == "fail":
        why = _clap_on(sync_qc, limiting) if limiting is not None else \
            "the nominal rate (the ratio is not measured: one clap)"
        msg = f"clock map may be {bound:.1f} ms off over {where} (at video {at:.1f} s), limited by {why}"
        msg += f"; {left[0]}" if left else ""
    return Check("clock_map", sev, msg, value=bound, threshold=_thr(None, th.clock_bound_fail_ms),
                 details={"warnings": left, "span_video_s": list(span), "limiting_clap": limiting,
                          "over": where.removeprefix("the ")})


SYNC_CHECKS = ("clap_offset", "clap_confidence", "clock_drift", "clap_residual", "clock_map", "frames_without_video")


def sync_checks(sync_qc: SyncQC | None, has_video: bool, frames: int | None, rate_hz: float | None,
                th: Thresholds, crop_s: tuple[float, float] | None = None) -> list[Check]:
    """clap_offset, clap_confidence, clock_drift, clap_residual, clock_map and frames_without_video from the sync
    QC; ``crop_s``: the first and last kept mocap frame's time, s (the clean stage's crop), over which clock_map
    is bounded."""
    if sync_qc is None:
        why = "the take has no video" if not has_video else "no sync record"
        return [skipped(i, why) for i in SYNC_CHECKS]
    out: list[Check] = []
    off = float(sync_qc.offset_s)
    out.append(Check("clap_offset", "pass", f"mocap minus video clock at the first clap: {off:+.3f} s",
                     value=off))
    confs = []
    for c in sync_qc.claps:
        for conf in (c.mocap_confidence, c.video_confidence):
            if conf is not None:
                confs.append(float(conf))
    unmatched = sum(1 for c in sync_qc.claps if c.video_s is None)
    if confs:
        v = min(confs)
        sev = grade(v, th.clap_confidence_warn, None, below=True)
        msg = f"lowest clap confidence {v:.2f} over {len(sync_qc.claps)} clap(s)"
        if unmatched:
            sev = worst([sev, "warning"])
            msg += f"; {unmatched} mocap clap(s) without a video clap"
        out.append(Check("clap_confidence", sev, msg, value=v, threshold=_thr(th.clap_confidence_warn),
                         details={"claps": [c.to_record() for c in sync_qc.claps]}))
    else:
        out.append(Check("clap_confidence", "error", "sync record lists no clap"))
    n_claps = int(sync_qc.n_claps)
    ppm = float(sync_qc.drift_ppm)
    if n_claps < 2:
        out.append(skipped("clock_drift", "one clap pair: the drift is not measurable (clock_map bounds what an "
                                          "unmeasured rate can do)"))
    else:
        msg = f"clock drift {ppm:+.0f} ppm (ratio {float(sync_qc.ratio):.6f}, " \
            f"{float(sync_qc.drift_ms_over_take):+.1f} ms over the video), corrected"
        out.append(Check("clock_drift", grade(abs(ppm), th.drift_warn_ppm, None), msg, value=ppm,
                         threshold=_thr(th.drift_warn_ppm)))
    if n_claps >= 3 and rate_hz:
        res_frames = float(sync_qc.residual_ms) / 1000.0 * rate_hz
        out.append(Check("clap_residual", grade(res_frames, th.clap_residual_warn_frames, None),
                         f"largest clap-pair misfit {float(sync_qc.residual_ms):.1f} ms "
                         f"({res_frames:.2f} mocap frames)", value=res_frames,
                         threshold=_thr(th.clap_residual_warn_frames)))
    else:
        out.append(skipped("clap_residual", f"{n_claps} clap pair(s): the map fits them exactly"))
    out.append(check_clock_map(sync_qc, th, crop_s))
    if frames:
        n = int(sync_qc.frames_without_video)
        v = n / frames
        out.append(Check("frames_without_video", grade(v, th.no_video_warn, th.no_video_fail),
                         f"{n} of {frames} mocap frames ({_pct(v)}) outside the video", value=v,
                         threshold=_thr(th.no_video_warn, th.no_video_fail)))
    else:
        out.append(skipped("frames_without_video", "no mocap frame count (ingest record)"))
    return out


# --------------------------------------------------------------------------------------------------- eyes

EYES_CHECKS = ("eye_gated", "eye_longest_invalid", "camera_residual")


def eyes_checks(eyes_qc: EyesQC | None, has_eyes: bool, th: Thresholds) -> list[Check]:
    """eye_gated, eye_longest_invalid and camera_residual from the eyes QC."""
    if eyes_qc is None:
        why = "the take has no eye tracking" if not has_eyes else "no eyes record"
        return [skipped(i, why) for i in EYES_CHECKS]
    out: list[Check] = []
    v = float(eyes_qc.gated_share)
    by = dict(eyes_qc.gated_by)
    top = ", ".join(f"{k} {_pct(float(x))}" for k, x in sorted(by.items(), key=lambda kv: -kv[1]) if x)
    out.append(Check("eye_gated", grade(v, th.eye_gated_warn, th.eye_gated_fail),
                     f"{_pct(v)} of eye samples gated out" + (f" ({top})" if top else ""), value=v,
                     threshold=_thr(th.eye_gated_warn, th.eye_gated_fail), details={"gated_by": by}))
    v = float(eyes_qc.longest_invalid_run_s)
    out.append(Check("eye_longest_invalid", grade(v, th.eye_longest_invalid_warn_s, None),
                     f"longest invalid eye run {v:.2f} s", value=v,
                     threshold=_thr(th.eye_longest_invalid_warn_s)))
    res = eyes_qc.camera_residual_deg
    if res is None:
        out.append(skipped("camera_residual", "no camera rotation residual (too few fixation frames)"))
    else:
        v = float(res)
        src = eyes_qc.camera_rotation_source
        out.append(Check("camera_residual", grade(v, th.camera_residual_warn_deg, th.camera_residual_fail_deg),
                         f"camera rotation ({src}) residual {v:.2f} deg over "
                         f"{eyes_qc.camera_frames_used} fixation frames", value=v,
                         threshold=_thr(th.camera_residual_warn_deg, th.camera_residual_fail_deg)))
    return out


# --------------------------------------------------------------------------------------------------- face

FACE_CHECKS = ("face_unmatched", "face_dropped")


def face_checks(face_qc: FaceQC | None, th: Thresholds) -> list[Check]:
    """face_unmatched and face_dropped from the face QC (Live Link Face tracks aligned on timecode)."""
    if face_qc is None:
        return [skipped(i, "no face record") for i in FACE_CHECKS]
    out = []
    n = int(face_qc.rows_tracked)
    if n:
        v = int(face_qc.unmatched_tracked) / n
        out.append(Check("face_unmatched", grade(v, th.face_unmatched_warn, th.face_unmatched_fail),
                         f"{face_qc.unmatched_tracked} of {n} tracked frames ({_pct(v)}) without a clean "
                         f"frame; {face_qc.rows_out} rows kept", value=v,
                         threshold=_thr(th.face_unmatched_warn, th.face_unmatched_fail)))
    else:
        out.append(Check("face_unmatched", "fail", "the tracked face track has no frame", value=1.0))
    shares = {}
    for side, rows, dropped in (("tracked", face_qc.rows_tracked, face_qc.dropped_frames_tracked),
                                ("clean", face_qc.rows_clean, face_qc.dropped_frames_clean)):
        shares[side] = dropped / (rows + dropped) if rows + dropped else 0.0
    side = max(shares, key=lambda k: shares[k])
    v = shares[side]
    out.append(Check("face_dropped", grade(v, th.face_dropped_warn, None),
                     f"dropped capture frames: {_pct(shares['tracked'])} tracked, {_pct(shares['clean'])} clean",
                     value=v, threshold=_thr(th.face_dropped_warn), details=shares))
    return out
