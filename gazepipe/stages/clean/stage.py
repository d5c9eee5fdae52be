"""The ``clean`` stage's entry point (SPEC §3.2, Pejsa 5.2.2.1): :func:`clean_markers` runs its steps in order.

Spikes become gaps (:mod:`.spikes`), gaps are filled (:mod:`.gapfill`), the root is stabilised
(:mod:`.stabilise`), the optional low-pass runs (:mod:`.filters`), then rests are found and the take is
cropped (:mod:`.rests`). Pure functions on :class:`~gazepipe.model.Markers`; no file I/O. Positions stay on lab
axes (the character frame is the ``frames`` stage's business); after stabilisation the root marker sits at the
lab origin.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from gazepipe.errors import StageError
from gazepipe.model import FILL_CODES, Markers, MarkerSet
from gazepipe.stages.clean.filters import lowpass_runs, true_runs, zero_phase_sos
from gazepipe.stages.clean.gapfill import (
    METHODS,
    ErrorLimits,
    GapRecord,
    error_map,
    fill_gaps,
    unlabeled_markers,
)
from gazepipe.stages.clean.qc import CleanQC
from gazepipe.stages.clean.rests import (
    crop_bounds,
    hidden_at,
    refine_rests,
    rest_periods,
    rest_speed,
)
from gazepipe.stages.clean.spikes import G_MM_S2, find_spikes
from gazepipe.stages.clean.stabilise import stabilise
from gazepipe.stages.clean.swaps import SubjectReferences, judged_columns, repair_swaps
from gazepipe.stages.geometry import up_vector

UNFILLED = FILL_CODES["unfilled"]
#: a crop bound against at most this many hidden frames is not said to be off: it is found within a frame or two
#: anyway (the clean takes of the benchmarks had a few such frames at a bound, where a fill moved faster than the
#: markers seen)
HIDDEN_WITHIN = 2
#: samples that do not show where the subject is in their own frame: fills through time from the marker's own
#: track, PCA fills (a model of the whole body, extrapolated from the few markers an occlusion leaves: a 2 mm
#: drift of its fills read as a 7 mm/s motion 23 frames before the real one), and no fill; a rigid fill from its
#: own cluster's markers measured there shows it
_NOT_SEEN = (FILL_CODES["linear"], FILL_CODES["pchip"], FILL_CODES["pca"], UNFILLED)
#: without the subject's references, a take's own frames judge its swaps only when it is at least this long (s):
#: a swap (0.3-3 s) is then a small minority of its frames; in a short take one can be most of them, and the
#: right names would look swapped (bench/bench_swaps.py: on 4-s takes, hundreds of samples made wrong)
OWN_REFERENCES_MIN_S = 20.0


@dataclass(frozen=True)
class CleanParams:
    """Parameters of :func:`clean_markers` (every threshold of SPEC §3.2).

    Attributes
    ----------
    max_gap_s : longest gap (s) that gets filled; longer gaps stay unfilled.
    fill_still_gaps : a gap longer than ``max_gap_s`` is still filled when its marker is still (a rest is not
        motion): measured still (below ``rest_speed_mm_s``) on both sides, and the markers moving with it stay
        so through the gap, which gives the fill's error estimate
        (:func:`gazepipe.stages.clean.gapfill.still_gap`).
    max_fill_error_mm : a gap is filled only when its fill's estimated error (its mean error on measured samples
        of the gap's own length hidden beside it, :func:`gazepipe.stages.clean.gapfill.fill_error`, with the
        checks on the gap's own frames) is at most this; a gap whose fill's error cannot be estimated (nothing
        beside it to hide) stays unfilled, counted apart in QC (``unfilled_gaps``).
    max_target_fill_error_deg : the target marker is used only as a direction from the head, so its fills are
        held to an angle instead: a target gap is filled when its estimated error is at most the larger of
        ``max_fill_error_mm`` and the head-to-target distance beside the gap times tan(this angle) (2° at 2 m:
        70 mm). The head is the head centre marker, else the mean of the last segment's markers.
    remove_spikes : run spike removal before gap filling (:func:`gazepipe.stages.clean.spikes.find_spikes`).
    spike_residual_mm, spike_step_factor, spike_cluster_mm : thresholds of the glitch test
        (:func:`gazepipe.stages.clean.spikes.find_glitches`): a sample farther than
        max(residual_mm, step_factor × the marker's typical step there) from the running median of the five
        frames around it, or whose distances to every measured mate of its segment are off by more than
        max(cluster_mm, 6 × their typical deviation) while it is also ``cluster_mm`` off its running median.
        Defaults: 8 mm (16 times the running median residual of 0.5 mm marker noise, about half the smallest
        ghost worth catching, 15 mm), 2 (a sharp turn of a fast marker leaves the median by about one step),
        5 mm.
    spike_max_accel_mm_s2, spike_min_step_mm, spike_max_piece_s : thresholds of
        :func:`gazepipe.stages.clean.spikes.remove_spikes` (a second difference above
        max(accel / rate², min_step) is implausible; pieces cut off by such breaks shorter than max_piece_s
        become gaps). Defaults: 50 g, 100 mm, 0.5 s.
    fill_methods : candidate gap-filling methods, best chosen per gap (:func:`gazepipe.stages.clean.gapfill.fill_gaps`).
    lowpass_hz : cutoff (Hz, −3 dB of the whole zero-phase filter) of the optional low-pass; ``None`` = off.
    lowpass_order : Butterworth order of *one* pass (2: the forward–backward pair is a 4th-order zero-phase
        filter with a monotone magnitude response and little overshoot, Winter's usual choice for marker data).
    rest_speed_mm_s : a frame is "still" when the subject's mean marker speed is below this (Pejsa: 6 mm/s).
    rest_merge_s : rests separated by less than this merge (Pejsa: 1/6 s).
    rest_min_s : rests shorter than this do not count.
    rest_filter_hz : −3 dB frequency (Hz) of the Gaussian low-pass applied only to the positions used for
        speeds (σ = √(ln 2) / (2π f)). Marker noise of 0.5 mm gives a mean speed of ~20 mm/s at 30 Hz on
        raw positions and still ~10 mm/s after a 6 Hz low-pass: above the 6 mm/s threshold, so no rest would
        ever be found. At 1.75 Hz the noise floor's 99.9th percentile is ~4 mm/s at 30 Hz (~2 mm/s at 120 Hz).
        A Gaussian rather than a Butterworth because the threshold is ~1 % of a gaze shift's peak speed:
        Butterworth ringing ahead of a fast movement crosses it and moves rest bounds by up to 0.5 s; the
        Gaussian's smear moves them by ~2 frames at 30 Hz (≤ 0.1 s at any rate) against the noise-free
        speed's crossing (early at the end of a rest: the smear spreads the motion's onset back; hence
        ``rest_refine``). Measured by tests/stages/clean/test_clean.py.
    rest_refine : move the end of every rest of at least 0.7 s to where the noise-free speed reaches the
        threshold, from a fit of the smoothed speed's rise (:func:`refine_onset`). Without it the end of the
        first rest of the sample session's gaze shifts comes 1–2 frames early (median −2); with it the
        median error is 0 and every end is within 1 frame. The rests themselves (which frames are still, the
        noise floor) do not change.
    remove_heading : also rotate every frame about the lab vertical so the root segment's left direction
        (its first marker minus its second, horizontal part) points along lab +X.
    repair_swaps : find label swaps (two markers carrying each other's names) and put the samples back under
        their own names where the exchange is proven frame by frame, before spike removal
        (:func:`gazepipe.stages.clean.swaps.repair_swaps`; samples coded ``swap_repaired``).
    swap_tolerance : a sample is suspect when one of its marker's steadiest distances to other markers is off
        its usual value by more than this many of that distance's spreads (each spread at least 1 mm): 6
        (about 6 mm for a rigid mate) is far outside marker noise and well inside the 50-200 mm that two
        exchanged markers stand apart.
    fill_unlabeled : also fill the gaps of unlabeled trajectories (Vicon ``*12``, ``Unlabeled 3``, ...:
        :func:`gazepipe.stages.clean.gapfill.unlabeled_markers`); off: their gaps stay, counted in QC.

    Each field's metadata gives its allowed values (:func:`gazepipe.pipeline.registry.value_problem`) and its one
    line of help (``help``: what ``gazepipe params`` prints).
    """

    max_gap_s: float = field(default=3.0, metadata={
        "min": 0, "help": "longest gap, in s, that gets filled; longer gaps stay gaps"})
    max_fill_error_mm: float = field(default=5.0, metadata={
        "gt": 0, "help": "fill a gap only when its fill's estimated error is at most this, in mm"})
    max_target_fill_error_deg: float = field(default=2.0, metadata={
        "min": 0, "max": 45, "help": "the same for the gaze target marker, as an angle seen from the head, "
            "in degrees"})
    remove_spikes: bool = field(default=True, metadata={
        "help": "turn spikes (ghost samples, impossible jumps) into gaps before filling"})
    spike_residual_mm: float = field(default=8.0, metadata={
        "gt": 0, "help": "a sample this far (mm) from the median of its neighbours in time is a spike"})
    spike_step_factor: float = field(default=2.0, metadata={
        "min": 0, "help": "a sample farther from that median than this many times the marker's usual step "
            "is a spike"})
    spike_cluster_mm: float = field(default=5.0, metadata={
        "gt": 0, "help": "a sample whose distances to its segment's other markers are off by this (mm) is a "
            "spike"})
    spike_max_accel_mm_s2: float = field(default=50.0 * G_MM_S2, metadata={
        "gt": 0, "help": "acceleration above this (mm/s², 50 g) is impossible: a spike"})
    spike_min_step_mm: float = field(default=100.0, metadata={
        "min": 0, "help": "a jump between frames smaller than this (mm) is never a spike, whatever its "
            "acceleration"})
    spike_max_piece_s: float = field(default=0.5, metadata={
        "min": 0, "help": "stretches shorter than this (s) cut off between spikes become gaps too"})
    fill_methods: tuple[str, ...] = field(default=METHODS, metadata={
        "choices": METHODS, "help": "the gap-filling methods tried; the best one is chosen for each gap"})
    lowpass_hz: float | None = field(default=None, metadata={
        "gt": 0, "help": "cutoff, in Hz, of a zero-phase low-pass on the cleaned markers (off by default)"})
    lowpass_order: int = field(default=2, metadata={
        "min": 1, "help": "order of that low-pass (2: a 4th-order filter forward and backward)"})
    rest_speed_mm_s: float = field(default=6.0, metadata={
        "gt": 0, "help": "the subject rests while the mean marker speed is below this, in mm/s"})
    rest_merge_s: float = field(default=1.0 / 6.0, metadata={
        "min": 0, "help": "rests less than this apart (s) merge into one"})
    rest_min_s: float = field(default=0.25, metadata={
        "min": 0, "help": "rests shorter than this (s) do not count"})
    rest_filter_hz: float = field(default=1.75, metadata={
        "gt": 0, "help": "low-pass, in Hz, of the positions the rest speed is measured on"})
    rest_refine: bool = field(default=True, metadata={
        "help": "move the end of each long rest to where the movement really starts"})
    remove_heading: bool = field(default=False, metadata={
        "help": "turn every frame so the subject faces the same way (lab +X to their left)"})
    repair_swaps: bool = field(default=True, metadata={
        "help": "find markers that swapped labels and put their samples back under their own names"})
    swap_tolerance: float = field(default=6.0, metadata={
        "gt": 0, "help": "how far off (in spreads of a marker-to-marker distance) a sample is suspect of a "
            "swap"})
    fill_unlabeled: bool = field(default=False, metadata={
        "help": "also fill unlabeled trajectories (*12, Unlabeled 3, ...); off: their gaps stay"})
    fill_still_gaps: bool = field(default=True, metadata={
        "help": "fill a longer gap too where its marker is still on both sides and its body through it"})


@dataclass
class CleanResult:
    """Output of :func:`clean_markers`.

    Attributes
    ----------
    markers : cleaned, stabilised, cropped markers (mm, lab axes, root at the origin); ``first_frame`` is the
        source frame number of the first kept row.
    frames : (N,) int64 row indices of the kept rows in the uncropped take (``crop[0] .. crop[1]-1``).
    fill_code : (N, M) int8 :data:`~gazepipe.model.FILL_CODES` of every kept sample.
    spike : (N, M) bool, the measured samples removed as spikes (each then filled, or left unfilled, as a gap).
    fill_error_mm : (N, M) float64, each filled sample's estimated error (mm); NaN where measured, unfilled or
        filled without an estimate.
    crop : (start, stop) half-open, in rows of the uncropped take.
    rests : rest periods (start, stop) half-open, in rows of the uncropped take.
    speed_mm_s : (T,) mean subject-marker speed of the uncropped take (NaN where unknown).
    neutral : the cleaned (uncropped) frames of the first rest period, for neutral calibration
        (``None`` when no rest was found; for a take of kind ``neutral`` without a rest, the whole take, with a
        QC warning). Give the ``neutral`` take's (else the take's own) to :func:`~gazepipe.stages.frames.stage.compute_frames`.
    qc : JSON-ready record (see :func:`clean_markers`).
    """

    markers: Markers
    frames: np.ndarray
    fill_code: np.ndarray
    spike: np.ndarray
    fill_error_mm: np.ndarray
    crop: tuple[int, int]
    rests: list[tuple[int, int]]
    speed_mm_s: np.ndarray
    neutral: Markers | None
    qc: dict
    #: (R, M) int8 :data:`~gazepipe.model.FILL_CODES` of the ``neutral`` frames (None with no neutral): which of
    #: the rest's samples were measured
    neutral_fill_code: np.ndarray | None = None


def _marker_qc(fill_code: np.ndarray, valid_in: np.ndarray, labels: list[str], rate_hz: float,
               spikes: np.ndarray) -> dict:
    """Per-marker QC from the gaps (after spike removal) and the fill codes."""
    out: dict = {}
    for m, lab in enumerate(labels):
        gaps = true_runs(~valid_in[:, m])
        longest = max((b - a for a, b in gaps), default=0)
        counts = {name: int(np.sum(fill_code[:, m] == code)) for name, code in FILL_CODES.items()}
        out[lab] = {
            "gaps": len(gaps),
            "longest_gap_frames": int(longest),
            "longest_gap_s": longest / rate_hz,
            "spikes_removed": int(spikes[m]),
            "samples": {k: v for k, v in counts.items() if k != "unfilled"},
            "unfilled": counts["unfilled"],
        }
    return out


def _fill(markers: Markers, markerset: MarkerSet, params: CleanParams, qc: dict,
          references: SubjectReferences | None, in_place: bool = False
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[GapRecord]]:
    """Label swaps repaired, spikes → gaps, then gap filling. Returns (xyz, fill_code, spike mask, the filler's
    gap records); ``in_place``: ``xyz`` is ``markers.xyz`` itself (and the mask ``markers.valid``), else a
    copy."""
    # the stage's one working array of positions and mask (the caller's own when in place): every step below
    # writes into them
    if in_place:
        valid, xyz = markers.valid, markers.xyz
        valid &= np.isfinite(xyz).all(axis=2)
        xyz[~valid] = np.nan
    else:
        valid = markers.valid & np.isfinite(markers.xyz).all(axis=2)
        xyz = np.where(valid[..., None], markers.xyz, np.nan)
    pos = {lab: i for i, lab in enumerate(markers.labels)}
    clusters = [[pos[n] for n in s.markers if n in pos] for s in markerset.segments]
    swapped = _repair_swaps(xyz, valid, markers.labels, markers.rate_hz, markerset, params, qc, references)
    spike = np.zeros(valid.shape, dtype=bool)
    if params.remove_spikes:
        spike = find_spikes(xyz, valid, markers.rate_hz, clusters, residual_mm=params.spike_residual_mm,
                            step_factor=params.spike_step_factor, cluster_mm=params.spike_cluster_mm,
                            max_accel_mm_s2=params.spike_max_accel_mm_s2, min_step_mm=params.spike_min_step_mm,
                            max_piece_s=params.spike_max_piece_s)
        valid &= ~spike
        xyz[spike] = np.nan
    spikes = spike.sum(axis=0)
    qc["spikes_removed"] = int(spikes.sum())
    qc["gaps"] = []
    records: list[GapRecord] = []
    if valid.all():  # nothing to fill
        code = np.zeros(valid.shape, dtype=np.int8)
    else:
        res = fill_gaps(xyz, valid, markers.rate_hz, clusters=[c for c in clusters if len(c) >= 2],
                        max_gap_s=params.max_gap_s, methods=tuple(params.fill_methods),
                        max_error_mm=_error_limits(xyz, markers.labels, markerset, params), in_place=True,
                        groups=_moving_groups(pos, markerset),
                        still_speed_mm_s=params.rest_speed_mm_s if params.fill_still_gaps else None,
                        leave=() if params.fill_unlabeled else unlabeled_markers(markers.labels))
        records = res.gaps
        code = np.asarray(res.fill_code, dtype=np.int8)
        xyz = res.xyz                     # NaN wherever unfilled (fill_gaps writes only the samples it fills)
        qc["gaps"] = [_gap_qc(g, markers.labels) for g in res.gaps]
    qc["unfilled_gaps"] = unfilled_counts(records)
    code[swapped & (code == FILL_CODES["measured"])] = FILL_CODES["swap_repaired"]
    qc["markers"] = _marker_qc(code, valid, markers.labels, markers.rate_hz, spikes)
    return xyz, code, spike, records


def _gap_qc(g: GapRecord, labels: list[str]) -> dict:
    """One gap's QC entry. Its ``error_mm`` is the estimate as the markers table stores it (float32): QC, the
    table's ``fill_error_mm`` and the replay quote one figure."""
    return {"marker": labels[g.marker], "start": int(g.start), "stop": int(g.stop), "method": g.method,
            "error_mm": float(np.float32(g.error_mm)) if np.isfinite(g.error_mm) else None, "reason": g.reason,
            "errors_mm": {k: (None if not np.isfinite(v) else float(v)) for k, v in g.errors.items()},
            "weights": {k: float(v) for k, v in g.weights.items()}}


def unfilled_counts(records: list[GapRecord]) -> dict[str, dict[str, int]]:
    """The gaps left unfilled, by reason (a ``REASON_*`` of :mod:`.gapfill`): ``{reason: {"gaps", "samples"}}``,
    reasons in alphabetical order."""
    out: dict[str, dict[str, int]] = {}
    for g in records:
        if g.method == "unfilled":
            n = out.setdefault(g.reason, {"gaps": 0, "samples": 0})
            n["gaps"] += 1
            n["samples"] += g.length
    return dict(sorted(out.items()))


def _moving_groups(pos: dict[str, int], markerset: MarkerSet) -> list[list[int]]:
    """Marker indices (``pos``: label -> column) that move independently of one another: the subject, the
    clapper, the gaze target. A marker the markerset does not name is a group of its own. A subject marker
    filled from a clapper held before the face follows the clap (a head filled 37 mm off across a 1 s
    occlusion in a rest, its estimate 2 mm, from stretches where the clapper was still)."""
    named = [markerset.subject_markers, markerset.clapper, (markerset.target,) if markerset.target else ()]
    return [[pos[n] for n in names if n in pos] for names in named]


def _repair_swaps(xyz: np.ndarray, valid: np.ndarray, labels: list[str], rate_hz: float, markerset: MarkerSet,
                  params: CleanParams, qc: dict, references: SubjectReferences | None) -> np.ndarray:
    """Label swaps repaired in place in ``xyz`` and ``valid`` (:mod:`.swaps`; the subject's references when
    given, else the take's own); ``qc["swaps"]`` lists the stretches. Returns the (T, M) mask of repaired
    samples."""
    qc["swaps"], qc["swap_pairs"] = [], {}
    if not params.repair_swaps:
        return np.zeros(valid.shape, dtype=bool)
    if references is None and valid.shape[0] < OWN_REFERENCES_MIN_S * rate_hz:
        qc["swaps_not_checked"] = (f"a take shorter than {OWN_REFERENCES_MIN_S:g} s cannot tell swaps from the "
                                   "right names by itself (the pipeline judges every take against all of the "
                                   "session's)")
        return np.zeros(valid.shape, dtype=bool)
    # every marker the table carries is judged, listed in the markerset or not: the target and the clapper only
    # are no part of the body
    res = repair_swaps(xyz, valid, params.swap_tolerance,
                       references=None if references is None else references.for_labels(labels),
                       markers=judged_columns(labels, markerset.target, markerset.clapper), in_place=True)
    qc["swaps"] = [{"markers": [labels[r.first], labels[r.second]], "start": r.start, "stop": r.stop,
                    "repaired": r.repaired} for r in res.records]
    pairs: dict[str, dict[str, int]] = {}
    for r in res.records:
        count = pairs.setdefault(f"{labels[r.first]}/{labels[r.second]}", dict.fromkeys(
            ("repaired", "removed", "repaired_samples", "removed_samples"), 0))
        outcome = "repaired" if r.repaired else "removed"
        count[outcome] += 1
        mask = res.repaired if r.repaired else res.removed
        count[f"{outcome}_samples"] += int(mask[r.start:r.stop, [r.first, r.second]].sum())
    qc["swap_pairs"] = pairs
    if any(not r.repaired for r in res.records):
        lost = int(res.removed.sum())
        qc["warnings"].append(f"{lost} sample(s) of swapped markers could not be put back under their names "
                              "and became gaps")
    return res.repaired


def _error_limits(xyz: np.ndarray, labels: list[str], markerset: MarkerSet,
                  params: CleanParams) -> float | ErrorLimits:
    """The fill error limit (mm): ``max_fill_error_mm``, or when the target marker is captured an
    :class:`~gazepipe.stages.clean.gapfill.ErrorLimits` whose target column allows the error that
    ``max_target_fill_error_deg`` subtends at the head-to-target distance of each frame."""
    if markerset.target not in labels or not params.max_target_fill_error_deg:
        return params.max_fill_error_mm
    head = [markerset.head_centre] if markerset.head_centre in labels else list(markerset.segments[-1].markers)
    cols = [labels.index(n) for n in head if n in labels]
    if not cols:
        return params.max_fill_error_mm
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)        # frames without any head marker: NaN
        centre = np.nanmean(xyz[:, cols], axis=1)
    t = labels.index(markerset.target)
    dist = np.linalg.norm(xyz[:, t] - centre, axis=1)
    angular = dist * np.tan(np.radians(params.max_target_fill_error_deg))
    # fmax: NaN distance gives the mm limit
    return ErrorLimits(params.max_fill_error_mm, {t: np.fmax(params.max_fill_error_mm, angular)})


#: peak memory of the clean unit, bytes: a fixed part (the stage's modules and compiled kernels, a row group read
#: or written, the spike tests' blocks of frames) and a part per marker sample: the take's positions and masks,
#: held once (the raw table is read a row group at a time into the arrays the stage cleans in place, and the
#: cleaned table written a row group at a time as it is made), the fill codes and errors, and the take-long
#: temporaries of the swap repair and the rest speed (about 20 bytes each). Measured with
#: ``bench/bench_clean_length.py --unit`` on generated takes of 1 and 2 hours at 120 Hz with 60 markers (25.9 and
#: 51.8 million samples): 1.67 and 3.06 GB added to the process at their peaks (1.84 and 3.23 GB peak resident),
#: 53.5 bytes per sample and 287 MB besides; with a margin
CLEAN_BYTES_FIXED = 300 * 2**20
CLEAN_BYTES_PER_SAMPLE = 60


def clean_memory_bytes(n_samples: int) -> int:
    """About how much memory cleaning a take of ``n_samples`` marker samples (frames x markers) takes at its
    peak, bytes (:data:`CLEAN_BYTES_FIXED` and :data:`CLEAN_BYTES_PER_SAMPLE`)."""
    return CLEAN_BYTES_FIXED + int(n_samples) * CLEAN_BYTES_PER_SAMPLE


def _rigid_groups(markerset: MarkerSet, labels: list[str]) -> list[list[int]]:
    """Columns of the markers that move rigidly together: each segment's, the root marker with the root segment's
    and the head-centre marker with the head's (the segment named ``head``, else the last)."""
    pos = {n: i for i, n in enumerate(labels)}
    extra = {markerset.root_segment.name: markerset.root}
    if markerset.head_centre:
        names = [s.name for s in markerset.segments]
        extra["head" if "head" in names else names[-1]] = markerset.head_centre
    return [[pos[n] for n in (*s.markers, extra.get(s.name, "")) if n in pos] for s in markerset.segments]


def clean_markers(markers: Markers, markerset: MarkerSet, kind: str, params: CleanParams | None = None,
                  *, path: str | None = None, take: str | None = None,
                  references: SubjectReferences | None = None, in_place: bool = False) -> CleanResult:
    """Clean one take's markers (SPEC §3.2).

    ``in_place``: ``markers.xyz`` and ``markers.valid`` are the caller's to give up: the stage cleans them in
    place instead of a copy of the take (a long take's positions are held once), and the result's markers are
    rows of them; the caller must not read them afterwards.

    ``references``: the subject's marker geometry from all of the session's takes
    (:func:`gazepipe.stages.clean.swaps.pooled_references`), against which label swaps are judged; without
    them, the take's own, for a take of at least :data:`OWN_REFERENCES_MIN_S` (a shorter one is not looked at
    for swaps: a swap can be most of it).

    Steps: label-swap repair → spike removal → gap filling (clusters = the markerset's segments) → root stabilisation (lab axes,
    optional heading removal; frames without the root marker become unfilled) → optional zero-phase
    low-pass per run of valid samples → rest detection on the subject's markers → cropping by ``kind``.

    Raises :class:`~gazepipe.errors.StageError` (one line, naming ``path``/``take``) when the root marker is
    missing or the rest periods the kind needs are not found.

    ``qc`` holds: ``swaps`` (every swapped stretch: the two markers, start, stop, repaired or made gaps),
    ``swap_pairs`` (per pair ``"A/B"``: stretches repaired and removed, and their samples apart),
    ``swaps_not_checked`` (why, when swaps
    were not looked for),
    ``markers`` (per marker: gaps after spike removal, longest gap in frames and seconds, spikes
    removed, samples per fill method, unfilled samples), ``spikes_removed`` (total), ``gaps`` (every gap:
    marker, start, stop, method, its fill's estimated error as the markers table stores it, each method's
    validation error in mm), ``unfilled_gaps`` (gaps and samples left unfilled, per reason),
    ``root_missing_frames``, ``lowpass`` (cutoff,
    runs left unfiltered), ``rests`` (list of [start, stop]), ``crop`` ([start, stop]), ``kept_frames``,
    ``warnings`` and ``failures`` (lists of one-line strings; ``failures`` stays empty here because a failure
    raises instead).
    """
    params = params or CleanParams()
    qc: dict = {"warnings": [], "failures": []}
    labels = list(markers.labels)
    if markerset.root not in labels:
        raise StageError(path, f"root marker {markerset.root!r} is not in the capture", take=take)
    root = labels.index(markerset.root)
    rate = float(markers.rate_hz)

    xyz, code, spike, gap_records = _fill(markers, markerset, params, qc, references, in_place)
    # rests are the subject standing still in the room: speeds on lab positions, before stabilisation
    subj = [labels.index(n) for n in markerset.subject_markers if n in labels]
    clusters = _rigid_groups(markerset, labels)
    speed, hidden = rest_speed(xyz, code != UNFILLED, rate, params.rest_filter_hz, params.rest_speed_mm_s, subj,
                               clusters, seen=~np.isin(code, _NOT_SEEN))

    # 3. stabilisation
    up = left_pair = None
    if params.remove_heading:
        rs = markerset.root_segment
        if len(rs.markers) < 2 or any(n not in labels for n in rs.markers[:2]):
            raise StageError(path, f"heading removal needs the root segment {rs.name!r}'s first two markers",
                             take=take)
        up = up_vector(markerset.up_axis)
        left_pair = (labels.index(rs.markers[0]), labels.index(rs.markers[1]))
    xyz = stabilise(xyz, root, up, left_pair, in_place=True)
    lost = ~np.isfinite(xyz).all(axis=2) & (code != UNFILLED)
    code = np.where(lost, UNFILLED, code).astype(np.int8)
    valid = code != UNFILLED
    xyz[~valid] = np.nan
    qc["root_missing_frames"] = int(np.sum(~valid[:, root]))

    # 4. optional low-pass
    if params.lowpass_hz is not None:
        if not params.lowpass_hz < rate / 2.0:
            raise StageError(path, f"clean.lowpass_hz {params.lowpass_hz:g} Hz is not below half this take's rate "
                                   f"({rate:g} Hz): lower it", take=take)
        sos = zero_phase_sos(params.lowpass_hz, rate, params.lowpass_order)
        xyz, short = lowpass_runs(xyz, valid, sos)
        qc["lowpass"] = {"cutoff_hz": float(params.lowpass_hz), "order_per_pass": params.lowpass_order,
                         "runs_unfiltered": int(short)}
        if short:
            qc["warnings"].append(f"{short} run(s) of valid samples too short to low-pass, left unfiltered")

    # 5. rests and crop
    rests = rest_periods(speed, rate, params.rest_speed_mm_s, params.rest_merge_s, params.rest_min_s)
    if params.rest_refine and params.rest_filter_hz is not None:
        rests = refine_rests(rests, speed, rate, params.rest_filter_hz, params.rest_speed_mm_s)
    qc["rests"] = [[a, b] for a, b in rests]
    try:
        (start, stop), warns = crop_bounds(rests, speed, kind, int(params.rest_merge_s * rate))
    except ValueError as e:
        raise StageError(path, f"clean: {e}", take=take) from None
    qc["warnings"].extend(warns)
    qc["crop"] = [int(start), int(stop)]
    qc["kept_frames"] = int(stop - start)
    crop_hidden = [hidden_at(hidden, start) if start > 0 else 0, hidden_at(hidden, stop) if stop < len(speed) else 0]
    crop_hidden = [h if h > HIDDEN_WITHIN else 0 for h in crop_hidden]
    if any(crop_hidden):
        qc["crop_hidden"] = crop_hidden
    for bound, frames in zip(("start", "end"), crop_hidden, strict=True):
        if frames:
            qc["warnings"].append(f"the crop's {bound} lies against {frames} frame(s) where too few of the subject's "
                                  "markers are seen to tell rest from motion: it may be off by up to that many")

    def _slice(a: int, b: int, copy: bool = True) -> Markers:
        rows = slice(a, b)
        return replace(markers, xyz=xyz[rows].copy() if copy else xyz[rows], valid=valid[rows].copy(),
                       first_frame=int(markers.first_frame) + a, warnings=list(markers.warnings))

    neutral = _slice(*rests[0]) if rests else None
    neutral_code = code[slice(*rests[0])].copy() if rests else None
    if kind == "neutral" and neutral is None and markers.n_frames:
        neutral, neutral_code = _slice(0, markers.n_frames), code.copy()
        qc["warnings"].append("no rest period in the neutral take; its every frame is the neutral pose")
    # the record the report reads, checked against its type here: a key renamed or left out fails the stage's
    # own tests, not a report check later
    qc = CleanQC.from_record(qc).to_record()
    fill_error = error_map(gap_records, code.shape)     # made last: no other take-sized temporary is alive
    fill_error[code == UNFILLED] = np.nan
    # the kept rows are views of the stage's own arrays: a long take's positions are not copied once more
    return CleanResult(markers=_slice(start, stop, copy=False), frames=np.arange(start, stop, dtype=np.int64),
                       fill_code=code[start:stop], spike=spike[start:stop], fill_error_mm=fill_error[start:stop],
                       crop=(int(start), int(stop)), rests=rests, speed_mm_s=speed, neutral=neutral, qc=qc,
                       neutral_fill_code=neutral_code)
