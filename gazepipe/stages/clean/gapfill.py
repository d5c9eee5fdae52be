"""Gap filling (SPEC §3.2 step 2): every gap filled with a per-gap choice of method, and the
rigid-cluster finder used when no markerset is given.

Pure functions on arrays: positions are (T, M, 3) float64 millimetres in the lab frame, NaN where not measured;
``valid`` is (T, M) bool; frames are rows, half-open ranges ``[start, stop)``.

Gap filling (Pejsa 5.2.2.1, improved). For every gap of every marker each applicable method predicts the gap:

* ``rigid``: least-squares rigid fit of the marker's cluster (segment) mates measured in each frame to the nearest
  complete frames before and after the gap, blended across it; a marker without a cluster (or whose mates are
  hidden with it) uses the markers measured through the gap whose distance to it is steadiest around it;
* ``pca``: reconstruction from all markers' intercorrelation (Gløersen & Federolf 2016, PLoS ONE 11:e0152616),
  in the lab frame and in the moving frames of nearby markers (the body part's rotation removed); the best few
  (model, component count) pairs on the hidden stretches below are averaged (:func:`_pca_predictions`);
* ``pchip`` and ``linear`` interpolation in time.

Rigid and PCA predictions are corrected to meet the measured samples at both gap edges. To choose, measured
samples of the same marker next to the gap (two stretches as long as the gap on each side, when there is room;
more for gaps under eight frames, so that at least 16 samples per side are hidden) are hidden and every
method predicts them (its validation error: the mean error there). The hidden stretches are given the gap's
own occlusion pattern (markers missing during the gap are treated as missing there too), so rigid and PCA are
judged with the donors they will really have; methods are compared on the frames all of them can predict. The
same stretches pick the PCA models and component counts. Interpolation is also judged on the gap's own frames: the
nearest markers measured through the gap that move with the marker (steady distance) are interpolated over it,
and when their error is larger it is the interpolation methods' validation error (motion during the gap that the
stretches beside it do not show); PCA's error is then scaled by how much worse its components explain the
predictors in the gap than in the stretches (:func:`~gazepipe.stages.clean.fill_methods.pca_novelty`), when clearly
worse. The gap is filled with a convex blend of the best methods, weighted by inverse squared validation error
(:func:`blend_weights`), and coded by the method with the largest weight. Gaps of 16 frames or more are also
filled by averaging the candidates frame by frame (:mod:`.framewise`: each frame weights them by how well they
keep the marker's distances to its most rigidly linked neighbours there); that average replaces the blend when
it predicts the hidden stretches better. When no sample can be hidden the first applicable method in
``methods`` is used.

A fill is kept when its estimated error is within the limit (``max_error_mm``): the larger of its mean error on
the hidden stretches and, for the part of it that comes from interpolation, how far it strays from the curve
that meets the gap's edges with the marker's velocities there (:func:`edge_velocity_error`: a turn inside the
gap that the stretches beside it cannot show). A fill whose error cannot be estimated at all is not kept
(:data:`REASON_NO_ESTIMATE`): every fill written carries the estimate it was kept on, the one every report of
it quotes.

Gaps at the start or end of a take are never extrapolated in time: pchip and linear cannot fill them; rigid and
PCA fill them only from the other markers measured in those frames (and only up to ``max_gap_s``), with the
mismatch correction taken from the one measured edge. Gaps longer than ``max_gap_s`` stay unfilled, but where
the marker is still through them (``still_speed_mm_s``; :func:`still_gap`: a rest is not motion). Unlabeled
trajectories (:func:`unlabeled_markers`) are left alone when the caller says so (``leave``).

Each gap is decided from its neighbourhood only: the frames within ``_GapSettings.reach`` of it (the PCA
training window, the mates' window and the hidden stretches of the longest gap all fit), plus two statistics of
the whole take (:class:`TakeStatistics`: step limits and noise floors). So its cost does not grow with the take,
and a take cut anywhere farther than that from a gap fills the gap to the same bits. Nor does it grow with the
capture rate: the windows are in seconds, but a window statistic reads at most ``WINDOW_SAMPLES`` evenly spaced
frames and PCA trains on at most ``PCA_MAX_TRAIN`` (:mod:`.fill_methods`; every frame below ~480 and ~200 Hz),
the searches for a fill's anchors and reference frames go outward from the gap (:mod:`.kernels`, compiled), and
nothing copies the neighbourhood unless the rigid or PCA candidates are tried. A short gap (up to
``_CHEAP_MAX_S``) whose interpolation already validates at the marker's noise floor
(:func:`interpolation_noise_mm`) is filled without the rigid and PCA candidates: nothing can predict the hidden
samples measurably better than the noise they carry, and these are most of the gaps a spike leaves.

Every fill is checked for plausible speed before it is kept (:func:`step_limits`): no step from frame to frame,
into, across or out of the gap, may exceed both 2.5x the marker's own 99th-percentile measured step and 1.5x
the largest such percentile of any marker, nor ever the fastest step measured anywhere in the take (no fill
moves faster than the capture was seen to move). A fill that does (seen for PCA at the end of a take whose last
poses the training frames never held: a foot marker moving 120 mm per frame) is replaced by the next method
by validation error that passes, or the gap stays unfilled (``GapRecord.reason``).
"""

from __future__ import annotations

import re
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from gazepipe.blas import one_blas_thread
from gazepipe.model import FILL_CODES
from gazepipe.stages.clean import framewise
from gazepipe.stages.clean.fill_methods import (
    MATES_MAX_STD_MM,
    WINDOW_SAMPLES,
    PcaModel,
    distance_stats,
    donor_interp_errors,
    edge_speed,
    find_steady_mates,
    fit_pca_models,
    interp_fill,
    pca_fill_packed,
    pca_novelty,
    rigid_fill,
    rigid_fill_many,
    sample_step,
    speed_over,
)
from gazepipe.stages.clean.spikes import _nanmedian
from gazepipe.stages.geometry import kabsch, norm3

METHODS = ("rigid", "pca", "pchip", "linear")
#: measured frames kept between a hidden validation stretch and the gap, so interpolation has anchors
_SEPARATION = 2
#: hidden validation stretches on each side of an interior gap (two: gaps over 0.25 s of the ART file 3.02 ->
#: 2.87 mm, 1.31 -> 1.13 x the best method per gap in hindsight; Walking 7.23 -> 7.36 mm; see the commit)
_WINDOWS_PER_SIDE = 2
#: short gaps get more stretches (each as long as the gap), up to this many hidden samples per side: the mean
#: error over two stretches of one to five frames is too noisy to rank the methods by (ART file, gaps of 1-5
#: frames: 1.27 -> 1.17 x the best method per gap in hindsight; gaps of 6 frames or more are unchanged)
_MIN_HIDDEN_PER_SIDE = 16
#: interpolation methods (they use the marker's own samples only)
_INTERP = ("pchip", "linear")
#: the donors' interpolation error replaces the validation error when more than this many times larger (the
#: larger of two noisy estimates of the same error would be biased up)
_INTERP_DONOR_FACTOR = 1.5
#: PCA's validation error is multiplied by :func:`pca_novelty` when that is above this: the model has clearly
#: not seen the gap's poses (131 on a movement between two still phases; 0.6 to 2.1 between the gaps and their
#: stretches on the ART file, where nothing unseen happens)
_PCA_NOVELTY_MIN = 3.0
#: a gap whose marker moves at its edges (and across it) at less than this fraction of its speed in the hidden
#: stretches is taken as still: interpolation's validation error is scaled by the speed ratio (long gaps on the
#: Walking file: 0.03-0.10 for foot markers in stance, 0.29 and up for the others)
_STILL_EDGE_RATIO = 0.25
#: time each side of a gap (s) over which a marker without a cluster gets its steadiest mates, and over which
#: a donor of the interpolation check must keep its distance to the gap's marker
_MATES_WINDOW_S = 2.0
#: at most this many methods are blended per gap
_BLEND_TOP = 3
#: at most this many PCA (model, component count) candidates are averaged per gap
_PCA_BLEND_TOP = 5
#: PCA models fitted per gap: lab frame (None) and the moving frames of :class:`PcaModel` ``local_frame``
#: (the third model: gaps over 0.25 s 1.05 -> 0.87 mm on the ART file, 5.84 -> 5.44 mm on Walking)
_PCA_MODELS = (None, "steady", "near")
#: methods with a validation error more than this many times the best one's are left out of the blend
_BLEND_MAX_RATIO = 3.0
#: validation errors below this (mm) are treated as equal: below the noise of any capture
_ERR_FLOOR_MM = 0.01
#: a filled step above this many times the marker's 99th-percentile measured step, and above
#: ``_STEP_FACTOR_ANY`` times the largest such percentile of any marker (a marker seen only still may move as
#: fast as the others, a little faster at the end of a longer lever), is implausible
_STEP_FACTOR = 2.5
_STEP_FACTOR_ANY = 1.5
#: reasons a gap stays unfilled (``GapRecord.reason``)
REASON_TOO_LONG = "longer than max_gap_s"
REASON_NEVER_MEASURED = "marker never measured"
REASON_NO_METHOD = "no method applies"
REASON_IMPLAUSIBLE = "every fill implausibly fast"
REASON_UNCERTAIN = "estimated error above its limit (clean.max_fill_error_mm; the target's, max_target_fill_error_deg)"
REASON_NO_ESTIMATE = ("its fill's error cannot be estimated (nothing measured beside it to hide, or moving with it "
                      "through it, to check a fill on)")
REASON_UNLABELED = "an unlabeled trajectory (filled only when asked)"
#: the note of a gap longer than ``max_gap_s`` filled because its marker is still (:func:`still_gap`)
NOTE_STILL = "longer than max_gap_s, filled as still: still on both sides, and the markers moving with it stay so"


@dataclass
class GapRecord:
    """One gap of one marker: frames ``[start, stop)``, the method that filled it (``unfilled`` if none) and
    each method's mean validation error in mm (NaN when the method could not apply or nothing was hidden).
    ``method`` is the method with the largest weight when several were blended (see ``weights``)."""

    marker: int
    start: int
    stop: int
    method: str
    errors: dict[str, float] = field(default_factory=dict)
    #: blend weights of the methods combined to fill the gap (summing to 1; one entry when a single method)
    weights: dict[str, float] = field(default_factory=dict)
    #: why the gap stays unfilled (a ``REASON_*``), or why its first choice was replaced; empty otherwise
    reason: str = ""
    #: the fill's estimated error, mm: its mean error on the hidden stretches (NaN when nothing could be hidden)
    error_mm: float = float("nan")

    @property
    def length(self) -> int:
        return self.stop - self.start


@dataclass
class Stretches:
    """The measured samples hidden beside a gap for validation, and what each method made of them."""

    #: (n, 3) the hidden samples, mm, stretch after stretch
    truth: np.ndarray
    #: method -> (n, 3) its prediction of them (NaN where it could not predict)
    hidden: dict[str, np.ndarray]
    #: (n,) their frame indices
    frames: np.ndarray
    #: (n, M) the visibility the methods saw in those frames (the gap's occlusion pattern laid over each stretch)
    vis_rows: np.ndarray
    #: (T,) the marker's samples the methods could use (measured, not in the gap or a stretch)
    known: np.ndarray
    #: start of each stretch in ``truth``
    cuts: np.ndarray


@dataclass
class MarkerQC:
    """Per-marker gap-filling QC: gap count, samples filled by each method, samples left unfilled, longest gap."""

    n_gaps: int
    filled: dict[str, int]
    unfilled: int
    longest_gap_frames: int
    longest_gap_s: float


@dataclass
class FillResult:
    """Output of :func:`fill_gaps`.

    xyz : (T, M, 3) filled positions, mm; NaN where still unfilled.
    fill_code : (T, M) int8, :data:`gazepipe.model.FILL_CODES`.
    qc : one :class:`MarkerQC` per marker.
    gaps : one :class:`GapRecord` per gap, in marker then time order.
    """

    xyz: np.ndarray
    fill_code: np.ndarray
    qc: list[MarkerQC]
    gaps: list[GapRecord]

    @property
    def valid(self) -> np.ndarray:
        """(T, M) bool: measured or filled."""
        return self.fill_code != FILL_CODES["unfilled"]

    @property
    def error_mm(self) -> np.ndarray:
        """(T, M) float64, each filled sample's estimated error (:func:`error_map`)."""
        return error_map(self.gaps, self.fill_code.shape)


def error_map(gaps: list[GapRecord], shape: tuple[int, ...]) -> np.ndarray:
    """(T, M) float64 mm: each filled sample's estimated error, its gap's ``error_mm``; NaN where measured,
    unfilled, or filled without an estimate. Made from the records when asked for, so the filler does not hold
    a second take-sized array while it works."""
    error = np.full(shape, np.nan)
    for gap in gaps:
        if gap.method != "unfilled":
            error[gap.start:gap.stop, gap.marker] = gap.error_mm
    return error


def find_gaps(valid_m: np.ndarray) -> list[tuple[int, int]]:
    """Half-open ``[start, stop)`` runs of False in a (T,) bool array."""
    d = np.diff(np.concatenate([[1], valid_m.astype(np.int8), [1]]))
    return list(zip(np.flatnonzero(d == -1).tolist(), np.flatnonzero(d == 1).tolist(), strict=True))


def _validation_windows(valid_m: np.ndarray, s: int, e: int) -> list[tuple[int, int]]:
    """Stretches of measured samples next to gap ``[s, e)`` to hide for validation, about as long as the gap:
    ``_WINDOWS_PER_SIDE`` on each side, or as many as hide ``_MIN_HIDDEN_PER_SIDE`` samples for a short gap.

    Inside a take the stretch is kept ``_SEPARATION`` measured frames away from the gap and leaves at least one
    measured frame on its far side, so every method (interpolation included) sees the same kind of problem.
    At the start or end of a take the stretch touches the gap, so the gap and the stretch form one edge gap.
    """
    n_t = valid_m.size
    length = e - s
    n_win = max(_WINDOWS_PER_SIDE, -(-_MIN_HIDDEN_PER_SIDE // length))
    wins: list[tuple[int, int]] = []
    edge = s == 0 or e == n_t
    # the stretches reach at most this far from the gap: the search for the nearest unmeasured sample (the end of
    # the marker's measured run) looks no farther, so a gap costs its own length, not the take's
    need = n_win * (length + _SEPARATION) + _SEPARATION + 2
    if s > 0:
        w0 = max(0, s - need)
        before = np.flatnonzero(~valid_m[w0:s])
        r0 = int(before[-1]) + 1 + w0 if before.size else w0
        if edge:
            lp = min(length, s - r0 - 1)
            if lp >= 1:
                wins.append((s - lp, s))
        else:
            stop = s - _SEPARATION
            for _ in range(n_win):
                lp = min(length, stop - r0 - 1)
                if lp < 1:
                    break
                wins.append((stop - lp, stop))
                stop -= lp + _SEPARATION
    if e < n_t:
        w1 = min(n_t, e + need)
        after = np.flatnonzero(~valid_m[e:w1])
        r1 = int(after[0]) + e if after.size else w1
        if edge:
            lp = min(length, r1 - e - 1)
            if lp >= 1:
                wins.append((e, e + lp))
        else:
            start = e + _SEPARATION
            for _ in range(n_win):
                lp = min(length, r1 - start - 1)
                if lp < 1:
                    break
                wins.append((start, start + lp))
                start += lp + _SEPARATION
    return wins


@dataclass
class Hidden:
    """The measured samples of a gap's marker hidden beside it for validation (:func:`hide_stretches`)."""

    #: the stretches ``[a, b)`` hidden, nearest the gap first on each side
    wins: list[tuple[int, int]]
    #: (T,) the marker's samples the methods may use (measured, not in the gap or a stretch)
    known: np.ndarray
    #: (T, M) the measured samples of the neighbourhood, and the gap ``[s, e)`` whose occlusion pattern the
    #: stretches get
    valid: np.ndarray
    s: int
    e: int
    _vis: np.ndarray | None = field(default=None, repr=False)

    def rows(self, a: int, b: int) -> np.ndarray:
        """(b - a, M) the visibility the methods see in hidden stretch ``[a, b)``: the gap's occlusion pattern
        laid over it (a marker missing in the gap's i-th frame is missing in the stretch's i-th frame)."""
        return self.valid[a:b] & self.valid[self.s + np.minimum(np.arange(b - a), self.e - self.s - 1)]

    @property
    def vis(self) -> np.ndarray:
        """(T, M) the visibility the methods see: ``valid`` with :meth:`rows` in the stretches. A copy of the
        neighbourhood's, made when first asked for (by the rigid and PCA candidates): a gap that interpolation
        fills alone needs only the stretches' rows."""
        if self._vis is None:
            vis = self.valid.copy()
            for a, b in self.wins:
                vis[a:b] = self.rows(a, b)
            self._vis = vis
        return self._vis


@dataclass
class Candidates:
    """What each method makes of a gap and of its hidden stretches."""

    #: method -> (e - s, 3) its fill of the gap, mm, in ``methods`` order
    gap: dict[str, np.ndarray]
    #: method -> its prediction of each hidden stretch (None where it has none)
    stretch: dict[str, Mapping[tuple[int, int], np.ndarray | None]]
    #: the PCA model of the best (model, component count) pair, when PCA predicted
    pca_model: PcaModel | None = None
    pca_stretches: list[tuple[int, int]] = field(default_factory=list)


def hide_stretches(valid: np.ndarray, m: int, s: int, e: int, validate: bool,
                   valid_m: np.ndarray | None = None) -> Hidden:
    """The stretches beside gap ``[s, e)`` to hide (:func:`_validation_windows`; none without ``validate``).
    They also get the gap's occlusion pattern: a marker missing in the gap's i-th frame is treated as missing in
    each stretch's i-th frame, so rigid and PCA are validated with the donors they will really have.
    ``valid_m``: ``valid[:, m]`` as a contiguous array, when the caller holds one (copied far faster than the
    column of ``valid``)."""
    valid_m = valid[:, m] if valid_m is None else valid_m
    wins = _validation_windows(valid_m, s, e) if validate else []
    known = valid_m.copy()
    for a, b in wins:
        known[a:b] = False
    return Hidden(wins, known, valid, s, e)


def _seen_in_stretches(valid: np.ndarray, hid: Hidden, m: int) -> np.ndarray:
    """``valid`` without the markers (but ``m``) missing somewhere in a hidden stretch as the methods see it: a
    rigid fill from neighbours is then validated with the very neighbours it fills the gap from. A head marker
    measured through a chest gap but hidden beside it joined the gap's neighbours only: validated at 1.5 mm
    without it, the fill with it was 48 mm off."""
    if not hid.wins:
        return valid
    seen = np.logical_and.reduce([hid.rows(a, b).all(axis=0) for a, b in hid.wins])
    seen[m] = True
    return valid & seen


def interpolation_candidates(xyz_m: np.ndarray, valid_m: np.ndarray, s: int, e: int, hid: Hidden,
                             methods: tuple[str, ...]) -> Candidates:
    """Linear and PCHIP (those of ``methods``) over the gap from the marker's measured samples ``valid_m``, and
    over each hidden stretch from its ``known`` ones."""
    gap: dict[str, np.ndarray] = {}
    stretch: dict[str, Mapping[tuple[int, int], np.ndarray | None]] = {}
    for meth in (k for k in methods if k in _INTERP):
        fill = interp_fill(xyz_m, valid_m, [(s, e)], meth)[0]
        if fill is not None:
            gap[meth] = fill
        stretch[meth] = dict(zip(hid.wins, interp_fill(xyz_m, hid.known, hid.wins, meth), strict=True))
    return Candidates(gap, stretch)


def _donor_errors(xyz: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, cands: Candidates,
                  mates_window: int | None) -> dict[str, float]:
    """Interpolation's error over the gap's own frames on the markers moving with ``m``
    (:func:`donor_interp_errors`), for the interpolation methods that fill the gap."""
    return donor_interp_errors(xyz, valid, m, s, e, [k for k in cands.gap if k in _INTERP], window=mates_window)


def model_candidates(xyz: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, methods: tuple[str, ...],
                     cluster: list[int] | None, hid: Hidden, interp: Candidates, pca_window: int | None
                     ) -> Candidates:
    """``interp`` with the rigid and PCA candidates (those of ``methods``) added, in ``methods`` order."""
    gap: dict[str, np.ndarray] = {}
    stretch = dict(interp.stretch)
    out = Candidates(gap, stretch)
    if "rigid" in methods and cluster:
        stretch["rigid"] = (dict(zip(hid.wins, rigid_fill_many(xyz, hid.vis, m, cluster, hid.known, hid.wins,
                                                                  True), strict=True)) if hid.wins else {})
    if "pca" in methods:
        win = None if pca_window is None else (max(0, s - pca_window), min(xyz.shape[0], e + pca_window))
        model, pca_gap, pca_wins = _pca_predictions(xyz, valid, hid.vis, m, s, e, hid.wins, win)
        if model is not None:
            stretch["pca"] = pca_wins
            out.pca_model, out.pca_stretches = model, list(pca_wins)
    for meth in methods:
        if meth in interp.gap:
            gap[meth] = interp.gap[meth]
        elif meth == "rigid" and cluster:
            fill = rigid_fill(xyz, valid, m, cluster, valid[:, m], s, e)
            if fill is not None:
                gap[meth] = fill
        elif meth == "pca" and out.pca_model is not None and pca_gap is not None:
            gap[meth] = pca_gap
        elif meth not in METHODS:
            raise ValueError(f"unknown gap-filling method {meth!r}")
    return out


def validate_candidates(xyz: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, hid: Hidden,
                        cands: Candidates, donors: dict[str, float], validate: bool
                        ) -> tuple[dict[str, np.ndarray], dict[str, float], Stretches | None]:
    """Each candidate's mean error on the hidden samples (methods compared on the frames all of them could
    predict, else each on its own frames), then corrected for motion the stretches cannot show.

    Returns ``(predictions, errors, stretches)``: method -> (e - s, 3) fill; method -> mean Euclidean error (mm)
    over the hidden samples (NaN when nothing could be hidden or the method predicted none of them); the hidden
    samples and each method's prediction of them (:class:`Stretches`), None when nothing was hidden."""
    preds = cands.gap
    xyz_m = xyz[:, m]
    stretches = None
    errors = {meth: float("nan") for meth in preds}
    if hid.wins and preds:
        truth = np.concatenate([xyz_m[a:b] for a, b in hid.wins])
        hidden = {meth: np.concatenate([_or_nan(cands.stretch.get(meth, {}).get((a, b)), b - a)
                                        for a, b in hid.wins]) for meth in preds}
        frames = np.concatenate([np.arange(a, b) for a, b in hid.wins])
        cuts = np.cumsum([0] + [b - a for a, b in hid.wins[:-1]])
        stretches = Stretches(truth, hidden, frames, np.concatenate([hid.rows(a, b) for a, b in hid.wins]),
                              hid.known, cuts)
        err = norm3(np.stack(list(hidden.values())) - truth)
        common = np.isfinite(err).all(axis=0)
        for i, meth in enumerate(preds):
            row = err[i, common] if common.any() else err[i, np.isfinite(err[i])]
            errors[meth] = float(row.mean()) if row.size else float("nan")
    if validate:
        _motion_checks(xyz, valid, m, s, e, hid, cands, donors, errors)
    return preds, errors, stretches


def _motion_checks(xyz: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, hid: Hidden, cands: Candidates,
                   donors: dict[str, float], errors: dict[str, float]) -> None:
    """Correct the validation ``errors`` (in place) for what the stretches beside the gap cannot show.

    Interpolation knows nothing of the gap's own frames: its error there is what the motion during the gap makes
    it (a reach between two still phases). The nearest markers measured through the gap that move with the
    marker, interpolated over the same frames (``donors``), show it. The opposite blind spot: the marker stands
    still through the gap (a foot in stance) while the stretches hold motion (the steps); its speed at the gap's
    edges shows it. PCA is blind like interpolation when the gap's poses are unlike the training frames; its own
    predictors show it (:func:`pca_novelty`). Where no donor shows it, the fill's final estimate is scaled by
    how much further the marker travels across the gap (:func:`moving_gap_factor`, in :func:`_fill_gap`).
    """
    novel = False
    for meth, err_d in donors.items():
        # another marker's error is a rough guess of this one's: believed only when clearly larger
        if np.isfinite(err_d) and not err_d <= _INTERP_DONOR_FACTOR * errors.get(meth, np.nan):
            errors[meth] = err_d
            novel = True
    xyz_m = xyz[:, m]
    if not novel and hid.wins:
        # interpolation's error scaled by the speed at the gap over the speed in the stretches (not where the
        # donors saw motion in the gap: a reach between holds)
        speed_gap, speed_str = edge_speed(xyz_m, valid[:, m], s, e), speed_over(xyz_m, hid.wins)
        if speed_gap < _STILL_EDGE_RATIO * speed_str:
            for meth in donors:
                errors[meth] *= max(speed_gap, _ERR_FLOOR_MM) / speed_str
    # checked only where the donors show motion the stretches do not
    if novel and "pca" in cands.gap and cands.pca_model is not None:
        ratio = pca_novelty(cands.pca_model, xyz, valid, hid.vis, cands.pca_stretches, s, e)
        if ratio > _PCA_NOVELTY_MIN:
            errors["pca"] *= ratio


def _pca_predictions(xyz: np.ndarray, valid: np.ndarray, valid_v: np.ndarray, m: int, s: int, e: int,
                     wins: list[tuple[int, int]], win: tuple[int, int] | None
                     ) -> tuple[PcaModel | None, np.ndarray | None, dict[tuple[int, int], np.ndarray]]:
    """PCA's prediction of gap ``[s, e)`` of marker ``m`` and of the hidden stretches ``wins``.

    Models are fitted on the frames in ``win`` where the marker is measured outside the gap and the stretches:
    in the lab frame, and in the moving frames of the three predictors at the steadiest distance from the marker
    and of the three nearest ones (:class:`PcaModel` ``local_frame``: the rotation of the body part removed, so
    the components describe how it bends). When the stretches leave too few training frames, the farthest
    stretches are given back to training (and not used for validation). Every (model, component count) pair
    predicts the stretches; the gap is filled with the ``_PCA_BLEND_TOP`` pairs that predicted them best,
    weighted by inverse squared error (model averaging: 5–10 % below the single best pair on both real files,
    at every gap length). Returns ``(model, gap, stretches)``: the best pair's model (its ``k`` set), the
    (e - s, 3) prediction or None, and each validated stretch's blended prediction (NaN where it cannot be
    predicted).
    """
    valid_m = valid[:, m]
    used = sorted(wins, key=lambda w: min(abs(w[0] - e), abs(s - w[1])))  # nearest first
    while True:
        known = valid_m.copy()
        for a, b in used:
            known[a:b] = False
        models = fit_pca_models(xyz, valid, m, known, s, e, _PCA_MODELS, window=win)
        if models or not used:
            break
        used = used[:-1]
    if not models:
        return None, None, {}
    wins = [w for w in wins if w in used]
    # the hidden stretches and the gap in one prediction (they share the gap's occlusion patterns)
    jobs = [(a, b, valid_v, known, True) for a, b in wins] + [(s, e, valid, valid_m, False)]
    cands = [(mod, k) for mod in models for k in mod.ks]
    # every candidate's prediction of the stretches then the gap (C, frames, 3), NaN where it has none
    filled, none = pca_fill_packed(models, xyz, jobs)
    no_gap = none[:, -1]
    n_hidden = filled.shape[1] - (e - s)
    xyz_m = xyz[:, m]
    if wins:
        # each candidate's mean error over the hidden samples it could predict
        truth = np.concatenate([xyz_m[a:b] for a, b in wins])
        # row-major, so each row sums in the same (pairwise) order whatever the layout norm3 returns
        e_c = np.ascontiguousarray(norm3(filled[:, :n_hidden] - truth))
        fin = np.isfinite(e_c)
        n_fin = fin.sum(axis=1)
        scores = np.where(fin, e_c, 0.0).sum(axis=1) / np.maximum(n_fin, 1)
        scores[n_fin == 0] = np.inf
    else:
        scores = np.full(len(cands), np.inf)
    if not np.isfinite(scores[~no_gap]).any():
        # nothing hidden, or no candidate predicted a hidden sample: unvalidated, the first model's middle
        # component count, else the first candidate that predicts the gap
        mid = len(models[0].ks) // 2
        scores = np.full(len(cands), np.inf)
        scores[mid if not no_gap[mid] else int(np.argmin(no_gap))] = 1.0
    scores[no_gap] = np.inf
    if not np.isfinite(scores).any():
        return None, None, {}
    idx, w = inverse_square_weights(scores, _PCA_BLEND_TOP)
    model, model.k = cands[idx[0]]
    # the blend, weights renormalised per frame over the candidates that predict it
    q = filled[idx]
    ok = np.isfinite(q).all(axis=2)
    wf = np.where(ok, w[:, None], 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mixed = (np.where(ok[..., None], q, 0.0) * wf[..., None]).sum(axis=0) / wf.sum(axis=0)[:, None]
    offs = np.cumsum([0] + [b - a for a, b in wins]).tolist()
    stretches = {(a, b): mixed[o:o + b - a] for (a, b), o in zip(wins, offs[:-1], strict=True)}
    return model, mixed[n_hidden:], stretches


def _or_nan(pred: np.ndarray | None, n: int) -> np.ndarray:
    """A method's (n, 3) prediction, or NaN rows when it could not predict any of the n frames."""
    return np.full((n, 3), np.nan) if pred is None else pred


def inverse_square_weights(errors: np.ndarray, top: int, max_ratio: float = _BLEND_MAX_RATIO
                           ) -> tuple[np.ndarray, np.ndarray]:
    """The ``top`` entries of ``errors`` (mm) with the lowest finite values, among those within ``max_ratio`` of
    the lowest, and their convex weights ∝ 1 / error² (an error below ``_ERR_FLOOR_MM`` counts as that floor):
    ``(indices best first, weights)``. Ties keep the order of ``errors``."""
    order = np.argsort(errors, kind="stable")
    order = order[np.isfinite(errors[order])][:top]
    e = np.maximum(errors[order], _ERR_FLOOR_MM)
    order, e = order[e <= max_ratio * e[0]], e[e <= max_ratio * e[0]]
    inv = 1.0 / e ** 2
    return order, inv / inv.sum()


def choose(errors: dict[str, float], methods: tuple[str, ...]) -> str | None:
    """Method with the lowest validation error; the first available in ``methods`` order when none has one."""
    avail = [m for m in methods if m in errors]
    if not avail:
        return None
    scored = [m for m in avail if np.isfinite(errors[m])]
    if not scored:
        return avail[0]
    return min(scored, key=lambda m: (errors[m], methods.index(m)))


def blend_weights(errors: dict[str, float], methods: tuple[str, ...], *, top: int = _BLEND_TOP,
                  max_ratio: float = _BLEND_MAX_RATIO) -> dict[str, float]:
    """Convex weights of the methods to blend, from their validation errors (mm).

    The ``top`` methods with the lowest finite errors, among those within ``max_ratio`` of the best, are weighted
    by inverse squared error (an error below ``_ERR_FLOOR_MM`` counts as that floor), so a clearly better
    method dominates and near-equal ones average out their independent mistakes. Without any finite error, the
    method :func:`choose` picks gets weight 1. Empty when no method applies.
    """
    best = choose(errors, methods)
    if best is None:
        return {}
    scored = [m for m in methods if m in errors and np.isfinite(errors[m])]
    if not scored:
        return {best: 1.0}
    idx, w = inverse_square_weights(np.array([errors[m] for m in scored]), top, max_ratio)
    return {scored[i]: float(x) for i, x in zip(idx, w, strict=True)}


def check_blend(weights: dict[str, float], truth: np.ndarray, hidden: dict[str, np.ndarray]) -> dict[str, float]:
    """``weights``, or the method with the largest weight alone when the blend predicts the hidden samples
    ``truth`` (n, 3) worse than that method does (mean error over the frames every blended method predicts;
    ``hidden`` maps method -> its (n, 3) prediction, NaN where none).

    Inverse-square weights assume independent errors; two methods that err alike (linear and PCHIP
    interpolating the same noisy samples) or one whose validation error is flattered by the samples' own noise
    can make the blend worse than its best member. On the sample session's still takes this took short gaps from
    1.09x to 1.06x linear's error.
    """
    top = max(weights, key=lambda k: weights[k])
    if any(k not in hidden for k in weights):
        return weights
    q, ok = _blend_on_hidden(weights, hidden)
    if not ok.any():
        return weights
    if norm3(q[ok] - truth[ok]).mean() > norm3(hidden[top][ok] - truth[ok]).mean():
        return {top: 1.0}
    return weights


def fill_error(weights: dict[str, float], errors: dict[str, float], stretches: Stretches | None) -> float:
    """The estimated error (mm) of a fill with ``weights``: the method's validation error, or for a blend its
    mean error on the hidden samples (over the frames every blended method predicts). A blend that cannot be
    tried on hidden samples (none could be hidden beside the gap: its members' errors come from the markers
    moving with it through the gap, :func:`_motion_checks`) gets the weighted sum of its members' errors, which
    bounds its own (a convex blend errs by at most as much: triangle inequality). NaN when unknown."""
    if len(weights) == 1:
        return float(errors.get(next(iter(weights)), np.nan))
    if stretches is not None and all(k in stretches.hidden for k in weights):
        q, ok = _blend_on_hidden(weights, stretches.hidden)
        if ok.any():
            return float(norm3(q[ok] - stretches.truth[ok]).mean())
    bound = sum(w * errors.get(k, np.nan) for k, w in weights.items())
    return float(bound) if np.isfinite(bound) else float("nan")


def _blend_on_hidden(weights: dict[str, float], hidden: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The blend's prediction of the hidden samples (n, 3) and the frames where every blended method has one."""
    q = cast(np.ndarray, sum(w * hidden[k] for k, w in weights.items()))   # weights is never empty
    return q, np.isfinite(q).all(axis=1)


def fill_gaps(xyz: np.ndarray, valid: np.ndarray, rate_hz: float, *, clusters: list[list[int]] | None = None,
              max_gap_s: float = 1.0, methods: tuple[str, ...] = METHODS, validation: bool = True,
              pca_window_s: float | None = 10.0, blend: bool = True, steady_mates: bool = True,
              max_error_mm: float | np.ndarray | ErrorLimits | None = None, framewise: bool = True,
              stats: TakeStatistics | None = None, in_place: bool = False,
              groups: list[list[int]] | None = None, leave: Collection[int] = (),
              still_speed_mm_s: float | None = None) -> FillResult:
    """Fill marker gaps, choosing the best method per gap.

    Parameters
    ----------
    xyz : (T, M, 3) positions, mm, NaN where not measured.
    valid : (T, M) bool, measured samples.
    rate_hz : sampling rate, Hz.
    clusters : lists of marker indices that move rigidly together (segments); rigid fill uses the cluster of
        the gap's marker (the first one listing it).
    steady_mates : for a gap whose marker has no cluster, or whose cluster has no mate measured in some of its
        frames, rigid fill uses the (up to three) markers measured through the gap whose distance to it varied
        least around the gap (standard deviation under 20 mm over 2 s each side), when there are two or more.
    max_gap_s : gaps of more than ``max_gap_s * rate_hz`` missing samples stay unfilled.
    max_error_mm : gaps whose fill's estimated error (:func:`fill_error`) is above this stay unfilled (None: no
        limit). A (T, M) array or an :class:`ErrorLimits` gives a limit per sample; a gap's limit is the smaller
        of those of the measured frames on either side. Whatever the limit, with ``validation`` a gap whose
        fill's error cannot be estimated (nothing beside it could be hidden) stays unfilled
        (:data:`REASON_NO_ESTIMATE`).
    methods : candidate methods, subset of ``("rigid", "pca", "pchip", "linear")``; the order breaks ties
        and decides when nothing can be hidden for validation. A single method forces that method.
    validation : when False, skip hiding samples and take the first applicable method in ``methods`` order.
    blend : fill each gap with the convex combination of the best methods by validation error
        (:func:`blend_weights`; samples coded by the largest weight), unless the combination predicts the hidden
        samples worse than its best member (:func:`check_blend`); when False, the single best method.
    pca_window_s : PCA models are fitted on frames within this many seconds of the gap (None: the whole take).
    framewise : for gaps of at least ``_FRAMEWISE_MIN_FRAMES``, also average the candidate fills frame by frame
        (:mod:`.framewise`) and keep that average where it predicts the hidden samples better than the per-gap
        blend (``GapRecord.reason`` says so; ``weights`` are then its priors).
    stats : the take's statistics (:func:`take_statistics`) when ``xyz`` is part of a longer take; default:
        those of ``xyz``. Given them, a gap's fill depends only on the frames within ``_GapSettings.reach`` of it.
    in_place : fill ``xyz`` itself, a C-contiguous float64 array the caller owns (its samples not ``valid`` are
        set to NaN first), instead of a copy: a long take's positions are then held once, not twice.
    groups : lists of marker indices that move independently of every other group (the subject; each prop, such
        as a gaze target or a clapper): a gap is filled from its own group's markers only (PCA predictors,
        steady mates, frame-by-frame donors). A marker in no group is a group of its own. None: one group.
    leave : markers whose gaps stay unfilled (:data:`REASON_UNLABELED`: unlabeled trajectories,
        :func:`unlabeled_markers`, unless the caller was asked to fill them).
    still_speed_mm_s : when given, a gap longer than ``max_gap_s`` is still filled where its marker is measured
        still (at most this speed, mm/s) on both sides and the markers moving with it stay still through it
        (:func:`still_gap`); None: longer gaps stay unfilled.

    Returns
    -------
    FillResult; measured samples are copied bit for bit, only gap samples are written (with ``in_place``, its
    ``xyz`` is the array given).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    if xyz.ndim != 3 or xyz.shape[2] != 3 or valid.shape != xyz.shape[:2]:
        raise ValueError(f"xyz must be (T, M, 3) and valid (T, M); got {xyz.shape} and {valid.shape}")
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise ValueError(f"unknown gap-filling method(s) {bad}; choose from {list(METHODS)}")
    n_t, n_m = valid.shape
    # measured samples must be finite to be used; non-finite ones are treated as gaps. C order: every gap's
    # neighbourhood below is then a contiguous block of rows
    valid = valid & np.isfinite(xyz).all(axis=2)
    if in_place and xyz.flags.c_contiguous and xyz.flags.writeable:
        src = xyz
        src[~valid] = np.nan
    else:
        src = np.ascontiguousarray(np.where(valid[..., None], xyz, np.nan))
    fills: list[tuple[int, int, int, np.ndarray]] = []    # written into src once every gap is decided
    code = np.where(valid, FILL_CODES["measured"], FILL_CODES["unfilled"]).astype(np.int8)
    cfg = _GapSettings.for_take(rate_hz, n_t, tuple(methods), max_gap_s=max_gap_s, validation=validation,
                                pca_window_s=pca_window_s, blend=blend, steady_mates=steady_mates,
                                framewise=framewise, still_speed_mm_s=still_speed_mm_s)
    left = {int(i) for i in leave}
    cluster_of: dict[int, list[int]] = {}
    for c in clusters or []:
        for j in c:
            cluster_of.setdefault(int(j), [int(k) for k in c])
    same_group = _same_group(groups, n_m)
    masked: dict[bytes, np.ndarray] = {}     # valid for each group's markers only, made once per group
    records: list[GapRecord] = []
    qc: list[MarkerQC] = []
    stats = take_statistics(src, valid) if stats is None else stats
    limits, noise = stats.step_limit_mm, stats.noise_mm
    ever = np.any(valid, axis=0)
    # each marker's measured samples as one contiguous row: a gap copies its neighbourhood's part of it (a
    # column of ``valid`` is strided: copying it cost as much as the rest of a short gap at 10 kHz)
    columns = np.ascontiguousarray(valid.T)
    # the small matrix products below run fastest, and give the same results everywhere, on one BLAS thread
    with one_blas_thread():
        for m in range(n_m):
            gaps = find_gaps(valid[:, m]) if n_t else []
            filled = {k: 0 for k in METHODS}
            for s, e in gaps:
                why = REASON_NEVER_MEASURED if not ever[m] else REASON_UNLABELED if m in left else ""
                if why or (e - s > cfg.max_len and cfg.still_speed is None):
                    records.append(GapRecord(m, s, e, "unfilled", reason=why or REASON_TOO_LONG))
                    continue
                # everything about a gap is decided from its neighbourhood: the cost per gap does not grow with
                # the take, and the result does not depend on what lies farther away
                lo, hi = max(0, s - cfg.reach), min(n_t, e + cfg.reach)
                limit = None if max_error_mm is None else gap_limit(max_error_mm, m, s, e)
                near = valid[lo:hi] if same_group is None else _group_valid(valid, same_group[m], masked)[lo:hi]
                if e - s > cfg.max_len:
                    record, fill = still_gap(src[lo:hi], near, m, s - lo, e - lo, float(limits[m]), limit, cfg)
                else:
                    record, fill = _fill_gap(src[lo:hi], near, m, s - lo, e - lo, cluster_of.get(m),
                                             float(limits[m]), limit, float(noise[m]), cfg, columns[m, lo:hi])
                record.start, record.stop = s, e
                records.append(record)
                if fill is not None:
                    fills.append((m, s, e, fill))
                    code[s:e, m] = FILL_CODES[record.method]
                    filled[record.method] += e - s
            unfilled = int((code[:, m] == FILL_CODES["unfilled"]).sum())
            longest = max((e - s for s, e in gaps), default=0)
            qc.append(MarkerQC(len(gaps), filled, unfilled, longest, longest / rate_hz))
    # no gap's fill may serve another gap as data: they go in only now
    for m, s, e, fill in fills:
        src[s:e, m] = fill
    return FillResult(src, code, qc, records)


def _group_valid(valid: np.ndarray, members: np.ndarray, masked: dict[bytes, np.ndarray]) -> np.ndarray:
    """``valid`` (T, M) with the markers outside ``members`` (M,) bool cleared, made once per group and kept in
    ``masked``: a gap then slices its neighbourhood out of it instead of masking the neighbourhood again."""
    key = members.tobytes()
    if key not in masked:
        masked[key] = valid & members
    return masked[key]


def _same_group(groups: list[list[int]] | None, n_m: int) -> np.ndarray | None:
    """(M, M) bool: whether two markers are in one of ``groups`` (a marker in none is alone); None for None."""
    if groups is None:
        return None
    label = np.arange(n_m) + n_m                      # a marker in no group is a group of its own
    for g, members in enumerate(groups):
        label[np.asarray(members, dtype=int)] = g
    return label[:, None] == label[None, :]


@dataclass(frozen=True)
class TakeStatistics:
    """What the filler knows of the whole take: each marker's largest plausible step (:func:`step_limits`) and
    its noise floor (:func:`interpolation_noise_mm`), (M,) mm each."""

    step_limit_mm: np.ndarray
    noise_mm: np.ndarray


def take_statistics(xyz: np.ndarray, valid: np.ndarray) -> TakeStatistics:
    """:class:`TakeStatistics` of positions ``xyz`` (T, M, 3) mm, NaN where not measured, ``valid`` (T, M)."""
    return TakeStatistics(step_limits(xyz, valid), interpolation_noise_mm(xyz, valid))


@dataclass(frozen=True)
class _GapSettings:
    """What :func:`fill_gaps` decides once per take: the methods, how they run, and in frames the longest gap
    filled, the windows the methods look through and the neighbourhood (``reach`` frames each side) that holds
    them all."""

    methods: tuple[str, ...]
    validation: bool
    blend: bool
    steady_mates: bool
    framewise: bool
    max_len: int
    pca_window: int | None
    mates_window: int
    edge_window: int
    reach: int
    cheap_max_len: int
    #: a gap longer than ``max_len`` is filled as still when its marker moves at most this much (mm per frame) on
    #: both sides over ``still_side`` frames (None: never)
    still_speed: float | None = None
    still_side: int = 0

    @classmethod
    def for_take(cls, rate_hz: float, n_t: int, methods: tuple[str, ...], *, max_gap_s: float,
                 validation: bool, pca_window_s: float | None, blend: bool, steady_mates: bool,
                 framewise: bool, still_speed_mm_s: float | None = None) -> _GapSettings:
        max_len = int(np.floor(max_gap_s * rate_hz + 1e-9))
        pca_window = None if pca_window_s is None else int(round(pca_window_s * rate_hz))
        mates_window = max(1, int(round(_MATES_WINDOW_S * rate_hz)))
        edge_window = max(_EDGE_MIN_SAMPLES, int(round(_EDGE_WINDOW_S * rate_hz)))
        still_side = max(_STILL_MIN_SAMPLES, int(round(_STILL_SIDE_S * rate_hz)))
        reach = max(n_t if pca_window is None else pca_window, mates_window, edge_window, still_side,
                    _stretch_reach(max_len)) + 1
        still = None if still_speed_mm_s is None or not validation else float(still_speed_mm_s) / rate_hz
        return cls(methods, validation, blend, steady_mates, framewise, max_len, pca_window, mates_window,
                   edge_window, reach, int(np.floor(_CHEAP_MAX_S * rate_hz + 1e-9)), still, still_side)


#: a gap up to this long (s) whose interpolation validates at the marker's noise floor is filled by
#: interpolation without trying the rigid and PCA candidates: over such a span nothing predicts the hidden
#: samples measurably better than the noise they carry
_CHEAP_MAX_S = 0.25
NOTE_NOISE_FLOOR = "interpolation at the marker's noise floor: rigid and PCA not tried"
#: spread of the length of a 3-D normal error over its mean (√(3 − 8/π) / √(8/π)): the mean of n hidden samples'
#: errors is "at the noise floor" up to two standard errors above it, 1 + 2 · 0.42 / √n times the floor
_NOISE_ERROR_CV = 0.42
#: third differences needed to estimate a marker's noise (fewer: no estimate, nothing skipped), and about the
#: most used (the relative standard error of a MAD from n samples is about 1.1 / √n: 2 % from 4,000)
_NOISE_MIN_FRAMES = 20
_NOISE_SAMPLES = 4000


def interpolation_noise_mm(xyz: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Each marker's noise floor (M,) mm: the mean error that interpolating its hidden samples would show from
    measurement noise alone (NaN when it has fewer than ``_NOISE_MIN_FRAMES`` runs of four measured frames).

    The noise (σ per axis) comes from the third difference of consecutive measured samples, robustly (median
    absolute deviation); white noise gives it a variance of 20 σ², while smooth motion barely moves it (a limb
    swinging 100 mm at 0.8 Hz adds 0.06 mm at 60 Hz, against 0.7 mm in the second difference: 0.1 mm of noise
    would read as 0.2-0.4 mm from that). A hidden sample carries σ and a linear interpolant between
    its anchors about σ √(2/3) on average, so the error is a 3-D normal of σ √(5/3) per axis, whose mean length
    is 2 √(2/π) σ √(5/3) ≈ 2.06 σ.
    """
    from gazepipe.stages.clean import kernels

    n_t, n_m = valid.shape
    if n_t < 4:
        return np.full(n_m, np.nan)
    # a few thousand differences per marker fix its MAD to a percent or so: evenly spaced frames, so a long take
    # costs no more than a short one
    step = max(1, (n_t - 3) // _NOISE_SAMPLES)
    mad = 1.4826 * kernels.third_difference_mads(np.asarray(xyz, dtype=np.float64),
                                                 np.asarray(valid, dtype=np.bool_), step, _NOISE_MIN_FRAMES)
    sigma = np.sqrt(np.mean(np.square(mad), axis=1) / 20.0)
    return 2.0 * np.sqrt(2.0 / np.pi) * np.sqrt(5.0 / 3.0) * sigma


def _interpolation_suffices(src: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, hid: Hidden,
                            interp: Candidates, donors: dict[str, float], noise_mm: float, cfg: _GapSettings
                            ) -> tuple[dict[str, np.ndarray], dict[str, float], Stretches | None] | None:
    """The validated interpolation candidates of a short gap (linear and PCHIP only) when the better of them
    validates at the noise floor ``noise_mm`` (within two standard errors of the mean over the hidden samples;
    the donor and still-marker checks included); None when the gap needs every candidate."""
    n_interp = sum(k in _INTERP for k in cfg.methods)
    if (not cfg.validation or not n_interp or n_interp == len(cfg.methods) or not np.isfinite(noise_mm)
            or e - s > cfg.cheap_max_len):
        return None
    preds, errors, stretches = validate_candidates(src, valid, m, s, e, hid, interp, donors, True)
    best = min((v for v in errors.values() if np.isfinite(v)), default=np.inf)
    if stretches is None:
        return None
    at_floor = noise_mm * (1.0 + 2.0 * _NOISE_ERROR_CV / np.sqrt(stretches.truth.shape[0]))
    return (preds, errors, stretches) if best <= at_floor else None


def _stretch_reach(max_len: int) -> int:
    """Frames beyond a gap of at most ``max_len`` frames that its hidden validation stretches
    (:func:`_validation_windows`) can reach, with the measured frame kept on their far side."""
    lengths = np.arange(1, max(max_len, 1) + 1)
    n_win = np.maximum(_WINDOWS_PER_SIDE, -(-_MIN_HIDDEN_PER_SIDE // lengths))
    return int((n_win * (lengths + _SEPARATION)).max()) + _SEPARATION + 1


def _fill_gap(src: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, cluster: list[int] | None,  # noqa: C901
              step_limit: float, max_error: float | None, noise_mm: float, cfg: _GapSettings,
              valid_m: np.ndarray | None = None) -> tuple[GapRecord, np.ndarray | None]:
    """Fill gap ``[s, e)`` of marker ``m`` from its neighbourhood ``src`` (n, M, 3) mm, ``valid`` (n, M), frames
    relative to it: the candidates, their validation, the blend (or the frame-by-frame average), the checks.
    ``noise_mm``: the marker's noise floor (:func:`interpolation_noise_mm`); ``valid_m``: ``valid[:, m]`` as a
    contiguous array, when the caller holds one. Returns the gap's record and its (e - s, 3) fill, or None when it
    stays unfilled (the record says why)."""
    methods = cfg.methods
    own_mates = cluster                  # the segment's; ``cluster`` may become steady mates from other segments
    valid_m = valid[:, m] if valid_m is None else valid_m
    hid = hide_stretches(valid, m, s, e, cfg.validation, valid_m)
    interp = interpolation_candidates(src[:, m], valid_m, s, e, hid, methods)
    donors = _donor_errors(src, valid, m, s, e, interp, cfg.mates_window) if cfg.validation else {}
    found = _interpolation_suffices(src, valid, m, s, e, hid, interp, donors, noise_mm, cfg)
    if found is not None:
        preds, errors, stretches = found
    else:
        # no cluster, or none of its mates measured in some frame of the gap: the steadiest neighbours
        if cfg.steady_mates and "rigid" in methods and (cluster is None
                                                        or not valid[s:e][:, cluster].any(axis=1).all()):
            cluster = find_steady_mates(src, _seen_in_stretches(valid, hid, m), m, s, e, cfg.mates_window)
        cands = model_candidates(src, valid, m, s, e, methods, cluster, hid, interp, cfg.pca_window)
        preds, errors, stretches = validate_candidates(src, valid, m, s, e, hid, cands, donors, cfg.validation)
    if cfg.blend:
        weights = blend_weights(errors, methods)
        if len(weights) > 1 and stretches is not None:
            weights = check_blend(weights, stretches.truth, stretches.hidden)
    else:
        one = choose(errors, methods)
        weights = {} if one is None else {one: 1.0}
    full_errors = {k: errors.get(k, float("nan")) for k in methods}
    if not weights:
        return GapRecord(m, s, e, "unfilled", full_errors, reason=REASON_NO_METHOD), None
    weights, fill, note = _plausible_fill(src[:, m], s, e, preds, weights, full_errors, methods, step_limit)
    if fill is None:
        return GapRecord(m, s, e, "unfilled", full_errors, reason=note), None
    error = fill_error(weights, full_errors, stretches)
    if cfg.framewise and cfg.blend and stretches is not None and e - s >= _FRAMEWISE_MIN_FRAMES:
        averaged = _framewise_fill(src, valid, m, s, e, preds, full_errors, methods, stretches,
                                   cfg.mates_window, step_limit)
        if averaged is not None and not averaged[1] >= error:     # better, or the blend has no estimate
            fill, error, weights = averaged
            note = NOTE_FRAMEWISE
    error = max(error, edge_velocity_error(src[:, m], s, e, preds, weights, cfg.edge_window))
    if weights.get("rigid", 0.0) > 0 and cluster and _two_mates_somewhere(valid, cluster, m, s, e):
        error = max(error, weights["rigid"] * _twist_error(src, valid, m, s, e, cluster, preds["rigid"],
                                                           cfg.mates_window))
    moving = moving_gap_factor(src[:, m], valid[:, m], s, e, hid.wins) if cfg.validation else 1.0
    if moving > 1.0:
        # the stretches it was tried on may be still while the gap moves (a gaze shift between two rests): every
        # method looks right on them, so the estimate grows with how much further the gap travels; a rigid fill
        # from three mates measured in every frame of the gap follows the motion, and stands alone where the
        # scaled estimate would leave the gap open
        scaled = error * moving
        rigid_error = full_errors.get("rigid", np.nan)
        if (max_error is not None and scaled > max_error and rigid_error < scaled and cluster
                and cluster is own_mates and "rigid" in preds and _mates_through(valid, cluster, m, s, e)):
            fill, weights, error = preds["rigid"], {"rigid": 1.0}, rigid_error
        else:
            error = scaled
    if weights.get("rigid", 0.0) > 0 and cluster and cluster is not own_mates:
        # mates from other segments: rigid with the marker only as far as they stay so around the gap
        error = max(error, weights["rigid"] * mates_misfit(src, valid, m, s, e, cluster, cfg.mates_window))
    if cfg.validation:
        error = max(error, distance_miss(src, valid, m, s, e, own_mates, fill, cfg.mates_window))
    if cfg.validation and not np.isfinite(error):
        # a fill is kept only where its error can be estimated (SPEC §3.2 step 2): nothing could be hidden beside
        # the gap, or no method predicted what was
        return GapRecord(m, s, e, "unfilled", full_errors, weights, REASON_NO_ESTIMATE, error), None
    if max_error is not None and error > max_error:
        return GapRecord(m, s, e, "unfilled", full_errors, weights, REASON_UNCERTAIN, error), None
    best = max(weights, key=lambda k: (weights[k], -methods.index(k)))
    if found is not None and not note:
        note = NOTE_NOISE_FLOOR
    return GapRecord(m, s, e, best, full_errors, weights, note, error), fill


def mates_misfit(src: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, mates: list[int], window: int
                 ) -> float:
    """How far (mm, mean) marker ``m`` strays from rigid with neighbours taken as rigid with it (steady mates
    from other segments) around gap ``[s, e)``: over the frames within ``window`` of it where all of them are
    measured, ``m`` carried rigidly with the neighbours from the such frame nearest the gap (least-squares fit of
    their positions there onto theirs in each frame) against where it was measured. The rigid fill's own error
    over the neighbourhood, not only on the few stretches hidden beside the gap: pelvis, neck and head markers
    standing in for a hidden chest fitted those stretches at 1.5 mm and the gap at 24 mm, the chest turning
    against them. 0 with fewer than three neighbours or ten such frames."""
    others = np.array([j for j in mates if j != m], dtype=int)
    if others.size < 3:
        return 0.0
    lo, hi = max(0, s - window), min(len(valid), e + window)
    rows = np.flatnonzero(valid[lo:hi, m] & valid[lo:hi][:, others].all(axis=1)) + lo
    if rows.size < 10:
        return 0.0
    ref_row = rows[np.argmin(np.minimum(np.abs(rows - (s - 1)), np.abs(rows - e)))]
    ref = src[ref_row, others]
    cur = src[rows][:, others]
    rot = kabsch(ref, cur)
    carried = rot @ (src[ref_row, m] - ref.mean(axis=0)) + cur.mean(axis=1)
    return float(norm3(carried - src[rows, m]).mean())


def distance_miss(src: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, cluster: list[int] | None,
                  fill: np.ndarray, window: int) -> float:
    """How far (mm, mean) a fill of gap ``[s, e)`` breaks its segment's shape where the shape is seen: in each
    frame of the gap where a cluster mate is measured, the filled position's distance to it against their usual
    distance (the median over ``window`` frames each side where both are measured). A position error is at least
    its distance error, so this is a lower bound on the fill's error from the gap's own frames, which the
    stretches beside the gap cannot give when the gap moves unlike them (a chest marker filled from the pelvis,
    neck and head across a 2 s occlusion: 2 mm on the stretches, 20 mm in the gap, while two of its mates were
    measured through half of it). 0 without a mate measured in the gap. The usual distance is read at most at
    ``WINDOW_SAMPLES`` evenly spaced frames of the window (:func:`~.fill_methods.sample_step`)."""
    if not cluster:
        return 0.0
    mates = np.array([j for j in cluster if j != m], dtype=int)
    shown = valid[s:e][:, mates]
    if not mates.size or not shown.any():
        return 0.0
    from gazepipe.stages.clean import kernels

    lo, hi = max(0, s - window), min(len(valid), e + window)
    d, both = kernels.distances(src, valid, valid[:, m], m, mates.astype(np.int64), lo, hi,
                                sample_step(hi - lo, WINDOW_SAMPLES))
    usual = np.where(both, d, np.nan).T                          # (frames, mates)
    ref = np.where(both.sum(axis=1) >= 10, _nanmedian(usual, axis=0), np.nan)
    dist = norm3(src[s:e][:, mates] - fill[:, None])
    miss = np.abs(dist - ref)[shown & np.isfinite(ref)]
    return float(miss.mean()) if miss.size else 0.0


#: gaps shorter than this (frames) keep the per-gap blend: over a few frames every method agrees (and may be
#: filled without an estimate when nothing beside them could be hidden)
_FRAMEWISE_MIN_FRAMES = 16
#: displacements below this (mm) count as this much in :func:`moving_gap_factor`: a still marker's noise
_MOVE_FLOOR_MM = 5.0


def moving_gap_factor(xyz_m: np.ndarray, valid_m: np.ndarray, s: int, e: int, wins: list[tuple[int, int]]
                      ) -> float:
    """How much further a marker travels across gap ``[s, e)`` than across its hidden validation stretches
    ``wins``: the distance between its measured samples either side of the gap over the largest of the same for
    its stretches (a stretch that travelled as far tested the fill on such motion), both floored at
    :data:`_MOVE_FLOOR_MM`, and at least 1 (1 at a take's edge or without a stretch). Hidden stretches next to a gap in which the body turns are still, and every method looks right on
    them (a neck marker filled across a gaze shift was estimated at 1.8 mm and was 23 mm off)."""
    n = xyz_m.shape[0]
    if s < 1 or e >= n or not (valid_m[s - 1] and valid_m[e]):
        return 1.0
    ends = [(a - 1, b) for a, b in wins if a >= 1 and b < n and valid_m[a - 1] and valid_m[b]]
    if not ends:
        return 1.0
    gap = float(np.linalg.norm(xyz_m[e] - xyz_m[s - 1]))
    moved = max(float(np.linalg.norm(xyz_m[b] - xyz_m[a])) for a, b in ends)
    return max(1.0, max(gap, _MOVE_FLOOR_MM) / max(moved, _MOVE_FLOOR_MM))


def _mates_through(valid: np.ndarray, cluster: list[int], m: int, s: int, e: int) -> bool:
    """Whether three of the marker's cluster mates are measured in every frame of the gap (a rigid fill then
    follows whatever the segment does)."""
    mates = [c for c in cluster if c != m]
    return len(mates) >= 3 and bool((valid[s:e][:, mates].sum(axis=1) >= 3).all())
NOTE_FRAMEWISE = "averaged frame by frame"


def _framewise_fill(xyz: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, preds: dict[str, np.ndarray],
                    errors: dict[str, float], methods: tuple[str, ...], st: Stretches, window: int,
                    step_limit: float) -> tuple[np.ndarray, float, dict[str, float]] | None:
    """The frame-by-frame average (:func:`gazepipe.stages.clean.framewise.average`) of gap ``[s, e)`` and its
    mean error on the hidden stretches, with its prior weights; None when it cannot be formed, cannot be
    validated on every hidden sample, or steps implausibly fast."""
    prior = blend_weights(errors, methods, top=len(methods))
    if len(prior) < 2 or any(k not in st.hidden for k in prior):
        return None
    links = framewise.linked_neighbours(xyz, valid, st.known, m, s, e, window)
    on_hidden = framewise.average(st.hidden, prior, st.frames, xyz, valid, links, st.cuts, vis_rows=st.vis_rows)
    if on_hidden is None or not np.isfinite(on_hidden).all():
        return None
    fill = framewise.average(preds, prior, np.arange(s, e), xyz, valid, links)
    if fill is None or not np.isfinite(fill).all():
        return None
    _, ok, _ = _plausible_fill(xyz[:, m], s, e, {"average": fill}, {"average": 1.0}, {}, ("average",),
                               step_limit)
    if ok is None:
        return None
    return fill, float(norm3(on_hidden - st.truth).mean()), prior


#: the trajectory-only methods, blind to a turn inside the gap that the samples beside it do not show
TRAJECTORY_METHODS = ("linear", "pchip")
#: samples (and seconds) beside a gap from which its edge velocities are estimated
_EDGE_MIN_SAMPLES = 3
_EDGE_WINDOW_S = 0.2


def edge_velocity_error(xyz_m: np.ndarray, s: int, e: int, preds: dict[str, np.ndarray],
                        weights: dict[str, float], window: int) -> float:
    """A lower bound (mm) on the error of the trajectory-only part of a fill of gap ``[s, e)``.

    Hiding samples beside a gap cannot see a turn inside it: a target moving straight on both sides validates a
    straight fill at noise level even when it turned in between. The velocities at the gap's edges (least-squares
    slopes over ``window`` measured samples on each side) do see it. The cubic Hermite curve that meets both edge
    positions with those velocities is the least the motion inside must bend; a linear or PCHIP member of the
    fill that strays from it by d mm on average adds its weight times d. Returns 0 when either side has fewer
    than ``_EDGE_MIN_SAMPLES`` measured samples in a row, or the fill has no trajectory-only member.
    """
    share = {k: w for k, w in weights.items() if k in TRAJECTORY_METHODS}
    n = xyz_m.shape[0]
    if not share or s < _EDGE_MIN_SAMPLES or n - e < _EDGE_MIN_SAMPLES:
        return 0.0
    before = xyz_m[max(0, s - window):s]
    after = xyz_m[e:e + window]
    ok_b = np.isfinite(before).all(axis=1)
    ok_a = np.isfinite(after).all(axis=1)
    # the run of measured samples that touches the gap on each side
    nb = len(ok_b) - (np.flatnonzero(~ok_b)[-1] + 1 if (~ok_b).any() else 0)
    na = int(np.argmin(ok_a)) if (~ok_a).any() else len(ok_a)
    if nb < _EDGE_MIN_SAMPLES or na < _EDGE_MIN_SAMPLES:
        return 0.0

    def line(seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.arange(len(seg), dtype=np.float64) - (len(seg) - 1) / 2.0
        slope = (t[:, None] * (seg - seg.mean(axis=0))).sum(axis=0) / (t * t).sum()
        return seg.mean(axis=0), slope

    mb, vb = line(before[len(before) - nb:])
    ma, va = line(after[:na])
    p0 = mb + vb * (nb - 1) / 2.0                      # the fitted line at frame s - 1
    p1 = ma - va * (na - 1) / 2.0                      # and at frame e
    span = float(e - s + 1)
    u = (np.arange(s, e, dtype=np.float64) - (s - 1)) / span
    h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
    h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
    bend = (h00[:, None] * p0 + h10[:, None] * vb * span + h01[:, None] * p1 + h11[:, None] * va * span)
    return float(sum(w * norm3(preds[k] - bend).mean() for k, w in share.items()))


def _two_mates_somewhere(valid: np.ndarray, cluster: list[int], m: int, s: int, e: int) -> bool:
    """Whether some frame of gap ``[s, e)`` has at most two of ``cluster``'s other markers measured."""
    mates = [j for j in cluster if j != m]
    return bool((valid[s:e][:, mates].sum(axis=1) <= 2).any())


def _twist_error(xyz: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, cluster: list[int],
                 rigid: np.ndarray, window: int) -> float:
    """How far (mm, mean) a rigid fill that rests on two mates in some frames could be off: two points leave the
    twist about their axis unseen (taken as none), which the samples hidden beside the gap cannot show when the
    segment only twists inside it. The same fill with the marker's steadiest neighbours added to its mates sees
    the twist; their disagreement is the error that fill cannot rule out (0 without such neighbours)."""
    extra = find_steady_mates(xyz, valid, m, s, e, window)
    if extra is None:
        return 0.0
    wider = [*cluster, *(j for j in extra if j not in cluster)]
    other = rigid_fill(xyz, valid, m, wider, valid[:, m], s, e)
    if other is None:
        return 0.0
    return float(norm3(other - rigid).mean())


@dataclass(frozen=True)
class ErrorLimits:
    """Fill error limits (mm) that vary along a few markers only: ``default_mm`` for every marker but those in
    ``by_marker``, which maps a marker's column to its (T,) limit per frame (NaN: none there). What a (T, M)
    array would say, in the memory of the few columns that differ."""

    default_mm: float
    by_marker: dict[int, np.ndarray]


def gap_limit(max_error_mm: float | np.ndarray | ErrorLimits, m: int, s: int, e: int) -> float:
    """The error limit (mm) of the gap [s, e) of marker ``m``: a scalar as is; from a (T, M) array or an
    :class:`ErrorLimits`, the smaller finite limit of the frames just before and just after the gap (+inf when
    neither has one)."""
    if isinstance(max_error_mm, ErrorLimits):
        if m not in max_error_mm.by_marker:
            return float(max_error_mm.default_mm)
        column = max_error_mm.by_marker[m]
    elif np.ndim(max_error_mm) == 0:
        return float(max_error_mm)
    else:
        column = np.asarray(max_error_mm)[:, m]
    edges = [column[i] for i in (s - 1, e) if 0 <= i < column.shape[0] and np.isfinite(column[i])]
    return float(min(edges)) if edges else float("inf")


def step_limits(xyz: np.ndarray, valid: np.ndarray, factor: float = _STEP_FACTOR,
                factor_any: float = _STEP_FACTOR_ANY) -> np.ndarray:
    """Largest plausible step (mm per frame) of each marker's filled samples, (M,): the larger of ``factor``
    times the marker's 99th-percentile step between consecutive measured frames and ``factor_any`` times the
    largest such percentile of any marker (so a marker seen only still may still be filled moving as fast as
    the others), and never more than the fastest step measured anywhere in the capture (:func:`fastest_step`):
    no fill moves faster than the capture was seen to move. Inf where nothing was measured twice in a row
    anywhere.

    The cap is the capture's, not the marker's own fastest step: a marker is often hidden while it moves fastest
    (a hand pushing a wheelchair rim, a foot in swing), and its own measured steps would refuse every fill of such
    a gap; the capture's fastest step is the most that any of its markers did, so a fill above it moves as
    nothing in the capture was seen to move (a linear fill across a marker that changed identity in the gap:
    42.7 mm per frame where the file's fastest measured step was 29.7 mm). ``valid`` should leave out the
    samples taken as spikes: a ghost's jump is not a speed the body reached."""
    from gazepipe.stages.clean import kernels

    n_m = valid.shape[1]
    if valid.shape[0] < 2:
        return np.full(n_m, np.inf)
    count, p99, top = kernels.step_statistics(np.asarray(xyz, dtype=np.float64), np.asarray(valid, dtype=np.bool_))
    if not (count >= 10).any():
        return np.full(n_m, np.inf)
    return np.fmin(np.fmax(factor * p99, factor_any * np.nanmax(p99)), top.max())


def fastest_step(xyz: np.ndarray, valid: np.ndarray) -> float:
    """The fastest step (mm per frame) between consecutive measured frames of any marker of ``xyz`` (T, M, 3),
    ``valid`` (T, M); 0 when nothing was measured twice in a row."""
    from gazepipe.stages.clean import kernels

    top = kernels.step_statistics(np.asarray(xyz, dtype=np.float64), np.asarray(valid, dtype=np.bool_))[2]
    return float(top.max()) if top.size else 0.0


def _plausible_fill(xyz_m: np.ndarray, s: int, e: int, preds: dict[str, np.ndarray], weights: dict[str, float],
                    errors: dict[str, float], methods: tuple[str, ...], limit: float
                    ) -> tuple[dict[str, float], np.ndarray | None, str]:
    """The fill of gap ``[s, e)`` of a marker (``xyz_m`` (T, 3), NaN in gaps) from ``weights``, or when one of
    its steps (into, across and out of the gap) exceeds ``limit`` mm, the first single method (by validation
    error, then ``methods`` order) whose steps do not. Returns ``(weights, fill or None, note)``."""
    lo, hi = max(s - 1, 0), min(e + 1, xyz_m.shape[0])

    def ok(fill: np.ndarray) -> bool:
        seg = np.concatenate([xyz_m[lo:s], fill, xyz_m[e:hi]])
        steps = norm3(seg[1:] - seg[:-1])
        return bool(np.all(np.isfinite(fill)) and not (steps > limit).any())

    best = max(weights, key=lambda k: (weights[k], -methods.index(k)))
    first = cast(np.ndarray, sum(w * preds[k] for k, w in weights.items())) if len(weights) > 1 else preds[best]
    if ok(first):
        return weights, first, ""
    err = {k: errors.get(k, np.nan) for k in preds}
    order = sorted(preds, key=lambda k: (err[k] if np.isfinite(err[k]) else np.inf, methods.index(k)))
    for k in order:
        if k != best or len(weights) > 1:
            if ok(preds[k]):
                return {k: 1.0}, preds[k], f"{best} fill implausibly fast; {k} used"
    return weights, None, REASON_IMPLAUSIBLE


#: seconds each side of a gap longer than ``max_gap_s`` over which its marker must be measured still for the gap
#: to be filled as still (:func:`still_gap`; SPEC §3.2 step 2), and the fewest measured samples there (at least
#: half of that side's frames too)
_STILL_SIDE_S = 0.5
_STILL_MIN_SAMPLES = 5


def _edge_lines(xyz: np.ndarray, valid: np.ndarray, s: int, e: int, side: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Least-squares lines through the measured samples of the ``side`` frames before gap ``[s, e)`` and of those
    after it, of each column of ``xyz`` (T, K, 3) mm, ``valid`` (T, K): ``(p0, p1, v0, v1)``, the lines' positions
    at frames ``s - 1`` and ``e`` (K, 3) and their velocities (K, 3) mm per frame; None where a side has fewer
    than ``max(_STILL_MIN_SAMPLES, side // 2)`` measured samples in some column, or misses the frame touching
    the gap."""
    n_t = valid.shape[0]
    if s < side or e + side > n_t or not (valid[s - 1].all() and valid[e].all()):
        return None
    out = []
    for a, b, at in ((s - side, s, s - 1), (e, e + side, e)):
        w = valid[a:b].astype(np.float64)                         # (side, K)
        n = w.sum(axis=0)
        if (n < max(_STILL_MIN_SAMPLES, side // 2)).any():
            return None
        t = np.arange(a, b, dtype=np.float64)[:, None]
        p = np.where(valid[a:b, :, None], xyz[a:b], 0.0)
        tm = (w * t).sum(axis=0) / n                                # (K,)
        pm = (w[..., None] * p).sum(axis=0) / n[:, None]            # (K, 3)
        dt = np.where(valid[a:b], t - tm, 0.0)
        v = (dt[..., None] * (p - pm)).sum(axis=0) / (dt * dt).sum(axis=0)[:, None]
        out.append((pm + v * (at - tm)[:, None], v))
    (p0, v0), (p1, v1) = out
    return p0, p1, v0, v1


def _straight(p0: np.ndarray, p1: np.ndarray, s: int, e: int) -> np.ndarray:
    """(e - s, K, 3): the straight lines from ``p0`` (K, 3) at frame ``s - 1`` to ``p1`` at frame ``e``."""
    u = (np.arange(s, e, dtype=np.float64) - (s - 1)) / (e - s + 1)
    return p0[None] + u[:, None, None] * (p1 - p0)[None]


def still_gap(src: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, step_limit: float,
              max_error: float | None, cfg: _GapSettings) -> tuple[GapRecord, np.ndarray | None]:
    """A gap ``[s, e)`` longer than ``max_gap_s`` (frames relative to the neighbourhood ``src`` (n, M, 3) mm,
    ``valid`` (n, M)), filled when its marker is still: a rest is not motion (SPEC §3.2 step 2).

    The marker must be measured still on both sides: the least-squares line through its measured samples of
    the ``cfg.still_side`` frames (0.5 s) on each side moves at most ``cfg.still_speed``. The fill is the
    straight line between those two lines' positions at the gap's edges: every measured sample of the sides
    counts, so the fill carries a fraction of one sample's noise. Its error is estimated on the gap's own
    frames, not assumed: up to three markers measured through the gap and both sides that keep their distance
    to this one (the steadiest neighbours, :func:`~gazepipe.stages.clean.fill_methods.distance_sd` under 20 mm
    over 2 s each side; the nearest of them) are filled the same way and compared with their measured samples
    there; their mean error (their own measurement noise, the body's sway, a turn away and back) is the
    estimate, at least half the distance between the marker's two edge positions (the most a straight line can
    miss a marker that moved from one to the other at an unknown moment). Without such a marker there is no
    estimate and the gap stays (:data:`REASON_NO_ESTIMATE`); above ``max_error`` it stays too
    (:data:`REASON_UNCERTAIN`)."""
    errors = {k: float("nan") for k in cfg.methods}
    side = cfg.still_side
    speed = cfg.still_speed
    own = (None if "linear" not in cfg.methods or speed is None
           else _edge_lines(src[:, m:m + 1], valid[:, m:m + 1], s, e, side))
    if own is None or speed is None or max(float(np.linalg.norm(own[2])), float(np.linalg.norm(own[3]))) > speed:
        return GapRecord(m, s, e, "unfilled", errors, reason=REASON_TOO_LONG), None
    fill = _straight(own[0], own[1], s, e)[:, 0]
    donor = _still_donor_error(src, valid, m, s, e, side, cfg.mates_window)
    error = max(donor, 0.5 * float(np.linalg.norm(own[1] - own[0])))      # NaN stays NaN
    errors["linear"] = error
    if not np.isfinite(error):
        return GapRecord(m, s, e, "unfilled", errors, reason=REASON_NO_ESTIMATE), None
    if max_error is not None and error > max_error:
        return GapRecord(m, s, e, "unfilled", errors, {"linear": 1.0}, REASON_UNCERTAIN, error), None
    _, kept, note = _plausible_fill(src[:, m], s, e, {"linear": fill}, {"linear": 1.0}, errors, cfg.methods,
                                    step_limit)
    if kept is None:
        return GapRecord(m, s, e, "unfilled", errors, reason=note), None
    return GapRecord(m, s, e, "linear", errors, {"linear": 1.0}, NOTE_STILL, error), kept


#: markers whose straight fill across a still gap estimates its error (:func:`still_gap`)
_STILL_DONORS = 3


def _still_donor_error(src: np.ndarray, valid: np.ndarray, m: int, s: int, e: int, side: int, window: int
                       ) -> float:
    """Mean error (mm) of :func:`still_gap`'s straight fill on up to ``_STILL_DONORS`` markers measured through
    gap ``[s, e)`` and the ``side`` frames on each side that keep their distance to marker ``m`` (standard
    deviation under ``MATES_MAX_STD_MM`` over ``window`` frames each side), the nearest first; NaN with none."""
    cand = np.flatnonzero(valid[s - side:e + side].all(axis=0))
    cand = cand[cand != m]
    if cand.size:
        cand = cand[distance_stats(src, valid, m, cand, s, e, window)[1] < MATES_MAX_STD_MM]
    if not cand.size:
        return float("nan")
    near = norm3(src[[s - 1, e]][:, cand] - src[[s - 1, e]][:, [m]]).mean(axis=0)
    donors = cand[np.argsort(near, kind="stable")[:_STILL_DONORS]]
    lines = _edge_lines(src[:, donors], valid[:, donors], s, e, side)
    if lines is None:
        return float("nan")
    miss = norm3(_straight(lines[0], lines[1], s, e) - src[s:e][:, donors])
    return float(miss.mean())


#: labels of unlabeled trajectories, as capture programs write them (after a ``Subject:`` prefix, if any): Vicon
#: Nexus/Shogun ``*12``; ``Unlabeled 3``, ``Unlabeled:1001``, ``unlabelled_7``, ``Unidentified 12``, ``Unnamed4``
#: (Motive, Qualisys and other exporters); a point without a label, which the C3D reader names ``_unnamed``
#: (``_unnamed~2``, ...)
UNLABELED_PATTERN = re.compile(r"^(?:\*\d+|(?:unlabell?ed|unidentified|unnamed)(?:[\s_:#.-]*\d+)?|_unnamed(?:~\d+)?)$",
                               re.IGNORECASE)


def is_unlabeled(label: str) -> bool:
    """Whether ``label`` names an unlabeled trajectory (:data:`UNLABELED_PATTERN`, on the whole label or its part
    after the last ``:``)."""
    name = label.strip()
    return bool(UNLABELED_PATTERN.match(name) or UNLABELED_PATTERN.match(name.rsplit(":", 1)[-1].strip()))


def unlabeled_markers(labels: Sequence[str]) -> list[int]:
    """Indices of the unlabeled trajectories among ``labels`` (:data:`UNLABELED_PATTERN`, matched on the whole
    label and on its part after the last ``:``). Such a trajectory is whatever the labeller could not name: a
    marker's fragments between identity changes, a ghost, a stray reflection; a fill between its scattered
    samples joins points of different markers, so it is left alone unless asked."""
    return [i for i, lab in enumerate(labels) if is_unlabeled(lab)]


def find_rigid_clusters(xyz: np.ndarray, valid: np.ndarray, *, max_rel_std: float = 0.02,
                        noise_std_mm: float = 1.5, min_common: int = 10,
                        min_dist_mm: float = 1.0) -> list[list[int]]:
    """Groups of markers whose mutual distances stay stable.

    A pair is stable when, over the frames where both are measured (at least ``min_common``), the standard
    deviation of their distance is at most ``max_rel_std`` times its mean (or ``noise_std_mm``, whichever is
    larger, so that close pairs are not split by measurement noise alone), and the mean is at least
    ``min_dist_mm`` (coincident duplicates carry no shape). Clusters are grown greedily as cliques of the
    stable-pair graph, starting from the most stable pair; each marker joins at most one cluster, and clusters
    need at least three markers.

    Returns clusters as sorted lists of marker indices, ordered by their first marker.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool) & np.isfinite(xyz).all(axis=2)
    n_m = valid.shape[1]
    rel = np.full((n_m, n_m), np.inf)
    x0 = np.where(valid[..., None], xyz, 0.0)
    for i in range(n_m - 1):
        both = valid[:, i:i + 1] & valid[:, i + 1:]
        cnt = both.sum(axis=0)
        d = np.linalg.norm(x0[:, i + 1:] - x0[:, i:i + 1], axis=2)
        d = np.where(both, d, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = d.sum(axis=0) / cnt
            var = (np.where(both, (d - mean) ** 2, 0.0)).sum(axis=0) / cnt
            r = np.sqrt(var) / np.maximum(mean, noise_std_mm / max_rel_std)
        r[(cnt < min_common) | ~(mean >= min_dist_mm) | ~np.isfinite(r)] = np.inf
        rel[i, i + 1:] = r
        rel[i + 1:, i] = r
    stable = rel <= max_rel_std
    used = np.zeros(n_m, dtype=bool)
    clusters: list[list[int]] = []
    order = np.argsort(rel[np.triu_indices(n_m, 1)], kind="stable")
    iu, ju = np.triu_indices(n_m, 1)
    for k in order:
        i, j = int(iu[k]), int(ju[k])
        if not stable[i, j]:
            break
        if used[i] or used[j]:
            continue
        members = [i, j]
        cand = np.flatnonzero(stable[i] & stable[j] & ~used)
        cand = cand[(cand != i) & (cand != j)]
        # add the candidate most stable with the current members, while it is stable with all of them
        while cand.size:
            score = rel[np.ix_(cand, members)].max(axis=1)
            best = int(cand[np.argmin(score)])
            if not np.isfinite(score.min()) or not stable[best, members].all():
                break
            members.append(best)
            cand = cand[(cand != best) & stable[best, cand]]
        if len(members) >= 3:
            used[members] = True
            clusters.append(sorted(members))
    return sorted(clusters)
