"""Label swaps (SPEC §3.2 step 1): stretches where the auto-labeller gave two markers each other's names.

Every marker the table carries is judged, listed in a markerset segment or not (:func:`judged_columns`: all but
the target and the clapper). A marker's *references* are the markers whose distance to it varies least over the
take: its rigid mates first, then markers of neighbouring segments; a marker rigid with too few others (a
shoulder or an elbow, on no segment) takes its steadiest distances whatever their spread, each judged within its
own spread, so that a 340 mm exchange stands out while a few centimetres of shrugging do not
(:func:`steady_references`). A sample's *misfit* is the largest, over its references measured in that frame, of
how far its distance to each is from that distance's median, in that distance's own spread (:func:`_misfit`). A
sample is *suspect* where its misfit is above the tolerance (6 spreads, each at least 1 mm). A suspect sample of
marker ``a`` is explained by a swap with ``b`` when it fits ``b``'s references within ``b``'s tolerance, something
that vouches for its own place tells ``b``'s place from ``a``'s there (a reference the sample fits as ``b`` and
misfits as ``a``, put where it is by others than the two: :func:`_vouched_for`; or the handedness), and ``b``'s own
sample in that frame is either suspect and fits ``a``'s references (exchanging the two names restores both
markers' distances), or missing while most of ``a``'s references disagree with ``a``'s sample, or most of its chiral
triples seen turn it to its mirror image (a mirror twin stands as far from the trunk's mirror plane as its own
marker would: its side is what is wrong; one reference astray cannot hand a sample to a missing marker). Distances cannot tell a body from its mirror image (a segment with two
mirror pairs: exchanging either pair restores every distance of a swap of the other; the left and right shoulders
against the markers on the trunk's mirror plane), so an exchange must also leave each marker's chiral triples
with their handedness, most of those seen in the frame (:class:`References`: several per marker, of markers on
rigid bodies only, rigid ones first, then those that tell the marker from its mirror twin, so that one hidden
marker leaves the others to judge). A sample that fits two missing markers (mirror twins), or is handed to a
missing marker for no more than the one or two frames of a ghost while its own marker is measured on both sides,
proves no swap and is left to spike removal. Those samples are exchanged (``repaired``), and the stretches
carried on by trajectory continuity; frames in which both markers are suspect but the exchange does not restore
them are made gaps (``removed``). Anything else suspect is left to spike removal. A
sample never moves unless the exchange is proven frame by frame, so a swap that starts or ends in a gap, or
across neighbouring segments, is handled like any other.

Positions are (T, M, 3) float64 mm, NaN where not measured; ``valid`` is (T, M) bool; frames are rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from itertools import combinations

import numpy as np

from gazepipe.stages.clean.filters import true_runs
from gazepipe.stages.clean.gapfill import is_unlabeled
from gazepipe.stages.clean.spikes import _MEDIAN_HALF, _nanmedian
from gazepipe.stages.geometry import norm3

#: references per marker (the steadiest distances): several, so that one astray is outvoted
N_REFERENCES = 6
#: a distance is *steady* when its spread (1.4826 MAD, mm: robust to the swaps themselves) is at most this: rigid
#: mates (noise, ~1 mm) and markers across one joint (a few mm). Steady references put a reference where it is
#: (:func:`_vouched_for`); a marker with fewer than :data:`N_REFERENCES` takes its steadiest distances whatever
#: their spread
MAX_REFERENCE_SPREAD_MM = 15.0
#: a reference's spread is taken as at least this (mm): marker noise, so that a perfectly rigid pair does not
#: make every sub-millimetre wobble suspect
SPREAD_FLOOR_MM = 1.0
#: a sample's misfit needs this many references measured in its frame
MIN_REFERENCES = 2
#: two markers closer than this (mm) are never exchanged: within a few tolerances of each other, either name
#: fits either sample, and camera systems merge markers that close anyway
MIN_SEPARATION_MM = 30.0
#: the misfit (in reference spreads) above which a sample is suspect, unless the caller says otherwise
TOLERANCE = 6.0
#: passes of repair at most (each pass after the first finds swaps an earlier repair uncovered)
MAX_PASSES = 3
#: frames sampled (evenly) to choose references: distance medians settle long before that
REFERENCE_FRAMES = 4000
#: frames per block of the take-long misfit: its temporaries stay within a block
_BLOCK_FRAMES = 2048


@dataclass(frozen=True)
class References:
    """Each marker's steady references: ``index`` (M, K) columns (−1: none), ``distance_mm`` (M, K) their
    distance's median and ``spread_mm`` (M, K) its spread, ``tolerance`` (M,) the misfit above which a sample
    is suspect (inf for a marker with fewer than :data:`MIN_REFERENCES` references: never judged)."""

    index: np.ndarray
    distance_mm: np.ndarray
    spread_mm: np.ndarray
    tolerance: np.ndarray
    #: (M, J, 3) up to :data:`N_CHIRAL` triples of references whose directions from the marker span a clear
    #: volume of one sign in nearly every frame of the subject's (−1: none), and (M, J) that sign (0: none).
    #: Distances cannot tell a rigid body from its mirror image: when two mirror pairs (left and right, front
    #: and back) share a segment, exchanging the wrong pair makes every distance right again and the handedness
    #: wrong. Several triples, so that one hidden marker (or one astray) does not leave the marker's handedness
    #: unknown (or turn it)
    chiral: np.ndarray | None = None
    handedness: np.ndarray | None = None
    #: (M, M) every distance (mm: median; NaN where never measured together) and its spread (mm, at least
    #: :data:`SPREAD_FLOOR_MM`): a sample that may be another marker's is judged as that marker against the
    #: references of both (:func:`_pair_references`), each within that marker's spread of it
    distance_all: np.ndarray | None = None
    spread_all: np.ndarray | None = None


@dataclass(frozen=True)
class SwapRecord:
    """One stretch of a swap: markers ``first`` and ``second`` (columns), frames ``[start, stop)``, repaired
    (names exchanged back) or removed (both made gaps)."""

    first: int
    second: int
    start: int
    stop: int
    repaired: bool


@dataclass
class SwapResult:
    """Output of :func:`repair_swaps`: positions and ``valid`` with the repaired stretches exchanged back (and
    the removed samples NaN / False), the (T, M) masks of ``repaired`` samples (now under their right name) and
    ``removed`` ones, and one :class:`SwapRecord` per stretch in time order."""

    xyz: np.ndarray
    valid: np.ndarray
    repaired: np.ndarray
    removed: np.ndarray
    records: list[SwapRecord]



def judged_columns(labels: Sequence[str], target: str | None, clapper: Sequence[str]) -> np.ndarray:
    """(K,) int64 columns of ``labels`` whose swaps are looked for, and that serve as each other's references:
    every marker the table carries, listed in a markerset segment or not, but the ``target`` and the
    ``clapper`` (no part of the body) and unlabeled trajectories (:func:`is_unlabeled`: no marker's name)."""
    other = {target, *clapper}
    return np.array([i for i, lab in enumerate(labels) if lab not in other and not is_unlabeled(lab)],
                    dtype=np.int64)


def even_rows(n_rows: int, at_most: int) -> np.ndarray:
    """Up to ``at_most`` row indices spread evenly over ``n_rows`` rows, first and last included."""
    return np.unique(np.linspace(0, max(n_rows - 1, 0), min(n_rows, at_most)).astype(np.int64))


def steady_references(xyz: np.ndarray, valid: np.ndarray, markers: np.ndarray | None = None) -> References:
    """:class:`References` of every marker from up to :data:`REFERENCE_FRAMES` evenly spaced frames of ``xyz``
    (one take, or the frames of several takes of the subject stacked), among the columns ``markers`` (default
    all; the others get none: the target and the clapper are no part of the body); tolerances are left infinite
    (:func:`with_tolerances` sets them for a take)."""
    from gazepipe.stages.clean.kernels import pair_distance_stats  # numba: imported where first needed

    n_t, n_m = valid.shape
    body = np.zeros(n_m, dtype=bool)
    body[np.arange(n_m) if markers is None else np.asarray(markers, dtype=np.int64)] = True
    rows = even_rows(n_t, REFERENCE_FRAMES)
    x, ok = xyz[rows], valid[rows]
    index = np.full((n_m, N_REFERENCES), -1, dtype=np.int64)
    distance = np.full((n_m, N_REFERENCES), np.nan)
    spread_mm = np.full((n_m, N_REFERENCES), np.nan)
    distance_all, spread = pair_distance_stats(x, ok, body)                   # (M, M) medians, spreads
    spread_all = np.maximum(spread, SPREAD_FLOOR_MM)
    for m in np.flatnonzero(body):
        cols = np.flatnonzero(np.isfinite(distance_all[m]))
        # the steadiest distances: a marker rigid with too few others for the bound (a shoulder, an elbow: on no
        # segment) takes its steadiest others as well, each judged within its own spread
        order = cols[np.argsort(spread[m, cols], kind="stable")[:N_REFERENCES]]
        index[m, :order.size] = order
        distance[m, :order.size] = distance_all[m, order]
        spread_mm[m, :order.size] = spread_all[m, order]
    distance_all, spread_all = _known_distances(distance_all, spread_all)
    # the handedness from the samples that keep their distances only: a marker's own swaps (a large share of a
    # short take's frames) are no part of its body's shape
    plain = with_tolerances(References(index, distance, spread_mm, np.full(n_m, np.inf)), TOLERANCE)
    suspect = _screen(x, ok, plain, slice(None))[0]
    chiral, handedness = _handedness(x, ok & ~suspect, _chiral_pool(index), spread_all, distance_all)
    return References(index, distance, spread_mm, np.full(n_m, np.inf), chiral, handedness, distance_all, spread_all)


def _known_distances(distance_all: np.ndarray, spread_all: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (M, M) distances (and spreads) of :class:`References` from those measured from each marker: a pair
    measured from one end only (its frames too few a share of the other's) has that end's, both ways."""
    return (np.where(np.isnan(distance_all), distance_all.T, distance_all),
            np.where(np.isnan(spread_all), spread_all.T, spread_all))


#: a reference triple's volume, as a share of the product of its three distances, must be at least this in
#: the median frame to tell a body from its mirror image (0.1: about 6° out of the plane of two of them)
MIN_CHIRAL_VOLUME = 0.1


def _volume(origin: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Triple product of the directions (..., 3) from ``origin`` to ``a``, ``b``, ``c``, as a share of the product
    of their lengths: in [−1, 1], its sign the triple's handedness."""
    u, v, w = a - origin, b - origin, c - origin
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]       # by components: np.cross costs more in its set-up than
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]       # in its arithmetic on the small blocks judged here
    w0, w1, w2 = w[..., 0], w[..., 1], w[..., 2]
    det = u0 * (v1 * w2 - v2 * w1) + u1 * (v2 * w0 - v0 * w2) + u2 * (v0 * w1 - v1 * w0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return det / np.sqrt((u0 * u0 + u1 * u1 + u2 * u2) * (v0 * v0 + v1 * v1 + v2 * v2)
                             * (w0 * w0 + w1 * w1 + w2 * w2))


#: frames (evenly spread) on which the chiral triples are chosen
CHIRAL_FRAMES = 500
#: chiral triples per marker at most
N_CHIRAL = 4
#: a quadruple (the marker and a triple) whose six distances all spread at most this (mm) is one rigid body:
#: marker noise alone. Its handedness cannot change but by a wrong name, so its median sign is its handedness
RIGID_SPREAD_MM = 2.0
#: a triple that is not rigid (across a joint) tells a body from its mirror image only when its volume keeps
#: its sign, by a clear share (half of :data:`MIN_CHIRAL_VOLUME`), in all but this share of the frames where it
#: is seen (the swaps and ghosts the sample frames hold themselves aside): one a joint turns over does not
CHIRAL_OUTLIERS = 0.05


#: markers whose triples may give a marker its handedness: its references, then its next steadiest distances
N_CHIRAL_POOL = 12


def _chiral_pool(index: np.ndarray) -> np.ndarray:
    """(M, :data:`N_CHIRAL_POOL`) columns (−1: none) whose triples may tell each marker from its mirror image:
    its references, then its steadiest reference's references, then the next one's, and so on. A marker on no
    segment (an elbow) has few references near it that can tell its side; the body it hangs from (its
    shoulder's references: the other shoulder, the chest) can."""
    n_m = index.shape[0]
    pool = np.full((n_m, N_CHIRAL_POOL), -1, dtype=np.int64)
    for m in range(n_m):
        own = index[m][index[m] >= 0]
        cols = np.concatenate([own, index[own].reshape(-1)]) if own.size else own
        cols = cols[(cols >= 0) & (cols != m)]
        cols = cols[np.sort(np.unique(cols, return_index=True)[1])][:N_CHIRAL_POOL]     # first seen first
        pool[m, :cols.size] = cols
    return pool


def _handedness(x: np.ndarray, ok: np.ndarray, index: np.ndarray, spread_all: np.ndarray,
                distance_all: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each marker's chiral reference triples and their handedness (see :class:`References`), from sample
    frames ``x`` (S, M, 3) where ``ok`` (S, M), the candidate corners ``index`` (M, K) and every pair's
    distance (``distance_all``, M x M, mm) and its spread (``spread_all``; NaN: unknown): of the triples whose
    volume from it is clear in the median frame, the rigid ones (:data:`RIGID_SPREAD_MM`) first, largest
    volume first, then those that tell it from its twin (:func:`_twins`: its volume from the twin's place
    keeps the other sign, by a clear share, as its own keeps its), then the others that keep their sign
    (:data:`CHIRAL_OUTLIERS`), farthest from turning over first; at most :data:`N_CHIRAL`. Corners are markers
    of rigid bodies only (the trunk, for a marker on no segment)."""
    from gazepipe.stages.clean.kernels import chiral_triples  # numba: imported where first needed

    n_m, k = index.shape
    chiral = np.full((n_m, N_CHIRAL, 3), -1, dtype=np.int64)
    handedness = np.zeros((n_m, N_CHIRAL))
    triples = np.array(list(combinations(range(k), 3)), dtype=np.int64)           # (C, 3) slots of index
    keep = even_rows(len(x), CHIRAL_FRAMES)
    x, ok = x[keep], ok[keep]                      # a handedness's sign settles on a few hundred frames
    spread = np.nan_to_num(spread_all, nan=np.inf)
    twins = _twins(distance_all, spread_all)
    # a corner must be anchored in a rigid body (rigid with at least MIN_REFERENCES others: a segment's marker):
    # a marker on no segment may be swapped itself (an elbow with its twin), and turn the triple with it
    anchored = np.append((spread <= RIGID_SPREAD_MM).sum(axis=1) >= MIN_REFERENCES, False)    # index −1: none
    for m in range(n_m):
        usable = triples[(index[m][triples] >= 0).all(axis=1) & anchored[index[m][triples]].all(axis=1)]
        if usable.size == 0 or np.count_nonzero(ok[:, m]) < 10:
            continue
        tri = index[m][usable]                                                      # (C, 3) columns
        seen, median, low, tells = chiral_triples(x, ok, m, int(twins[m]), tri, CHIRAL_OUTLIERS)
        enough = seen >= 10
        if not enough.any():
            continue
        tri, median, low, tells = tri[enough], median[enough], low[enough], tells[enough]
        sign = np.sign(median)
        rigid = np.maximum.reduce([spread[m, tri[:, 0]], spread[m, tri[:, 1]], spread[m, tri[:, 2]],
                                   spread[tri[:, 0], tri[:, 1]], spread[tri[:, 0], tri[:, 2]],
                                   spread[tri[:, 1], tri[:, 2]]]) <= RIGID_SPREAD_MM
        clear = np.abs(median) >= MIN_CHIRAL_VOLUME
        good = clear & (rigid | (low >= 0.5 * MIN_CHIRAL_VOLUME))
        telling = good & ~rigid & (tells >= 0.5 * MIN_CHIRAL_VOLUME)
        # rigid first, then those telling the twin; the others only for a marker without either (a triple that
        # keeps its sign from the twin's place too outvotes the ones that turn when the two are exchanged)
        if (good & rigid).any() or telling.any():
            good &= rigid | telling
        rank = np.where(rigid, 2.0 + np.abs(median), low)                # a share is at most 1
        order = _spread_out(tri, np.flatnonzero(good)[np.argsort(-rank[good], kind="stable")])
        chiral[m, :order.size], handedness[m, :order.size] = tri[order], sign[order]
    return chiral, handedness


def _twins(distance_all: np.ndarray, spread_all: np.ndarray) -> np.ndarray:
    """(M,) each marker's twin (−1: none): the marker whose distances to the others, sorted, are nearest its
    own sorted (the median difference, mm): its mirror image across the body (the left and the right shoulder
    stand as far from the trunk, each from its own side), which distances to the markers on the mirror plane
    cannot tell from it."""
    from gazepipe.stages.clean.kernels import twin_scores  # numba: imported where first needed

    known = np.isfinite(distance_all) & np.isfinite(spread_all)
    score = twin_scores(distance_all, known, MIN_REFERENCES)
    some = np.isfinite(score).any(axis=1)
    return np.where(some, np.argmin(score, axis=1), -1).astype(np.int64)


def _spread_out(tri: np.ndarray, ranked: np.ndarray) -> np.ndarray:
    """Up to :data:`N_CHIRAL` of the triples ``tri[ranked]`` (best first), taken so that each marker is a corner
    of as few of them as it can be: one hidden marker then leaves the others to judge."""
    chosen: list[int] = []
    uses: dict[int, int] = {}
    for cap in range(1, N_CHIRAL + 1):
        for t in ranked:
            if len(chosen) == N_CHIRAL:
                break
            if t not in chosen and all(uses.get(int(c), 0) < cap for c in tri[t]):
                chosen.append(int(t))
                for c in tri[t]:
                    uses[int(c)] = uses.get(int(c), 0) + 1
    return np.array(chosen, dtype=np.int64)


def with_tolerances(refs: References, tolerance: float) -> References:
    """``refs`` with the tolerance ``tolerance`` (in reference spreads) for every marker with at least
    :data:`MIN_REFERENCES` references, inf for the others."""
    judged = (refs.index >= 0).sum(axis=1) >= MIN_REFERENCES
    return replace(refs, tolerance=np.where(judged, float(tolerance), np.inf))


@dataclass(frozen=True)
class SubjectReferences:
    """:class:`References` of a subject by marker name (``labels``), from several takes: what a take's swaps
    are judged against when its own frames cannot say which names are right (a swap lasting most of a short
    take)."""

    labels: tuple[str, ...]
    references: References

    def for_labels(self, labels: list[str]) -> References:
        """The references of a take whose columns are ``labels`` (markers it lacks are no references; its
        markers the subject's takes never had get none)."""
        column = {lab: i for i, lab in enumerate(labels)}
        mine = [self.labels.index(lab) if lab in self.labels else -1 for lab in labels]
        n_m = len(labels)

        def columns(of: np.ndarray) -> np.ndarray:
            out = np.full((n_m, of.shape[1]), -1, dtype=np.int64)
            for m, src in enumerate(mine):
                if src >= 0:
                    out[m] = [column.get(self.labels[j], -1) if j >= 0 else -1 for j in of[src]]
            return out

        refs = self.references
        index = columns(refs.index)
        rows = np.array([max(src, 0) for src in mine], dtype=np.int64)
        has = index >= 0
        n_j = refs.chiral.shape[1] if refs.chiral is not None else 1
        chiral = columns(refs.chiral.reshape(len(self.labels), -1)).reshape(n_m, n_j, 3) \
            if refs.chiral is not None else np.full((n_m, n_j, 3), -1, dtype=np.int64)
        # a triple the take lacks a marker of: none
        whole = (chiral >= 0).all(axis=2) & (np.array(mine) >= 0)[:, None]
        handedness = np.where(whole, refs.handedness[rows], 0.0) if refs.handedness is not None \
            else np.zeros((n_m, n_j))
        return References(index, np.where(has, refs.distance_mm[rows], np.nan),
                          np.where(has, refs.spread_mm[rows], np.nan), np.full(n_m, np.inf),
                          np.where(whole[..., None], chiral, -1), handedness,
                          self._square(refs.distance_all, mine), self._square(refs.spread_all, mine))

    @staticmethod
    def _square(of: np.ndarray | None, mine: list[int]) -> np.ndarray | None:
        """The (M, M) matrix ``of`` (the subject's columns) for a take whose column ``m`` is the subject's
        ``mine[m]`` (−1: a marker the subject's takes never had: NaN row and column)."""
        if of is None:
            return None
        src = np.array(mine, dtype=np.int64).reshape(-1)
        out = of[np.ix_(np.maximum(src, 0), np.maximum(src, 0))].copy()
        out[src < 0] = np.nan
        out[:, src < 0] = np.nan
        return out


def pooled_references(takes: list[tuple[list[str], np.ndarray, np.ndarray]],
                      markers: set[str] | None = None) -> SubjectReferences:
    """The subject's references from several takes ``(labels, xyz, valid)``: up to
    :data:`REFERENCE_FRAMES` frames spread evenly over all of them, stacked by marker name; only the markers
    named in ``markers`` (default all) are judged or serve as references."""
    labels = tuple(sorted({lab for names, _, _ in takes for lab in names}))
    total = sum(valid.shape[0] for _, _, valid in takes)
    xs, vs = [], []
    for names, xyz, valid in takes:
        n_t = valid.shape[0]
        share = max(1, round(REFERENCE_FRAMES * n_t / max(total, 1)))
        rows = even_rows(n_t, share)
        x = np.full((rows.size, len(labels), 3), np.nan)
        v = np.zeros((rows.size, len(labels)), dtype=bool)
        cols = [labels.index(lab) for lab in names]
        x[:, cols] = xyz[rows]
        v[:, cols] = valid[rows]
        xs.append(x)
        vs.append(v)
    body = None if markers is None else np.array([i for i, lab in enumerate(labels) if lab in markers])
    xyz_all = np.concatenate(xs) if xs else np.zeros((0, 0, 3))
    valid_all = np.concatenate(vs) if vs else np.zeros((0, 0), bool)
    return SubjectReferences(labels, steady_references(xyz_all, valid_all, markers=body))


def _misfit(points: np.ndarray, xyz: np.ndarray, valid: np.ndarray, as_marker: np.ndarray, refs: References,
            exclude: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Misfits (n, C) of ``points`` (n, C, 3), each judged as marker ``as_marker[c]`` against its references in
    the same frames (``xyz`` (n, M, 3), ``valid`` (n, M)); references equal to ``exclude[c]`` are left out.
    Two of them: the largest deviation (a swap of mirror-image markers is seen by the one or two references
    off the mirror plane only; inf where the point turns the marker's chiral triples, :func:`_flipped`: a
    mirror image of the marker keeps every distance), and the lower median (a marker most of its references
    disagree with: displaced itself, not one of its references; above the tolerance only where most of them
    disagree: of two, both, since one astray and one agreeing cannot say which of the two markers is wrong).
    NaN where fewer than :data:`MIN_REFERENCES` references are measured."""
    from gazepipe.stages.clean.kernels import misfits

    chiral, hand = _chirality(refs)
    return misfits(points, xyz, valid, np.asarray(as_marker, dtype=np.int64), _excluded(exclude, points.shape[1]),
                   refs.index, refs.distance_mm, refs.spread_mm, chiral, hand, MIN_REFERENCES,
                   0.5 * MIN_CHIRAL_VOLUME)


def _chirality(refs: References) -> tuple[np.ndarray, np.ndarray]:
    """``refs``' chiral triples (M, J, 3) and handedness (M, J), none (J = 0) when it has none."""
    if refs.chiral is None or refs.handedness is None:
        n_m = refs.index.shape[0]
        return np.full((n_m, 0, 3), -1, dtype=np.int64), np.zeros((n_m, 0))
    return refs.chiral, refs.handedness


def _excluded(exclude: np.ndarray | None, n: int) -> np.ndarray:
    """(n,) int64 columns left out of each judgement (−1: none)."""
    return np.full(n, -1, dtype=np.int64) if exclude is None else np.asarray(exclude, dtype=np.int64)


def _flipped(points: np.ndarray, xyz: np.ndarray, valid: np.ndarray, as_marker: np.ndarray, refs: References,
             exclude: np.ndarray | None) -> np.ndarray:
    """(n, C) bool: ``points`` judged as ``as_marker`` turn more of its chiral triples (all three measured there,
    and none of them ``exclude``) against their handedness, by a clear volume, than they leave with it: one
    corner astray turns the triples it is in only."""
    from gazepipe.stages.clean.kernels import flipped

    chiral, hand = _chirality(refs)
    return flipped(points, xyz, valid, np.asarray(as_marker, dtype=np.int64), _excluded(exclude, points.shape[1]),
                   chiral, hand, 0.5 * MIN_CHIRAL_VOLUME)


def _turned(vol: np.ndarray, hand: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(...) bool from (..., J) volumes, their usual handedness and where they are seen: more of them turned
    against it by a clear volume than left with it."""
    with np.errstate(invalid="ignore"):
        turned = seen & (np.abs(vol) >= 0.5 * MIN_CHIRAL_VOLUME) & (np.sign(vol) == -hand)
        kept = seen & (np.sign(vol) == hand)
    return turned.sum(axis=-1) > kept.sum(axis=-1)


def _screen(xyz: np.ndarray, usable: np.ndarray, refs: References, rows: np.ndarray | slice,
            trusted: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(suspect, displaced) bool masks of frames ``rows`` (of ``xyz`` (T, M, 3)): a ``usable`` sample whose
    largest, or median, misfit (:func:`_misfit`) against its references measured in ``trusted`` (default
    ``usable``) is above its marker's tolerance."""
    from gazepipe.stages.clean.kernels import screen

    at = np.arange(usable.shape[0])[rows] if isinstance(rows, slice) else np.asarray(rows, dtype=np.int64)
    chiral, hand = _chirality(refs)
    return screen(xyz, usable, usable if trusted is None else trusted, at, refs.index, refs.distance_mm,
                  refs.spread_mm, chiral, hand, refs.tolerance, MIN_REFERENCES, 0.5 * MIN_CHIRAL_VOLUME)


def repair_swaps(xyz: np.ndarray, valid: np.ndarray, tolerance: float = TOLERANCE,
                 references: References | None = None, markers: np.ndarray | None = None,
                 in_place: bool = False) -> SwapResult:
    """Find and undo label swaps (see the module's docstring). Unless ``in_place``, ``xyz`` and ``valid`` are
    not changed and the result holds new arrays. ``tolerance``: the misfit (in reference spreads, each at
    least :data:`SPREAD_FLOOR_MM`) above which a sample is suspect. ``references``: the subject's
    (:func:`pooled_references` of several takes); default: the take's own, which cannot tell a swap that lasts
    most of the take from the right names. ``markers``: the columns of the subject's body (see
    :func:`steady_references`). ``in_place``: ``xyz`` and ``valid`` are the caller's own (``xyz`` NaN wherever
    not ``valid``) and are repaired in place, not copied."""
    if not in_place:
        xyz = np.where(valid[..., None], xyz, np.nan)
        valid = valid.copy()
    n_t, n_m = valid.shape
    repaired = np.zeros((n_t, n_m), dtype=bool)
    removed = np.zeros((n_t, n_m), dtype=bool)
    records: list[SwapRecord] = []
    if n_t < 3 or n_m < 2:
        return SwapResult(xyz, valid, repaired, removed, records)
    refs = with_tolerances(references or steady_references(xyz, valid, markers), tolerance)
    usable = valid.copy()
    suspect = np.zeros((n_t, n_m), dtype=bool)
    displaced = np.zeros((n_t, n_m), dtype=bool)
    for lo in range(0, n_t, _BLOCK_FRAMES):         # the whole take once; later only the frames that change
        rows = slice(lo, lo + _BLOCK_FRAMES)
        suspect[rows], displaced[rows] = _screen(xyz, usable, refs, rows)
    state = _State(xyz, valid, usable, suspect, displaced, repaired, removed, records, refs)
    # a pass repairs what it can prove; one swap can hide another (two pairs referencing each other), so
    # passes repeat, over the frames the last one changed, while they repair something; a last one, over the
    # markers of the repaired swaps, makes the frames of their stretches it cannot prove gaps. Samples handed
    # to a missing partner (the weakest proof: no sample of the partner's confirms it) come after every
    # exchange of two samples and its continuation: a reference of theirs still swapped would make a right
    # sample look displaced, and a sample handed on wrongly is carried on by continuity. Repaired stretches
    # are carried on by continuity after each pass, and the frames either changed are judged anew. Where a
    # repaired swap goes on unproven (its start hidden by a burst, say), its samples are made gaps
    for missing_partner in (False, True):
        frames = np.ones(n_t, dtype=bool)
        for _ in range(MAX_PASSES):
            frames = _one_pass(state, frames, markers=None, remove=False, missing_partner=missing_partner)
            frames |= _extend_by_continuity(state)
            if not frames.any():
                break
    _remove_unproven(state)
    swapped = sorted({m for pair, mask in state.exchanged.items() if mask.any() for m in pair})
    _one_pass(state, np.ones(n_t, dtype=bool), markers=np.array(swapped, dtype=np.int64), remove=True)
    xyz[removed] = np.nan
    valid &= ~removed
    return SwapResult(xyz, valid, repaired, removed, _merged(state.repaired_records() + state.records))


@dataclass
class _State:
    """What the passes of :func:`repair_swaps` share: the take as repaired so far (positions, measured,
    usable: measured and not removed) and the masks kept up to date as frames change."""

    xyz: np.ndarray
    valid: np.ndarray
    usable: np.ndarray
    suspect: np.ndarray
    displaced: np.ndarray
    repaired: np.ndarray
    removed: np.ndarray
    #: the stretches made gaps (those repaired are in ``exchanged``)
    records: list[SwapRecord]
    refs: References
    #: per pair (lower column first), the (T,) frames whose samples stand exchanged now: a frame exchanged
    #: twice (a repair undone once its references were put back) is under the capture's names again
    exchanged: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)

    def exchange(self, pair: list[int], frames: np.ndarray) -> None:
        """Exchange the samples of the two columns ``pair`` in ``frames`` (in place), every mask with them; a
        sample is ``repaired`` while it stands under the other name than the capture gave it."""
        rows = frames[:, None]
        for arr in (self.xyz, self.valid, self.usable, self.repaired):
            arr[rows, pair] = arr[rows, pair[::-1]]
        self.repaired[rows, pair] = self.valid[rows, pair] & ~self.repaired[rows, pair]
        mask = self.exchanged.setdefault((min(pair), max(pair)), np.zeros(self.valid.shape[0], dtype=bool))
        mask[frames] ^= True

    def repaired_records(self) -> list[SwapRecord]:
        """One repaired :class:`SwapRecord` per run of frames a pair stands exchanged in now."""
        n_t = self.valid.shape[0]
        return [r for pair, mask in self.exchanged.items() for r in _records(list(pair), np.flatnonzero(mask), n_t, True)]


def _one_pass(st: _State, where: np.ndarray, markers: np.ndarray | None, remove: bool,
              missing_partner: bool = True) -> np.ndarray:
    """One pass over the markers suspect in frames ``where`` ((T,) bool; only ``markers`` when given), in column
    order, exchanging (in place) the frames each swap explains and, with ``remove``, marking the unprovable
    ones removed; without ``missing_partner``, only frames where both markers are measured are explained.
    Returns the (T,) bool mask of frames it repaired."""
    n_t = st.valid.shape[0]
    done = np.zeros(n_t, dtype=bool)
    candidates = np.flatnonzero((st.suspect & where[:, None]).any(axis=0))
    if markers is not None:
        candidates = np.intersect1d(candidates, markers)
    for a in candidates:
        frames = np.flatnonzero(st.suspect[:, a] & ~st.removed[:, a] & where)
        if frames.size == 0:
            continue
        partner, explained, both = _best_partner(st.xyz, st.usable, st.displaced, st.refs, int(a), frames,
                                                 missing_partner)
        if partner < 0:
            continue
        fix, drop = frames[explained], frames[both & ~explained] if remove else frames[:0]
        pair = [int(a), partner]
        st.exchange(pair, fix)
        st.removed[drop[:, None], pair] = True
        st.usable[drop[:, None], pair] = False
        changed = np.union1d(fix, drop)
        if changed.size:                           # every marker judged in those frames anew
            st.suspect[changed], st.displaced[changed] = _screen(st.xyz, st.usable, st.refs, changed)
        st.records += _records(pair, drop, n_t, False)
        done[fix] = True
    return done


def _best_partner(xyz: np.ndarray, valid: np.ndarray, displaced: np.ndarray, refs: References, a: int,
                  frames: np.ndarray, missing_partner: bool = True) -> tuple[int, np.ndarray, np.ndarray]:
    """The marker whose name ``a``'s suspect samples (at ``frames``) carry: the one that explains most of them
    (see the module's docstring), judged only by references not ``displaced`` themselves in that frame (two
    swaps at once, of which one pair are references of the other); without ``missing_partner``, a partner not
    measured in a frame explains nothing there. Returns (its column or −1, explained (n,) bool, both suspect
    (n,) bool)."""
    n_m = valid.shape[1]
    none = np.zeros(frames.size, dtype=bool)
    if not np.isfinite(refs.tolerance[a]):
        return -1, none, none
    x, ok = xyz[frames], valid[frames]
    trusted = ok & ~displaced[frames]
    n = frames.size
    own = np.zeros((n, n_m), dtype=bool)
    gone_wrong = np.zeros(n, dtype=bool)
    for lo in range(0, n, _BLOCK_FRAMES):        # in blocks: a marker suspect all take long stays in bounds
        rows = slice(lo, lo + _BLOCK_FRAMES)
        # suspect against trusted references only: a marker suspect because its references were swapped is not
        own[rows] = _screen(x, ok, refs, rows, trusted=trusted)[0]
        worst, median = _misfit(x[rows, a:a + 1], x[rows], trusted[rows], np.array([a]), refs, exclude=None)
        with np.errstate(invalid="ignore"):
            # off by most references' reckoning, not one astray, or turned to its mirror image by most of its chiral
            # triples seen (a mirror twin, an elbow on the other side, stands as far from the trunk's mirror plane
            # as its own marker would: its side is what is wrong): what a sample handed to a missing partner needs
            gone_wrong[rows] = ok[rows, a] & ((median[:, 0] > refs.tolerance[a]) | np.isinf(worst[:, 0]))
    # a partner is missing or suspect itself in the frame where a is suspect
    maybe = (own | ~ok) & own[:, a:a + 1] & np.isfinite(refs.tolerance)[None]
    maybe[:, a] = False
    apart = _nanmedian(norm3(x[:, a:a + 1] - x), axis=0)     # the same, swapped or not
    maybe &= ~(apart < MIN_SEPARATION_MM)[None]          # unknown (never measured together here): allowed
    others = np.flatnonzero(maybe.any(axis=0))
    if others.size == 0:
        return -1, none, none
    explained = np.zeros((n, others.size), dtype=bool)
    for c, b in enumerate(others.tolist()):      # each candidate on its own frames only
        at = np.flatnonzero(maybe[:, b])
        xr, tr = x[at], trusted[at]
        # a's sample judged as b; b's sample judged as a
        # two samples exchanged: a reference across a joint held beyond the subject's usual range may be out
        # of tolerance for either, as long as it is nearer the exchanged name's distance (both samples say
        # so); a sample handed to a missing partner has no second sample to confirm it: strictly within
        gone = ~ok[at, b] & missing_partner & gone_wrong[at]
        both = own[at, b]
        if both.any():
            xb, tb = xr[both], tr[both]
            explained[at[both], c] = _fits_as(xb, tb, refs, a, b, lenient=True) \
                & _fits_as(xb, tb, refs, b, a, lenient=True)
        if gone.any():
            explained[at[gone], c] = _fits_as(xr[gone], tr[gone], refs, a, b)
    b_suspect = own[:, others]
    score = explained.sum(axis=0)
    best = -1
    checked = np.zeros(others.size, dtype=bool)
    for c in np.argsort(-score, kind="stable"):
        if score[c] == 0:
            break
        explained[:, c] &= _keeps_handedness(x, trusted, refs, a, int(others[c]))
        checked[c] = True
        if explained[:, c].sum() == score[c]:         # every explained frame keeps both hands: no better one
            best = int(c)
            break
        if best < 0 or explained[:, c].sum() > explained[:, best].sum():
            best = int(c)
    if best < 0 or not explained[:, best].any():
        return -1, none, none
    handed = explained[:, best] & ~ok[:, others[best]]
    # a sample handed to a missing marker that fits another name as well (a mirror twin: the left and right
    # chest markers, both hidden, and too few references seen to tell them apart by handedness) proves
    # neither: the order of the columns would choose
    rivals = np.flatnonzero((explained & handed[:, None]).any(axis=0))
    rivals = rivals[rivals != best]
    for c in rivals[~checked[rivals]]:
        explained[:, c] &= _keeps_handedness(x, trusted, refs, a, int(others[c]))
    twin = handed & explained[:, rivals].any(axis=1)
    explained[:, best] &= ~twin
    explained[:, best] &= ~_ghosts(frames, handed & ~twin, explained[:, best], valid[:, a])
    if not explained[:, best].any():
        return -1, none, none
    both = own[:, a] & b_suspect[:, best]
    # not provable inside the stretch the exchange explains (a glitch on one of them, say): both made gaps
    span = np.flatnonzero(explained[:, best])
    both &= (frames >= frames[span[0]]) & (frames <= frames[span[-1]])
    return int(others[best]), explained[:, best], both


#: the longest glitch spike removal outvotes (frames): a sample handed to a missing marker over no more than this,
#: with its own marker measured on both sides, may be a ghost off its own path as well as a swap
GHOST_FRAMES = _MEDIAN_HALF


def _ghosts(frames: np.ndarray, handed: np.ndarray, explained: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """(n,) bool: the frames of ``frames`` (ascending) in runs of consecutive ``explained`` frames that are all
    ``handed`` to a missing partner, at most :data:`GHOST_FRAMES` long, with the marker ``measured`` ((T,) bool)
    in the frames just before and after. Such a run is a ghost of one or two frames as much as a swap: a sample
    that lands where a hidden marker would be, within the tolerance of the references seen there, proves no
    swap (a spike's ghost lands anywhere; a hidden marker's loose references across a joint leave it room),
    and the exchange would carry a ghost under another name. Left alone, spike removal makes it a gap."""
    out = np.zeros(frames.size, dtype=bool)
    at = np.flatnonzero(explained)
    if at.size == 0:
        return out
    f = frames[at]
    cut = np.flatnonzero(np.diff(f) != 1) + 1
    starts, stops = np.r_[0, cut], np.r_[cut, f.size]                # runs of consecutive frames, in ``at``
    length = stops - starts
    all_handed = np.add.reduceat(handed[at].astype(np.int64), starts) == length
    first, last = f[starts], f[stops - 1]
    n_t = measured.size
    bounded = (first > 0) & (last < n_t - 1)
    bounded[bounded] = measured[first[bounded] - 1] & measured[last[bounded] + 1]
    ghost = (length <= GHOST_FRAMES) & all_handed & bounded
    out[at] = np.repeat(ghost, length)
    return out


def _remove_unproven(st: _State) -> None:
    """Make gaps (in place, both markers) of the frames where a repaired swap goes on unproven: one marker's
    sample suspect and standing where its partner would (:func:`_fits_as`), the partner's missing or suspect
    too, in a run of such frames joined to a repaired stretch of the pair (through frames where neither is
    measured). A burst that hides a swap's start leaves such a run: the references that would tell the two
    apart are hidden, or too few to hand the sample to its missing partner, and continuity cannot carry the
    stretch across frames where both are missing; left alone, the sample would stand as measured under the
    other name. Elsewhere the two are not known to be swapped, and are left to spike removal."""
    n_t = st.valid.shape[0]
    for (a, b), exchanged in list(st.exchanged.items()):
        if not exchanged.any():
            continue
        pair = [a, b]
        free = ~exchanged & ~st.removed[:, pair].any(axis=1)
        rows = np.flatnonzero(free & st.suspect[:, pair].any(axis=1))
        unproven = np.zeros(n_t, dtype=bool)
        if rows.size:
            x, trusted = st.xyz[rows], st.usable[rows] & ~st.displaced[rows]
            # suspect against trusted references only (as :func:`_best_partner` judges)
            worst = _misfit(x[:, pair], x, trusted, np.array(pair), st.refs, exclude=None)[0]
            with np.errstate(invalid="ignore"):
                suspect = st.usable[rows][:, pair] & (worst > st.refs.tolerance[pair][None])
            gone = ~st.usable[rows][:, pair]
            unproven[rows] = (suspect[:, 0] & _fits_as(x, trusted, st.refs, a, b) & (gone[:, 1] | suspect[:, 1])) \
                | (suspect[:, 1] & _fits_as(x, trusted, st.refs, b, a) & (gone[:, 0] | suspect[:, 0]))
        silent = free & ~st.usable[:, pair].any(axis=1)
        drop = np.flatnonzero(_joined(unproven, silent, exchanged))
        if drop.size == 0:
            continue
        st.removed[drop[:, None], pair] = True
        st.usable[drop[:, None], pair] = False
        st.suspect[drop], st.displaced[drop] = _screen(st.xyz, st.usable, st.refs, drop)
        st.records += _records(pair, drop, n_t, False)


def _joined(unproven: np.ndarray, silent: np.ndarray, repaired: np.ndarray) -> np.ndarray:
    """(T,) bool: the ``unproven`` frames of the runs of ``unproven`` or ``silent`` frames that touch a
    ``repaired`` frame (the frame before a run's start or after its end)."""
    out = np.zeros_like(unproven)
    n_t = unproven.size
    for start, stop in true_runs(unproven | silent):
        if (start > 0 and repaired[start - 1]) or (stop < n_t and repaired[stop]):
            out[start:stop] = unproven[start:stop]
    return out


def _pair_references(refs: References, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a sample that may be ``a``'s is judged against as ``b``'s: the references of both markers (neither
    marker itself), at ``b``'s distance to each (within its spread). A reference of one of them only can be all
    that tells the two apart (a mirror pair's mates stand as far from either), so ``b``'s own are not enough.
    Without the (M, M) distances of :class:`References`, ``b``'s own references. Returns the columns (K,), the
    distances (K,, mm, median) and their spreads (K,, mm)."""
    if refs.distance_all is None or refs.spread_all is None:
        keep = (refs.index[b] >= 0) & (refs.index[b] != a)
        return refs.index[b][keep], refs.distance_mm[b][keep], refs.spread_mm[b][keep]
    cols = np.union1d(refs.index[a], refs.index[b])
    cols = cols[(cols >= 0) & (cols != a) & (cols != b)]
    cols = cols[np.isfinite(refs.distance_all[b, cols])]
    return cols, refs.distance_all[b, cols], refs.spread_all[b, cols]


def _fits_as(x: np.ndarray, trusted: np.ndarray, refs: References, a: int, b: int, lenient: bool = False
             ) -> np.ndarray:
    """(n,) bool: frames where ``a``'s sample provably stands where ``b`` would: within ``b``'s tolerance (in
    spreads) of each of :func:`_pair_references` trusted there (at least :data:`MIN_REFERENCES` of them), not
    turning ``b``'s chiral triple against its handedness, and told from ``a`` there (:func:`_told_apart`).
    ``x`` (n, M, 3) mm and ``trusted`` (n, M): the frames. With ``lenient`` (two samples exchanged, each judged
    so), a reference out of ``b``'s tolerance but nearer ``b``'s distance than ``a``'s (in spreads) does not
    speak against it (a joint held bent beyond the subject's usual range: the head-centre marker against the
    neck's with the head pitched down), though it cannot be what tells the two apart."""
    cols, distance, spread = _pair_references(refs, a, b)
    if cols.size == 0:
        return np.zeros(x.shape[0], dtype=bool)
    assert refs.distance_all is not None and refs.spread_all is not None   # set whenever there are references
    seen = trusted[:, cols]
    d = norm3(x[:, [a]] - x[:, cols])
    with np.errstate(invalid="ignore"):
        dev = np.abs(d - distance[None]) / spread[None]                                     # (n, K)
        within = dev <= refs.tolerance[b]
        # a reference across a joint held beyond what the subject's takes showed (the head pitched down): out
        # of b's tolerance, yet still nearer b's distance than a's, it does not speak against b
        as_a = np.abs(d - refs.distance_all[a, cols][None]) / refs.spread_all[a, cols][None]
        nearer_b = ~within & (as_a > dev) & lenient
    agree = seen & within
    against = seen & ~within & ~nearer_b
    flipped = _flipped(x[:, [a]], x, trusted, np.array([b]), refs, exclude=np.array([a]))[:, 0]
    fits = (agree.sum(axis=1) >= MIN_REFERENCES) & ~against.any(axis=1) & ~flipped
    # what tells the two apart must be a reference the sample fits as b and that makes it suspect as a in that
    # frame (or the handedness): one merely nearer b's distance than a's proves nothing, nor one whose distance
    # to b spreads so far (a marker on no segment) that a's distance lies within it, nor one suspect itself by
    # the others, nor one the others do not vouch for (an elbow swapped with its twin makes each shoulder look
    # swapped, and the other way round: what the elbow's place says counts only where something but the
    # shoulders, which only loose distances tie it to, puts it there)
    with np.errstate(invalid="ignore"):
        telling = agree & (as_a > refs.tolerance[a]) & _vouched_for(x, trusted, refs, cols, [a, b])
    return fits & _told_apart(x, trusted, refs, a, b, cols, telling=telling)


def _vouched_for(x: np.ndarray, trusted: np.ndarray, refs: References, cols: np.ndarray, pair: list[int]
                 ) -> np.ndarray:
    """(n, K) bool: the markers ``cols`` that their references trusted in each frame of ``x`` (n, M, 3), the two
    of ``pair`` aside, put where they are: not suspect by them (distances and handedness), and either within
    tolerance of at least :data:`MIN_REFERENCES` of them that are steady (a spread within
    :data:`MAX_REFERENCE_SPREAD_MM`: a loose distance fits a marker anywhere near its place) or with one of its
    chiral triples seen and kept (the side of the trunk it is on)."""
    from gazepipe.stages.clean.kernels import vouched

    seen = trusted.copy()
    seen[:, pair] = False
    chiral, hand = _chirality(refs)
    return vouched(x, seen, np.asarray(cols, dtype=np.int64), np.array(pair, dtype=np.int64), refs.index,
                   refs.distance_mm, refs.spread_mm, chiral, hand, refs.tolerance, MIN_REFERENCES,
                   0.5 * MIN_CHIRAL_VOLUME, MAX_REFERENCE_SPREAD_MM)


def _told_apart(x: np.ndarray, trusted: np.ndarray, refs: References, a: int, b: int, cols: np.ndarray,
                telling: np.ndarray | None = None) -> np.ndarray:
    """(n,) bool: frames where something trusted can tell ``a``'s place from ``b``'s: a reference among ``cols``
    whose steady distance to ``b`` is beyond ``a``'s tolerance of its distance to ``a`` (a sample standing where
    ``b`` would is suspect as ``a`` by it), or ``a``'s chiral triple, which the capture as it stands (``b``'s
    sample too, where the triple holds ``b``) turns against ``a``'s handedness. A
    mirror pair's mates on the mirror plane, and references far off that stand about as far from both, cannot:
    a sample fits either name there, and one reference drifting (a joint turning) makes it look like the
    other's. ``telling`` (n, K): the references among ``cols`` that may tell them apart in each frame (default:
    those trusted). Without the (M, M) distances of :class:`References`: every frame."""
    if refs.distance_all is None or refs.spread_all is None:
        return np.ones(x.shape[0], dtype=bool)
    with np.errstate(invalid="ignore"):
        apart = np.abs(refs.distance_all[a, cols] - refs.distance_all[b, cols]) \
            > refs.tolerance[a] * refs.spread_all[a, cols]
    told = ((trusted[:, cols] if telling is None else telling) & apart[None]).any(axis=1)
    return told | _flipped(x[:, [a]], x, trusted, np.array([a]), refs, exclude=None)[:, 0]


def _keeps_handedness(x: np.ndarray, trusted: np.ndarray, refs: References, a: int, b: int) -> np.ndarray:
    """(n,) bool: frames where exchanging ``a`` and ``b`` leaves each with its usual handedness: not more of its
    chiral triples turned than kept (:func:`_turned`; a triple counts where its corners are trusted, or hold
    ``a`` or ``b``; where none does, it cannot be told)."""
    ok = np.ones(x.shape[0], dtype=bool)
    if refs.chiral is None or refs.handedness is None:
        return ok
    exchanged = x.copy()
    exchanged[:, [a, b]] = x[:, [b, a]]
    for m in (a, b):
        tri, hand = refs.chiral[m], refs.handedness[m]                  # (J, 3), (J,)
        use = (hand != 0) & (tri >= 0).all(axis=1)
        if not use.any():
            continue
        tri, hand = tri[use], hand[use]
        involved = np.any(np.isin(tri, [a, b]), axis=1, keepdims=True).T                # (1, J)
        seen = np.all(trusted[:, tri], axis=2) | involved                                # (n, J)
        corners = exchanged[:, tri]                                                     # (n, J, 3, 3)
        vol = _volume(exchanged[:, m][:, None], corners[..., 0, :], corners[..., 1, :], corners[..., 2, :])
        ok &= ~_turned(vol, hand[None], seen & np.isfinite(vol))
    return ok


#: a frame continues a swap when keeping the capture's names there costs this much more path (mm: the two
#: markers' steps from the frame before, summed) than exchanging them, and at least this share more
CONTINUITY_MARGIN_MM = 10.0
CONTINUITY_SHARE = 0.5


def _extend_by_continuity(st: _State) -> np.ndarray:
    """Carry each repaired stretch on, frame by frame away from it, while the capture's two trajectories stay
    continuous there and the exchanged ones would jump: a swap goes on until the labeller's next jump, though the
    references that proved it are hidden (a distinguishing mate in a gap; mirror-image markers seen from the
    mirror plane only). Stops at a frame that decides nothing (both markers missing, or no clear jump). Every
    marker is judged anew in the frames it repairs (a swapped pair put back can prove another swap that used
    them as references). Returns the (T,) bool mask of those frames."""
    done = np.zeros(st.valid.shape[0], dtype=bool)
    separation: dict[tuple[int, int], float] = {}
    for rec in st.repaired_records():
        pair = [rec.first, rec.second]
        if (rec.first, rec.second) not in separation:
            separation[rec.first, rec.second] = _separation(st, pair)
        for edge, step in ((rec.stop, 1), (rec.start - 1, -1)):
            frames = _continued(st, pair, edge, step, separation[rec.first, rec.second])
            if frames.size:
                st.exchange(pair, frames)
                st.suspect[frames], st.displaced[frames] = _screen(st.xyz, st.usable, st.refs, frames)
                done[frames] = True
    return done


def _separation(st: _State, pair: list[int]) -> float:
    """The usual distance (mm, median over the frames where both are measured; NaN: never) between the two
    markers of ``pair``: the same whichever name each carries."""
    both = np.flatnonzero(st.usable[:, pair].all(axis=1))
    if both.size == 0:
        return float("nan")
    rows = both[even_rows(both.size, REFERENCE_FRAMES)]
    return float(np.median(norm3(st.xyz[rows, pair[0]] - st.xyz[rows, pair[1]])))


def _continued(st: _State, pair: list[int], edge: int, step: int, separation_mm: float) -> np.ndarray:
    """The frames from ``edge`` on (in direction ``step``) over which the stretch of ``pair`` ending just before
    ``edge`` continues (see :func:`_extend_by_continuity`), looked at a block of frames at a time (a swap ends
    within seconds; the rest of the take is not read). ``separation_mm``: the pair's usual distance."""
    n_t = st.valid.shape[0]
    out: list[np.ndarray] = []
    at = edge
    while 0 <= at < n_t:
        rows = np.arange(at, min(n_t, at + _CONTINUITY_BLOCK) if step > 0 else max(-1, at - _CONTINUITY_BLOCK), step)
        kept = _continued_block(st, pair, rows, step, first=at == edge, separation_mm=separation_mm)
        out.append(kept)
        if kept.size < rows.size:
            break
        at = int(rows[-1]) + step
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


#: frames looked at at a time by :func:`_continued`
_CONTINUITY_BLOCK = 256


def _continued_block(st: _State, pair: list[int], rows: np.ndarray, step: int, first: bool,
                     separation_mm: float) -> np.ndarray:
    """The leading frames of ``rows`` (consecutive, in direction ``step``) that continue the stretch of ``pair``
    (everything before ``rows[0]`` continues it, or, when ``first``, was repaired).

    With both markers measured in the frame and the one before, the exchange must save a clear share of the
    two markers' summed steps. With one of them missing in either frame, each sample that has a position a
    frame before to go on decides alone: a distance to a marker not measured a frame before is bounded below
    by ``separation_mm`` less the sample's distance to the other marker (the two stood that far apart), and
    the frame continues the stretch when one sample is clearly nearer its partner's track than its own and
    none is the other way (a swap does not end because one of its markers is hidden for a while; a sample
    whose partner's track is unknown a frame before says nothing either way)."""
    free = ~(st.repaired[rows[:, None], pair].any(axis=1) | st.removed[rows[:, None], pair].any(axis=1))
    rows = rows[:np.argmin(free)] if not free.all() else rows
    if rows.size == 0:
        return rows
    here, before = st.xyz[rows[:, None], pair], st.xyz[(rows - step)[:, None], pair]    # (n, 2, 3): a, b
    # where each marker truly was a frame before, if the stretch goes on up to there: at the edge, as
    # repaired; beyond it, under the capture's other name
    at_edge = ((np.arange(rows.size) == 0) & first)[:, None]
    prev = np.stack([np.where(at_edge, before[:, 0], before[:, 1]),
                     np.where(at_edge, before[:, 1], before[:, 0])], axis=1)            # (n, 2, 3): a, b
    own = norm3(here - prev)                                 # (n, 2) each sample's step keeping its name
    cross = norm3(here - prev[:, ::-1])                      # (n, 2) its step under the other name
    keep_cost, exchange_cost = own.sum(axis=1), cross.sum(axis=1)
    full = np.isfinite(own).all(axis=1) & np.isfinite(cross).all(axis=1)
    decisive = full & (keep_cost - exchange_cost > np.maximum(CONTINUITY_MARGIN_MM, CONTINUITY_SHARE * keep_cost))
    # one sample, or one position a frame before, missing: each sample on its own, the unknown step bounded
    own_low = np.where(np.isfinite(own), own, separation_mm - cross)
    cross_low = np.where(np.isfinite(cross), cross, separation_mm - own)
    with np.errstate(invalid="ignore"):
        swapped = own_low - cross > np.maximum(CONTINUITY_MARGIN_MM, CONTINUITY_SHARE * own_low)
        kept = cross_low - own > np.maximum(CONTINUITY_MARGIN_MM, CONTINUITY_SHARE * cross_low)
    alone = ~full & swapped.any(axis=1) & ~kept.any(axis=1)
    decisive |= alone
    return rows[:np.argmin(decisive)] if not decisive.all() else rows


def _merged(records: list[SwapRecord]) -> list[SwapRecord]:
    """Records in time order, those of one pair and outcome that touch joined into one."""
    out: list[SwapRecord] = []
    for r in sorted(records, key=lambda r: (r.first, r.second, r.repaired, r.start)):
        last = out[-1] if out else None
        if last and (last.first, last.second, last.repaired) == (r.first, r.second, r.repaired) \
                and r.start <= last.stop:
            out[-1] = SwapRecord(r.first, r.second, last.start, max(last.stop, r.stop), r.repaired)
        else:
            out.append(r)
    return sorted(out, key=lambda r: (r.start, r.first, r.second))


def _records(pair: list[int], frames: np.ndarray, n_t: int, repaired: bool) -> list[SwapRecord]:
    """One record per run of consecutive ``frames``."""
    if frames.size == 0:
        return []
    mark = np.zeros(n_t, dtype=bool)
    mark[frames] = True
    first, second = sorted(pair)
    return [SwapRecord(first, second, int(s), int(e), repaired) for s, e in true_runs(mark)]
