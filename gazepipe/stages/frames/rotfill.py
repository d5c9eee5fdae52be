"""Filling a segment's rotation across a gap of its markers, and checking fits to gap-filled markers (SPEC §3.3).

A segment whose markers stay unfilled has its parent-relative rotation filled across the gap (slerp between the
rotations on either side, or a model of its neighbours' rotations), and where some of its markers are measured in
the gap the fill is turned to meet them (:func:`constrain`). Each way of filling is tried on stretches of the
gap's length hidden beside it and on stretches that move at least as much as it (judged from what is known in the
gap: the segment's turn across it and how far its neighbours stray from their own interpolation inside it); the
gap is filled when the estimate is at most the limit. A rotation fitted to gap-filled markers is checked the same
way: where the fill across its stretch and the fit disagree by more than both their estimates, one of them is
wrong and nothing says which, so the stretch becomes a gap. Rotations are (N, S, 3, 3) matrices in the character
frame, NaN where unknown; frames are rows of the take.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gazepipe.stages.clean.filters import true_runs


@dataclass(frozen=True)
class SegmentMarkers:
    """A segment's measured markers, which a fill across a gap of its rotation is turned to meet.

    Attributes
    ----------
    body : (K, 3) mm, the markers' neutral positions about their centroid in the segment's calibrated axes
        (where the segment's rotation G in the character frame takes them: G·body).
    pos : (N, K, 3) mm, each marker's position in character axes (lab positions turned by the character frame,
        no origin: only differences are used), NaN where it is not measured.
    """

    body: np.ndarray
    pos: np.ndarray


#: known frames on each side a rotation gap is interpolated from (and that a hidden stretch keeps)
_ROT_ANCHORS = 1
#: training frames the neighbour model needs at least, and its ridge weight (a share of the features' energy)
_MODEL_MIN_FRAMES = 30
_MODEL_RIDGE = 1e-3
#: hold-out stretches that move like the gap: at most this many, beside the two next to the gap
_MATCHED_STRETCHES = 3
#: a stretch moves like a gap when it moves at least this share of the gap's amount (the amounts carry noise)
_LIKE_SHARE = 0.8
#: a stretch moves at least this much, deg (the rotations' own noise): a still stretch is not taken as frozen
_MOTION_FLOOR_DEG = 1.0
#: weight of the fill against the measured markers in :func:`constrain`, as a share of the markers' spread
_PRIOR_WEIGHT = 1e-3
#: a rotation fitted to gap-filled markers is checked against the fill across it where the fills may turn it by
#: more than this (deg, :func:`gazepipe.stages.frames.stage.fit_uncertainty_deg`)
CHECK_FIT_DEG = 1.0


def _slerp_across(local, start: int, stop: int):
    """Rotations (stop − start) filling [start, stop) by slerp between the known rotations just before and just
    after (``local``: a rotation stack over every frame, :class:`gazepipe.stages.frames.kernels.Rot`). A cubic spline through two frames on each side
    was measured too: its edge velocities carry the rotations' noise into the gap (0.4° of noise: 1.2° mean
    error over 12 frames at 120 Hz and 4.7° over 30, against slerp's 0.3° and 0.3°)."""
    from gazepipe.stages.frames.kernels import Rot

    # scipy's Slerp between two rotations, written out (the same operations in the same order, so the same bits)
    # without building a Slerp object each time: this runs for every stretch a fill is judged on
    pair = local[[start - 1, stop]]
    first = pair[:1]
    rotvec = (first.inv() * pair[1:]).as_rotvec()
    alpha = (np.arange(start, stop, dtype=float) - float(start - 1)) / float(stop - (start - 1))
    ind = np.zeros(alpha.shape[0], dtype=np.intp)
    return first[ind] * Rot.from_rotvec(rotvec[ind] * alpha[:, None])


def _model_across(local, span, usable: np.ndarray, start: int, stop: int, window: int):
    """Rotations (stop − start) filling [start, stop) of a segment from the rotation its neighbours span across
    it (``span``: its parent's rotation to its child's, which moves with it; a rotation stack): a ridge
    regression of the segment's parent-relative rotation on the span's (as rotation vectors about their means)
    over the ``usable`` frames within ``window`` of the gap, corrected to meet the known rotations just before
    and just after (the correction interpolated across). None with too few training frames.

    Not used at a take's start or end: corrected from one side only, it was measured up to 7° off where the
    hold-out beside the gap said 1.4° (a gaze shift's first frames, whose motion the frames after do not show)."""
    from gazepipe.stages.frames.kernels import Rot

    lo, hi = max(0, start - window), min(len(usable), stop + window)
    train = np.flatnonzero(usable[lo:hi]) + lo
    train = train[(train < start - 1) | (train > stop)]
    if len(train) < _MODEL_MIN_FRAMES:
        return None
    ref, ref_s = local[train].mean(), span[train].mean()
    x = np.column_stack([(ref_s.inv() * span[train]).as_rotvec(), np.ones(len(train))])
    y = (ref.inv() * local[train]).as_rotvec()
    gram = x.T @ x
    w = np.linalg.solve(gram + _MODEL_RIDGE * np.trace(gram) / 4.0 * np.eye(4), x.T @ y)
    frames = np.arange(start - 1, stop + 1)
    xs = np.column_stack([(ref_s.inv() * span[frames]).as_rotvec(), np.ones(len(frames))])
    pred = ref * Rot.from_rotvec(xs @ w)
    miss0 = (pred[0].inv() * local[start - 1]).as_rotvec()
    miss1 = (pred[-1].inv() * local[stop]).as_rotvec()
    f = ((np.arange(start, stop) - (start - 1)) / (stop - start + 1))[:, None]
    return pred[1:-1] * Rot.from_rotvec((1.0 - f) * miss0 + f * miss1)


def constrain(glob: np.ndarray, body: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Rotations (F, 3, 3) closest to ``glob`` (F, 3, 3) that take the markers' ``body`` positions (k, 3), k ≥ 2,
    to their measured ``pos`` (F, k, 3) as well as a rotation can: Wahba's problem on the markers' positions
    about their centroid, with the fill as a weak prior (weight :data:`_PRIOR_WEIGHT` of the markers' spread),
    solved by Horn's closed form (:func:`gazepipe.stages.frames.kernels.wahba_rotations`).
    Two markers fix the rotation but for a turn about the line through them, which the fill keeps."""
    from gazepipe.stages.frames.kernels import wahba_rotations

    c = body - body.mean(axis=0)
    b = pos - pos.mean(axis=1, keepdims=True)
    prior = _PRIOR_WEIGHT * float((c * c).sum())
    return wahba_rotations(np.einsum("fki,kj->fij", b, c) + prior * glob)


@dataclass
class _Segment:
    """One segment's view for filling: parent-relative rotations and what else is known
    (:class:`~gazepipe.stages.frames.kernels.Rot` stacks, identity where unknown)."""

    local: Any
    trust: np.ndarray                 # frames whose rotation may be hidden to test a fill (or anchor a check)
    anchor: np.ndarray                # frames whose rotation may anchor a fill: the trusted ones and checked fits
    unc: np.ndarray                   # how far the fills of its markers may turn each rotation (deg)
    noise: float                      # the mean angle (deg) of the noise of its trusted rotations
    parent: Any | None                # the parent's rotation in the character frame (None for a root)
    span: Any | None = None           # the parent's rotation to the first child's (the neighbour model's input)
    span_ok: np.ndarray | None = None
    nbs: list = field(default_factory=list)      # (rotation in the character frame, known) of the neighbours
    markers: SegmentMarkers | None = None


def _segment_view(gmat: np.ndarray, ok_rot: np.ndarray, parents: np.ndarray, has_char: np.ndarray, j: int,
                  unc: np.ndarray, markers: SegmentMarkers | None) -> _Segment:
    """The :class:`_Segment` of segment ``j``; ``unc`` (N,) how far the fills of its markers may turn each of its
    rotations (deg): those above :data:`CHECK_FIT_DEG` are not trusted."""
    from gazepipe.stages.frames.kernels import Rot

    p = int(parents[j])
    base = has_char & (ok_rot[:, p] if p >= 0 else True)
    known = ok_rot[:, j] & base

    def rot(mats: np.ndarray, ok: np.ndarray):
        return Rot.from_matrix(np.where(ok[:, None, None], mats, np.eye(3)))

    def rel(mats: np.ndarray, ok: np.ndarray):       # (rows not ``ok`` become the identity in ``rot``)
        return rot(mats if p < 0 else np.swapaxes(gmat[:, p], 1, 2) @ mats, ok)

    local = rel(gmat[:, j], known)
    trust = known & (unc <= CHECK_FIT_DEG)
    view = _Segment(local=local, trust=trust, anchor=known, unc=unc, noise=_noise_deg(local, trust),
                    parent=rot(gmat[:, p], base) if p >= 0 else None, markers=markers)
    children = np.flatnonzero(np.asarray(parents) == j)
    if len(children):
        c = int(children[0])
        view.span_ok = base & ok_rot[:, c]
        view.span = rel(gmat[:, c], view.span_ok)
    # the neighbours whose motion says how a gap moves: the parent and the first child, in the character frame
    if p >= 0:                                   # the parent's known frames are ``base``: its stack is built once
        view.nbs.append((view.parent, base))
    if len(children):
        ok = has_char & ok_rot[:, int(children[0])]
        view.nbs.append((rot(gmat[:, int(children[0])], ok), ok))
    return view


#: fewest frames that give a segment's rotation noise (:func:`_noise_deg`)
_NOISE_MIN_FRAMES = 30


def _noise_deg(local, ok: np.ndarray) -> float:
    """The mean angle (deg) of the noise of a segment's rotations ``local`` on the frames ``ok``: how far each
    strays from the midpoint of the two beside it (the median, over frames with both neighbours ``ok``), over
    √1.5 (the stray of independent noises n_t − (n_t−1 + n_t+1)/2); 0 with too few frames. The motion adds to
    the strays at a low frame rate, and the median keeps the quiet frames' noise."""
    from gazepipe.stages.frames.kernels import Rot

    t = np.flatnonzero(ok[1:-1] & ok[:-2] & ok[2:]) + 1
    if len(t) < _NOISE_MIN_FRAMES:
        return 0.0
    half = Rot.from_rotvec(0.5 * (local[t - 1].inv() * local[t + 1]).as_rotvec())
    stray = np.degrees(((local[t - 1] * half).inv() * local[t]).magnitude())
    return float(np.median(stray) / np.sqrt(1.5))


def _gap_patterns(view: _Segment, lo: int, hi: int) -> np.ndarray | None:
    """Which of the segment's markers are measured on each frame of [lo, hi) (hi − lo, K), when at least two are
    on some frame: what a fill across the gap can be turned to meet, frame by frame."""
    if view.markers is None:
        return None
    seen = np.isfinite(view.markers.pos[lo:hi]).all(axis=2)
    return seen if (seen.sum(axis=1) >= 2).any() else None


def _constrained(view: _Segment, fill, lo: int, hi: int, patterns: np.ndarray):
    """``fill`` (parent-relative rotations over [lo, hi)) turned on each frame to meet the markers that are
    measured there among those ``patterns`` (hi − lo, K) allows (a gap's own, laid over a stretch hidden to test
    it: the stretch shows what the gap's markers would); None when no frame has two."""
    from gazepipe.stages.frames.kernels import Rot

    assert view.markers is not None
    pos = view.markers.pos[lo:hi]
    use = patterns & np.isfinite(pos).all(axis=2)
    two = use.sum(axis=1) >= 2
    if not two.any():
        return None
    glob = (fill if view.parent is None else view.parent[lo:hi] * fill).as_matrix()
    for pat in np.unique(use[two], axis=0):
        rows = two & (use == pat).all(axis=1)
        glob[rows] = constrain(glob[rows], view.markers.body[pat], pos[rows][:, pat])
    out = Rot.from_matrix(glob)
    return out if view.parent is None else view.parent[lo:hi].inv() * out


def _candidates(view: _Segment, start: int, stop: int, window: int, patterns: np.ndarray | None) -> dict:
    """Each way of filling [start, stop) that applies: slerp, the neighbour model where the span is known from the
    frame before to the frame after, and each turned to meet the markers measured there among ``patterns``
    (:func:`_constrained`)."""
    out = {"slerp": _slerp_across(view.local, start, stop)}
    if view.span is not None and view.span_ok is not None and view.span_ok[start - 1:stop + 1].all():
        model = _model_across(view.local, view.span, view.trust & view.span_ok, start, stop, window)
        if model is not None:
            out["model"] = model
    if patterns is not None:
        for name in list(out):
            turned = _constrained(view, out[name], start, stop, patterns)
            if turned is not None:
                out[f"{name}+markers"] = turned
    return out


def _off_slerp_deg(nb, lo: int, hi: int) -> float:
    """How far (deg, the largest over [lo, hi)) a rotation stack ``nb`` strays from the slerp between its
    rotations at lo − 1 and hi: the motion inside a stretch that interpolation across it cannot see."""
    return float(np.degrees((_slerp_across(nb, lo, hi) * nb[lo:hi].inv()).magnitude()).max())


def _motion_deg(view: _Segment, lo: int, hi: int) -> float:
    """How much a stretch [lo, hi) moves, deg: the largest of the segment's own turn across it (its rotations at
    lo − 1 and hi, known on both sides of a gap) and how far each neighbour (parent, first child; where known
    through the stretch) strays from its own interpolation inside it (:func:`_off_slerp_deg`)."""
    own = float(np.degrees((view.local[lo - 1].inv() * view.local[hi]).magnitude()))
    return max([own] + [_off_slerp_deg(nb, lo, hi) for nb, ok in view.nbs if ok[lo - 1:hi + 1].all()])


def _off_slerp_many(nb, starts: np.ndarray, length: int) -> np.ndarray:
    """:func:`_off_slerp_deg` of the stretches [lo, lo + length) for every ``lo`` in ``starts`` at once (the same
    operations on each rotation, so the same numbers as one stretch at a time)."""
    from gazepipe.stages.frames.kernels import Rot

    first, last = nb[starts - 1], nb[starts + length]
    rotvec = (first.inv() * last).as_rotvec()
    alpha = np.arange(1, length + 1, dtype=float) / float(length + 1)
    row = np.repeat(np.arange(starts.size), length)
    inside = (starts[:, None] + np.arange(length)).ravel()
    interp = first[row] * Rot.from_rotvec(rotvec[row] * np.tile(alpha, starts.size)[:, None])
    off = np.degrees((interp * nb[inside].inv()).magnitude()).reshape(starts.size, length)
    return off.max(axis=1)


def _motions_deg(view: _Segment, starts: np.ndarray, length: int) -> np.ndarray:
    """:func:`_motion_deg` of the stretches [lo, lo + length) for every ``lo`` in ``starts``, vectorised over the
    stretches (a gap is judged on dozens of them)."""
    own = np.degrees((view.local[starts - 1].inv() * view.local[starts + length]).magnitude())
    out = own.astype(float)
    for nb, ok in view.nbs:
        known = np.concatenate([[0], np.cumsum(~np.asarray(ok, dtype=bool))])
        whole = known[starts + length + 1] - known[starts - 1] == 0     # known from lo - 1 through lo + length
        if whole.any():
            out[whole] = np.maximum(out[whole], _off_slerp_many(nb, starts[whole], length))
    return out


def _holdouts(view: _Segment, s: int, e: int, window: int, a: int) -> tuple[list[int], list[float], float, int]:
    """Where to hide stretches of the gap's length to estimate a fill's error, with how much each moves.

    The two stretches next to the gap, and up to :data:`_MATCHED_STRETCHES` within ``window`` frames that move
    at least as much as the gap (:func:`_motion_deg`; the nearest such amounts first). Returns the stretches'
    first frames (those beside the gap first), their motion and the gap's (deg), and how many are beside it."""
    ok = view.trust
    n, length = len(ok), e - s
    usable = [int(lo) for lo in np.arange(max(a + 1, s - window), min(n - length - a - 1, e + window) + 1,
                                          max(1, length // 4))       # every quarter of the gap's length
              if (lo + length + a <= s - a or lo - a >= e + a) and ok[lo - a:lo + length + a].all()]
    beside = [lo for lo in (s - a - length, e + a)
              if lo - a >= 0 and lo + length + a <= n and ok[lo - a:lo + length + a].all()]
    gap = _motion_deg(view, s, e)
    starts = np.array(sorted({*usable, *beside}), dtype=np.int64)
    moves = dict(zip(starts.tolist(), _motions_deg(view, starts, length).tolist(), strict=True)) if starts.size else {}
    like = sorted((abs(moves[lo] - gap), lo) for lo in usable if moves[lo] >= _LIKE_SHARE * gap and lo not in beside)
    picked = beside + [lo for _, lo in like[:_MATCHED_STRETCHES]]
    return picked, [moves[lo] for lo in picked], gap, len(beside)


#: a stretch that moves more than the gap has its miss scaled down by at most this factor
_MAX_SCALE_DOWN = 2.0


def _estimate(errors: list[float], amounts: list[float], gap: float) -> float:
    """A fill's estimated error from its mean misses on the hold-out stretches (deg) and how much each stretch
    and the gap move (deg, :func:`_motion_deg`): the worst miss, each scaled by how much more (or less) the gap
    moves than its stretch (a still stretch beside a gap in which the head turns says little of it; one that
    turns twice as far as the gap misses about twice as much), the motion floored at :data:`_MOTION_FLOOR_DEG`
    and no miss scaled down by more than :data:`_MAX_SCALE_DOWN`."""
    g = max(gap, _MOTION_FLOOR_DEG)
    return max(err * max(1.0 / _MAX_SCALE_DOWN, g / max(m, _MOTION_FLOOR_DEG))
               for err, m in zip(errors, amounts, strict=True))


def _best_fill(view: _Segment, s: int, e: int, window: int) -> tuple[str | None, float | None, Any | None]:
    """The surest way to fill [s, e) (:func:`_candidates`), its estimated error (deg) and the fill, or Nones
    when no way could be tried on the stretches beside the gap. The estimate adds half the mean uncertainty of
    the two rotations it is anchored on (a fit to gap-filled markers: its error fades across the fill)."""
    a = _ROT_ANCHORS
    patterns = _gap_patterns(view, s, e)
    stretches, amounts, gap_moves, n_beside = _holdouts(view, s, e, window, a)
    errs: dict[str, dict[int, float]] = {}            # method -> stretch index -> mean miss (deg)
    for i, lo in enumerate(stretches):
        hi = lo + (e - s)
        for name, guess in _candidates(view, lo, hi, window, patterns).items():
            miss = float(np.degrees((guess * view.local[lo:hi].inv()).magnitude()).mean())
            # the hidden rotations carry their own noise: the fill's error is the miss without it
            errs.setdefault(name, {})[i] = float(np.sqrt(max(miss ** 2 - view.noise ** 2, 0.0)))
    # a method is scored when it was tried beside the gap; the stretches further off where it could not be tried
    # (the neighbour model needs its child there, a turn to the markers those markers) count for the others only
    scored = {k: _estimate([v[i] for i in sorted(v)], [amounts[i] for i in sorted(v)], gap_moves)
              for k, v in errs.items() if all(i in v for i in range(n_beside))}
    at_gap = _candidates(view, s, e, window, patterns)
    scored = {k: v for k, v in scored.items() if k in at_gap}
    if not scored:
        return None, None, None
    best = min(scored, key=lambda k: (scored[k], len(k), k))   # on a tie the simpler way
    anchors = float(view.unc[s - 1] + view.unc[e]) / 4.0
    return best, scored[best] + anchors, at_gap[best]


def _anchored(ok: np.ndarray, s: int, e: int) -> bool:
    """Whether [s, e) has :data:`_ROT_ANCHORS` frames of ``ok`` on each side to fill from."""
    a, n = _ROT_ANCHORS, len(ok)
    return s >= a and e + a <= n and bool(ok[s - a:s].all()) and bool(ok[e:e + a].all())


#: a fit and the fill across its stretch disagree when their mean angle is more than this many times the two
#: uncertainties combined (the fits' RMS and the fill's estimate, in quadrature)
DISAGREE_SIGMAS = 2.0


def _check_fits(view: _Segment, window: int) -> tuple[np.ndarray, list[tuple[np.ndarray, Any]]]:
    """Rotations fitted to gap-filled markers that the fills may turn by more than :data:`CHECK_FIT_DEG` (the
    known frames ``view`` does not trust), weighed against the fill across their stretch (a run of frames not
    trusted between trusted ones; one that cannot be filled across, at a take's end or with no way tried, is
    left as it is).

    Where fit and fill disagree (their mean angle over the stretch's fits is more than :data:`DISAGREE_SIGMAS`
    times the fits' RMS uncertainty, the fill's estimate and the rotations' noise combined), one of them is wrong
    and nothing says which: those fits are refuted (returned True, to become a gap of the segment's markers). Where they agree,
    each fit is replaced by the mean of the two weighted by their inverse squared uncertainties (returned per
    run as its frames and their parent-relative rotations): two independent estimates of the rotation, surer
    together.
    """
    from gazepipe.stages.frames.kernels import Rot

    out = np.zeros(len(view.trust), dtype=bool)
    blended: list[tuple[np.ndarray, Any]] = []
    suspect = view.anchor & ~view.trust
    for s, e in true_runs(~view.trust):
        if not suspect[s:e].any() or not _anchored(view.trust, s, e):
            continue
        _, error, fill = _best_fill(view, s, e, window)
        if error is None or fill is None:
            continue
        rows = np.flatnonzero(suspect[s:e])
        unc = np.maximum(view.unc[s + rows], 1e-6)
        diff = (view.local[s + rows].inv() * fill[rows]).as_rotvec()      # fit → fill, axes of the fit
        both = float(np.sqrt(np.mean(unc ** 2) + max(error, 1e-6) ** 2 + view.noise ** 2))
        if np.degrees(np.linalg.norm(diff, axis=1)).mean() > DISAGREE_SIGMAS * both:
            out[s + rows] = True
            continue
        share = (1.0 / max(error, 1e-6) ** 2) / (1.0 / unc ** 2 + 1.0 / max(error, 1e-6) ** 2)
        blended.append((s + rows, view.local[s + rows] * Rot.from_rotvec(share[:, None] * diff)))
    return out, blended


def fill_rotation_gaps(gmat: np.ndarray, parents: np.ndarray, has_char: np.ndarray, max_error_deg: float,
                       window: int = 300, *, markers: list[SegmentMarkers | None] | None = None,
                       fit_unc: np.ndarray | None = None) -> tuple[np.ndarray, list[dict], np.ndarray]:
    """Fill, in place, each segment's rotations (``gmat`` (N, S, 3, 3), character frame, NaN where its markers
    stay unfilled) across gaps where the character frame and the parent's rotation exist: the parent-relative
    rotation is interpolated by :func:`_slerp_across`, or predicted from its neighbours by :func:`_model_across`
    (where its first child is known through the gap), each also turned to meet the segment's markers measured
    throughout the gap (``markers``, :func:`constrain`), and composed with the parent's (segments in chain order,
    so a parent filled first carries its children). Each candidate is tried across stretches of the gap's length
    hidden just before and after it, and across stretches that move at least as much as the gap
    (:func:`_holdouts`, :func:`_motion_deg`); a candidate's estimate is its worst mean miss on those stretches,
    the hidden rotations' own noise taken out, each scaled by how much more the gap moves than its stretch
    (:func:`_estimate`: the stretches beside a gap in which the head turns are still, and slerp looks perfect
    there). The candidate with the smallest estimate fills the gap when that is at most
    ``max_error_deg``; with no stretch to hide the gap stays open. ``window``: frames each side of a gap the
    neighbour model learns from and the matched stretches are looked for in.

    ``fit_unc`` (N, S): how far the fills of a rotation's markers may turn it (deg; 0 where every marker is
    measured). Rotations it puts above :data:`CHECK_FIT_DEG` do not test a fill, and are weighed against the
    fill across their stretch (:func:`_check_fits`): where the two disagree they are a gap too (set NaN first),
    where they agree they become the two's weighted mean.

    Returns the (N, S) mask of filled rotations, one record per gap (segment, start, stop, method, estimated
    error in degrees, filled) and the (N, S) mask of fits refuted.
    """
    n, ns = gmat.shape[:2]
    filled = np.zeros((n, ns), dtype=bool)
    refuted = np.zeros((n, ns), dtype=bool)
    records: list[dict] = []
    ok_rot = np.isfinite(gmat).all(axis=(2, 3))
    for j in range(ns):
        seg_markers = markers[j] if markers is not None else None
        unc = np.zeros(n) if fit_unc is None else np.nan_to_num(fit_unc[:, j])
        view = _segment_view(gmat, ok_rot, parents, has_char, j, unc, seg_markers)
        refuted[:, j], blended = _check_fits(view, window)
        for rows, mixed in blended:
            mats = mixed.as_matrix()
            gmat[rows, j] = mats if parents[j] < 0 else gmat[rows, int(parents[j])] @ mats
        if refuted[:, j].any():
            gmat[refuted[:, j], j] = np.nan
            ok_rot[refuted[:, j], j] = False
            view.anchor = view.anchor & ~refuted[:, j]
        p = int(parents[j])
        missing = has_char & (ok_rot[:, p] if p >= 0 else True) & ~ok_rot[:, j]
        for s, e in true_runs(missing):
            if not _anchored(view.anchor, s, e):
                records.append({"segment": j, "start": s, "stop": e, "method": None, "error_deg": None,
                                "filled": False})
                continue
            best, error, fill = _best_fill(view, s, e, window)
            ok = fill is not None and error is not None and error <= max_error_deg
            records.append({"segment": j, "start": s, "stop": e, "method": best, "error_deg": error, "filled": ok})
            if fill is None or not ok:
                continue
            mats = fill.as_matrix()
            gmat[s:e, j] = mats if p < 0 else gmat[s:e, p] @ mats
            ok_rot[s:e, j] = True
            filled[s:e, j] = True
    return filled, records, refuted
