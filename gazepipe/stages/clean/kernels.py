"""The clean stage's compiled kernels: the gap filler's loops over a gap's few samples, markers and candidates, and
the swap references' and swap repair's loops over frames, markers and reference triples, where numpy's per-call
cost (dispatch, temporaries) outweighs the arithmetic.

Each kernel is the one implementation of its step (no numpy twin), compiled as :mod:`gazepipe.stages.jit` says (on
its first call, cached on disk for later processes and workers; ``fastmath`` off). Every operation is written in
the order numpy would do it, so the results are the same bits as the array code they replaced (elementwise
arithmetic; sums in numpy's order where a kernel sums; order statistics as numpy's median and linear quantile
compute them).

This module imports numba, which takes a few tenths of a second: the stage imports it where a kernel is first
needed, so planning a run (which imports the clean stage's parameters) goes without it.

Frames are rows; intervals are half-open ``[start, stop)``; positions are float64 mm.
"""

from __future__ import annotations

import numpy as np

from gazepipe.stages.jit import kernel


@kernel
def _sign(x: float) -> float:
    """``np.sign`` of a float (NaN stays NaN)."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    if x == 0.0:
        return 0.0
    return x


@kernel
def pchip_eval(x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """PCHIP interpolant through knots ``x`` (n,) increasing, values ``y`` (n, k), evaluated at ``t`` (q,) inside
    ``[x[0], x[-1]]``: (q, k).

    The same arithmetic as ``scipy.interpolate.PchipInterpolator(x, y, axis=0)(t)`` (Fritsch–Carlson slopes as a
    weighted harmonic mean, Moler's one-sided three-point end slopes, the cubic Hermite piece evaluated as
    ``c3 + c2 s + c1 s² + c0 s³``), so the results are bit for bit the same, without building a piecewise
    polynomial for every knot when a few pieces are evaluated."""
    n, k = y.shape
    hk = np.empty(n - 1)
    mk = np.empty((n - 1, k))
    for i in range(n - 1):
        hk[i] = x[i + 1] - x[i]
        for c in range(k):
            mk[i, c] = (y[i + 1, c] - y[i, c]) / hk[i]
    dk = np.empty((n, k))
    for c in range(k):
        if n == 2:
            dk[0, c] = mk[0, c]
            dk[1, c] = mk[0, c]
            continue
        for i in range(1, n - 1):
            m0, m1 = mk[i - 1, c], mk[i, c]
            if _sign(m1) != _sign(m0) or m1 == 0.0 or m0 == 0.0:
                dk[i, c] = 0.0
            else:
                w1 = 2.0 * hk[i] + hk[i - 1]
                w2 = hk[i] + 2.0 * hk[i - 1]
                dk[i, c] = 1.0 / ((w1 / m0 + w2 / m1) / (w1 + w2))
        for end in range(2):
            # Moler's end slope: at the first knot from the first two pieces, at the last from the last two
            i, i0, i1 = (0, 0, 1) if end == 0 else (n - 1, n - 2, n - 3)
            h0, h1, m0, m1 = hk[i0], hk[i1], mk[i0, c], mk[i1, c]
            d = ((2.0 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
            if _sign(d) != _sign(m0):
                dk[i, c] = 0.0
            elif _sign(m0) != _sign(m1) and abs(d) > 3.0 * abs(m0):
                dk[i, c] = 3.0 * m0
            else:
                dk[i, c] = d
    out = np.empty((t.size, k))
    for q in range(t.size):
        j = min(max(np.searchsorted(x, t[q], side="right") - 1, 0), n - 2)
        h = hk[j]
        s = t[q] - x[j]
        s2 = s * s
        for c in range(k):
            slope = mk[j, c]
            tt = (dk[j, c] + dk[j + 1, c] - 2.0 * slope) / h
            c0 = tt / h
            c1 = (slope - dk[j, c]) / h - tt
            out[q, c] = ((y[j, c] + dk[j, c] * s) + c1 * s2) + c0 * (s2 * s)
    return out


@kernel
def interp_intervals(xyz_m: np.ndarray, known_m: np.ndarray, starts: np.ndarray, stops: np.ndarray,
                     pchip: bool, n_anchors: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear or PCHIP interpolation of one marker, ``xyz_m`` (T, 3), over each interval ``[starts[i], stops[i])``
    from its samples ``known_m`` (T,): ``(out, good)``, the intervals' predictions one after the other
    (Σ (stop − start), 3) and (K,) whether each has one (a known sample on both sides and none inside; never
    extrapolated in time; NaN rows where not).

    Linear joins the nearest known samples either side; PCHIP runs through the ``n_anchors`` nearest known samples
    on each side (PCHIP is local: the slopes at the interval's two edge knots depend on their neighbours only, so
    the interval gets the same bits as from an interpolant through every known sample). The search for them goes
    outward from the interval and stops at the last anchor: its cost is the distance to them, not the take."""
    n_t = known_m.shape[0]
    n_k = starts.size
    lengths = stops - starts
    out = np.full((lengths.sum(), 3), np.nan)
    good = np.zeros(n_k, dtype=np.bool_)
    knots = np.empty(2 * n_anchors, dtype=np.int64)
    at = 0
    for i in range(n_k):
        a, b = starts[i], stops[i]
        nb = 0
        f = a - 1
        while f >= 0 and nb < n_anchors:
            if known_m[f]:
                nb += 1
                knots[n_anchors - nb] = f
            f -= 1
        na = 0
        f = b
        while f < n_t and na < n_anchors:
            if known_m[f]:
                knots[n_anchors + na] = f
                na += 1
            f += 1
        inside = False
        for f in range(a, b):
            if known_m[f]:
                inside = True
                break
        if nb > 0 and na > 0 and not inside:
            good[i] = True
            t = np.arange(a, b).astype(np.float64)
            if pchip:
                ks = knots[n_anchors - nb:n_anchors + na]
                y = np.empty((ks.size, 3))
                for j in range(ks.size):
                    y[j] = xyz_m[ks[j]]
                out[at:at + b - a] = pchip_eval(ks.astype(np.float64), y, t)
            else:
                t0, t1 = knots[n_anchors - 1], knots[n_anchors]
                for q in range(b - a):
                    w = (t[q] - t0) / (t1 - t0)
                    for c in range(3):
                        out[at + q, c] = (1.0 - w) * xyz_m[t0, c] + w * xyz_m[t1, c]
        at += b - a
    return out, good


# ------------------------------------------------------------------------------------------------ searches

@kernel
def nearest_complete(known_m: np.ndarray, valid: np.ndarray, cols: np.ndarray, starts: np.ndarray,
                     stops: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each interval ``[starts[i], stops[i])``, the nearest frame before it and the nearest at or after its
    end where ``known_m`` (T,) is set and every marker of ``cols`` is measured (``valid`` (T, M)): ``(before,
    after)``, (K,) each, -1 where there is none. The search goes outward from the interval and stops at the first
    such frame."""
    n_t = known_m.shape[0]
    before = np.full(starts.size, -1, dtype=np.int64)
    after = np.full(starts.size, -1, dtype=np.int64)
    for i in range(starts.size):
        f = starts[i] - 1
        while f >= 0:
            if known_m[f] and _all_valid(valid, f, cols):
                before[i] = f
                break
            f -= 1
        f = stops[i]
        while f < n_t:
            if known_m[f] and _all_valid(valid, f, cols):
                after[i] = f
                break
            f += 1
    return before, after


@kernel
def _all_valid(valid: np.ndarray, f: int, cols: np.ndarray) -> bool:
    for c in cols:
        if not valid[f, c]:
            return False
    return True


# ------------------------------------------------------------------------------------------ edge correction

@kernel
def edge_correct(preds: np.ndarray, xyz_m: np.ndarray, lo: np.ndarray, hi: np.ndarray, a: np.ndarray,
                 b: np.ndarray, partial: np.ndarray, known_l: np.ndarray, known_r: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Each of ``preds`` (K, F, 3) corrected to meet the measured marker ``xyz_m`` (T, 3) next to each interval
    ``[a[j], b[j])`` (K intervals' predictions over their spans ``[lo[j], hi[j])`` lie one after the other along
    F): the mismatches at frames ``a - 1`` (where ``known_l``, and predicted) and ``b`` (``known_r``) blended
    linearly across the interval, one of them added throughout when the other is missing. An interval with an
    unpredicted (NaN) frame has none unless ``partial`` (its NaN rows stay NaN), and none with no predicted frame.
    Returns ``(filled (K, Σ (b − a), 3) NaN where none, none (K, J))``: the formulas and order of
    :func:`gazepipe.stages.clean.fill_methods._edge_correct_packed`'s former array code, so the same bits."""
    n_k = preds.shape[0]
    n_j = a.size
    n_t = xyz_m.shape[0]
    filled = np.full((n_k, (b - a).sum(), 3), np.nan)
    none = np.zeros((n_k, n_j), dtype=np.bool_)
    res_l = np.zeros(3)
    res_r = np.zeros(3)
    for k in range(n_k):
        off = 0
        at = 0
        for j in range(n_j):
            n_in = b[j] - a[j]
            first = off + a[j] - lo[j]
            n_bad = 0
            for q in range(n_in):
                if _any_nan(preds, k, first + q):
                    n_bad += 1
            none[k, j] = n_bad == n_in or (n_bad > 0 and not partial[j])
            if not none[k, j]:
                i_l = off + max(a[j] - 1 - lo[j], 0)
                i_r = off + min(b[j] - lo[j], hi[j] - lo[j] - 1)
                ok_l = known_l[j] and not _any_nan(preds, k, i_l) and _all_finite(preds, k, i_l)
                ok_r = known_r[j] and not _any_nan(preds, k, i_r) and _all_finite(preds, k, i_r)
                f_l, f_r = max(a[j] - 1, 0), min(b[j], n_t - 1)
                for c in range(3):
                    res_l[c] = xyz_m[f_l, c] - preds[k, i_l, c] if ok_l else 0.0
                    res_r[c] = xyz_m[f_r, c] - preds[k, i_r, c] if ok_r else 0.0
                for q in range(n_in):
                    w = ((a[j] + q) - (a[j] - 1)) / (b[j] - (a[j] - 1))
                    if not ok_l:
                        w = 1.0
                    elif not ok_r:
                        w = 0.0
                    for c in range(3):
                        filled[k, at + q, c] = (preds[k, first + q, c] + (1.0 - w) * res_l[c]) + w * res_r[c]
            off += hi[j] - lo[j]
            at += n_in
    return filled, none


@kernel
def _any_nan(preds: np.ndarray, k: int, row: int) -> bool:
    return np.isnan(preds[k, row, 0]) or np.isnan(preds[k, row, 1]) or np.isnan(preds[k, row, 2])


@kernel
def _all_finite(preds: np.ndarray, k: int, row: int) -> bool:
    return np.isfinite(preds[k, row, 0]) and np.isfinite(preds[k, row, 1]) and np.isfinite(preds[k, row, 2])


# ----------------------------------------------------------------------------------------- window statistics

@kernel
def distances(xyz: np.ndarray, valid: np.ndarray, own: np.ndarray, m: int, cand: np.ndarray, lo: int, hi: int,
              step: int) -> tuple[np.ndarray, np.ndarray]:
    """The distance (mm) of each marker ``cand[k]`` of ``xyz`` (T, M, 3) to marker ``m`` in frames ``lo, lo +
    step, ... < hi``, and whether both count there (``own`` (T,) set and ``cand[k]`` measured in ``valid``
    (T, M)): ``(d, both)``, (K, frames) each, d 0 where not both. The distance is ``sqrt((dx² + dy²) + dz²)``,
    as :func:`gazepipe.stages.geometry.norm3`; frames read one by one, not gathered into temporaries."""
    n_k = cand.size
    n_f = (hi - lo + step - 1) // step
    d = np.zeros((n_k, n_f))
    both = np.zeros((n_k, n_f), dtype=np.bool_)
    for i in range(n_f):
        f = lo + i * step
        if not own[f]:
            continue
        for k in range(n_k):
            c = cand[k]
            if valid[f, c]:
                dx = xyz[f, c, 0] - xyz[f, m, 0]
                dy = xyz[f, c, 1] - xyz[f, m, 1]
                dz = xyz[f, c, 2] - xyz[f, m, 2]
                d[k, i] = np.sqrt((dx * dx + dy * dy) + dz * dz)
                both[k, i] = True
    return d, both



@kernel
def distance_moments(xyz: np.ndarray, valid: np.ndarray, own: np.ndarray, m: int, cand: np.ndarray, lo: int,
                     hi: int, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each marker ``cand[k]``'s distance to marker ``m`` over the frames of :func:`distances`: how many frames
    count, the mean and the standard deviation (K,) each (NaN with none), summed as numpy sums a contiguous
    row (:func:`_pairwise_sum`), so the bits of the array code's ``sum(axis=0)`` over frames."""
    d, both = distances(xyz, valid, own, m, cand, lo, hi, step)
    n_k, n_f = d.shape
    count = np.zeros(n_k, dtype=np.int64)
    mu = np.empty(n_k)
    sd = np.empty(n_k)
    dev = np.empty(n_f)
    for k in range(n_k):
        for i in range(n_f):
            count[k] += both[k, i]
        mu[k] = _pairwise_sum(d[k], 0, n_f) / count[k]        # d is 0 where not both
        for i in range(n_f):
            dev[i] = (d[k, i] - mu[k]) ** 2 if both[k, i] else 0.0
        sd[k] = np.sqrt(_pairwise_sum(dev, 0, n_f) / count[k])
    return count, mu, sd

# ------------------------------------------------------------------------------------- swap references

@kernel
def _volume_from(o0: float, o1: float, o2: float, xyz: np.ndarray, s: int, a: int, b: int, c: int) -> float:
    """Triple product of the directions from the point ``(o0, o1, o2)`` to markers ``a``, ``b``, ``c`` in frame
    ``s`` of ``xyz`` (S, M, 3), as a share of the product of their lengths (in [−1, 1]; NaN where a length is 0
    or a position NaN): the arithmetic of :func:`gazepipe.stages.clean.swaps._volume`, in its order."""
    u0 = xyz[s, a, 0] - o0
    u1 = xyz[s, a, 1] - o1
    u2 = xyz[s, a, 2] - o2
    v0 = xyz[s, b, 0] - o0
    v1 = xyz[s, b, 1] - o1
    v2 = xyz[s, b, 2] - o2
    w0 = xyz[s, c, 0] - o0
    w1 = xyz[s, c, 1] - o1
    w2 = xyz[s, c, 2] - o2
    det = u0 * (v1 * w2 - v2 * w1) + u1 * (v2 * w0 - v0 * w2) + u2 * (v0 * w1 - v1 * w0)
    return det / np.sqrt((u0 * u0 + u1 * u1 + u2 * u2) * (v0 * v0 + v1 * v1 + v2 * v2)
                         * (w0 * w0 + w1 * w1 + w2 * w2))


@kernel
def triple_volume(xyz: np.ndarray, s: int, origin: int, a: int, b: int, c: int) -> float:
    """:func:`_volume_from` marker ``origin``'s place in frame ``s``."""
    return _volume_from(xyz[s, origin, 0], xyz[s, origin, 1], xyz[s, origin, 2], xyz, s, a, b, c)


@kernel
def _select(values: np.ndarray, n: int, k: int) -> tuple[float, float]:
    """The ``k``-th and ``(k + 1)``-th smallest of ``values[:n]`` (no NaN; the ``k``-th twice when ``k`` is the
    last), ``values[:n]`` reordered in place: a quickselect (Hoare's partition about the median of three),
    then the least of what lies beyond ``k``. An order statistic is one value whatever finds it: the values
    numpy's partition gives."""
    lo, hi = 0, n - 1
    while lo < hi:
        a, b, c = values[lo], values[(lo + hi) // 2], values[hi]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = lo, hi
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break                                   # k among the values equal to the pivot
    kth = values[k]
    nxt = values[k + 1] if k + 1 < n else kth
    for i in range(k + 2, n):
        nxt = min(nxt, values[i])
    return kth, nxt


@kernel
def _median_of(values: np.ndarray, n: int) -> float:
    """Median of the first ``n`` entries of ``values`` (no NaN; reordered in place; NaN when ``n`` is 0): the
    lower and upper middle averaged, as :func:`gazepipe.stages.clean.spikes._sorted_median`."""
    if n == 0:
        return np.nan
    lo, hi = _select(values, n, (n - 1) // 2)
    if n % 2 == 1:
        hi = lo
    return 0.5 * (lo + hi)


@kernel
def _quantile_of(values: np.ndarray, n: int, q: float) -> float:
    """The ``q`` quantile of the first ``n`` entries of ``values`` (no NaN; reordered in place; NaN when ``n``
    is 0): numpy's default (linear) method with its arithmetic, virtual index ``(n − 1) q`` and its two-sided
    interpolation."""
    if n == 0:
        return np.nan
    virtual = (n - 1) * q
    if virtual >= n - 1:
        return np.max(values[:n])
    below = np.floor(virtual)
    i = int(below)
    low, high = _select(values, n, i)                # the two order statistics around the index
    gamma = virtual - below
    diff = high - low
    if gamma >= 0.5:
        return high - diff * (1.0 - gamma)
    return low + diff * gamma


@kernel
def chiral_triples(xyz: np.ndarray, ok: np.ndarray, m: int, twin: int, tri: np.ndarray, q: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How each reference triple ``tri`` (C, 3) columns tells marker ``m`` from its mirror image, over the
    sample frames of ``xyz`` (S, M, 3) where ``ok`` (S, M) has ``m``: per triple, the frames where all four are
    seen, the median of its volume (:func:`triple_volume`) there, the ``q`` quantile of the volume signed by the
    median's sign (how near it comes to turning over) and, where marker ``twin`` (−1: none) is seen in at least
    10 of those frames and is no corner, the ``q`` quantile of the smaller of that signed volume and the twin's
    volume from the same corners, the other way (−inf where it cannot tell). Quantiles and medians leave NaN
    out; each is NaN with no value."""
    n_s = ok.shape[0]
    n_c = tri.shape[0]
    seen = np.zeros(n_c, dtype=np.int64)
    median = np.full(n_c, np.nan)
    low = np.full(n_c, np.nan)
    tells = np.full(n_c, -np.inf)
    rows = np.empty(n_s, dtype=np.int64)
    n_r = 0
    n_twin = 0
    for s in range(n_s):
        if ok[s, m]:
            rows[n_r] = s
            n_r += 1
            if twin >= 0 and ok[s, twin]:
                n_twin += 1
    vol = np.empty(n_r)
    buf = np.empty(n_r)
    both = np.empty(n_r)
    for k in range(n_c):
        a, b, c = tri[k, 0], tri[k, 1], tri[k, 2]
        n_v = 0
        for i in range(n_r):
            s = rows[i]
            if ok[s, a] and ok[s, b] and ok[s, c]:
                seen[k] += 1
                vol[i] = triple_volume(xyz, s, m, a, b, c)
                if not np.isnan(vol[i]):
                    buf[n_v] = vol[i]
                    n_v += 1
            else:
                vol[i] = np.nan
        median[k] = _median_of(buf, n_v)
        sign = _sign(median[k])
        n_v = 0
        for i in range(n_r):
            signed = sign * vol[i]
            if not np.isnan(signed):
                buf[n_v] = signed
                n_v += 1
        low[k] = _quantile_of(buf, n_v, q)
        if twin < 0 or n_twin < 10 or a == twin or b == twin or c == twin:
            continue
        n_b = 0
        for i in range(n_r):
            s = rows[i]
            if not ok[s, twin]:
                continue
            signed = sign * vol[i]
            other = -sign * triple_volume(xyz, s, twin, a, b, c)
            smaller = signed if signed <= other else other
            if not (np.isnan(signed) or np.isnan(other)):
                both[n_b] = smaller
                n_b += 1
        value = _quantile_of(both, n_b, q)
        if np.isfinite(value):
            tells[k] = value
    return seen, median, low, tells


@kernel
def twin_scores(distance_all: np.ndarray, known: np.ndarray, min_references: int) -> np.ndarray:
    """(M, M) how unlike each marker ``m``'s distances to the others (``distance_all`` (M, M) mm, where
    ``known``) are to marker ``q``'s: the median absolute difference of the two sorted (over the markers
    known from both, neither of the two), inf where fewer than ``min_references`` are (or ``q`` not known from
    ``m``). :func:`gazepipe.stages.clean.swaps._twins`' score, with numpy's median."""
    n_m = distance_all.shape[0]
    score = np.full((n_m, n_m), np.inf)
    mine = np.empty(n_m)
    theirs = np.empty(n_m)
    for m in range(n_m):
        for q in range(n_m):
            if not known[m, q]:
                continue
            n = 0
            for j in range(n_m):
                if known[m, j] and known[q, j] and j != m and j != q:
                    mine[n] = distance_all[m, j]
                    theirs[n] = distance_all[q, j]
                    n += 1
            if n < min_references:
                continue
            a = np.sort(mine[:n])
            b = np.sort(theirs[:n])
            for i in range(n):
                a[i] = np.abs(a[i] - b[i])
            score[m, q] = _median_of(a, n)
    return score


@kernel
def _is_flipped(p0: float, p1: float, p2: float, xyz: np.ndarray, valid: np.ndarray, s: int, tri: np.ndarray,
                hand: np.ndarray, exclude: int, clear: float) -> bool:
    """Whether the point ``(p0, p1, p2)`` in frame ``s`` turns more of the chiral triples ``tri`` (J, 3) (−1:
    none; those with ``exclude`` for a corner, with no handedness, or not all measured in ``valid`` are left
    out) against their handedness ``hand`` (J,), by a volume of at least ``clear``, than it leaves with it."""
    turned = 0
    kept = 0
    for j in range(tri.shape[0]):
        a, b, c = tri[j, 0], tri[j, 1], tri[j, 2]
        if a < 0 or b < 0 or c < 0 or hand[j] == 0.0 or a == exclude or b == exclude or c == exclude:
            continue
        if not (valid[s, a] and valid[s, b] and valid[s, c]):
            continue
        vol = _volume_from(p0, p1, p2, xyz, s, a, b, c)
        sign = _sign(vol)
        if np.abs(vol) >= clear and sign == -hand[j]:
            turned += 1
        if sign == hand[j]:
            kept += 1
    return turned > kept


@kernel
def flipped(points: np.ndarray, xyz: np.ndarray, valid: np.ndarray, as_marker: np.ndarray, exclude: np.ndarray,
            chiral: np.ndarray, hand: np.ndarray, clear: float) -> np.ndarray:
    """(n, C) bool: ``points`` (n, C, 3) judged as markers ``as_marker`` (C,) turn more of their chiral triples
    (``chiral`` (M, J, 3), ``hand`` (M, J); none with ``exclude[c]`` for a corner, −1: none) against their
    handedness than they leave with it, in the frames of ``xyz`` (n, M, 3) where ``valid`` (n, M)."""
    n, n_c = points.shape[0], points.shape[1]
    out = np.zeros((n, n_c), dtype=np.bool_)
    for s in range(n):
        for c in range(n_c):
            mk = as_marker[c]
            out[s, c] = _is_flipped(points[s, c, 0], points[s, c, 1], points[s, c, 2], xyz, valid, s,
                                    chiral[mk], hand[mk], exclude[c], clear)
    return out


@kernel
def _deviations_at(p0: float, p1: float, p2: float, xyz: np.ndarray, valid: np.ndarray, s: int, mk: int,
                   exclude: int, index: np.ndarray, distance: np.ndarray, spread: np.ndarray, dev: np.ndarray
                   ) -> int:
    """The finite deviations ``|d − distance| / spread`` of the point ``(p0, p1, p2)`` in frame ``s`` judged as
    marker ``mk`` against its references (``index`` (M, K), −1: none; ``exclude`` left out) measured there
    (``valid``), into ``dev[:count]`` in reference order; returns ``count``. ``d`` as
    :func:`gazepipe.stages.geometry.norm3` computes it."""
    count = 0
    for k in range(index.shape[1]):
        r = index[mk, k]
        if r < 0 or r == exclude or not valid[s, r]:
            continue
        dx = p0 - xyz[s, r, 0]
        dy = p1 - xyz[s, r, 1]
        dz = p2 - xyz[s, r, 2]
        e = np.abs(np.sqrt((dx * dx + dy * dy) + dz * dz) - distance[mk, k]) / spread[mk, k]
        if np.isfinite(e):
            dev[count] = e
            count += 1
    return count


@kernel
def _lower_median(dev: np.ndarray, count: int) -> float:
    """The lower median of ``dev[:count]`` (finite, ``count`` ≥ 1): the value of rank ``(count − 1) // 2``,
    chosen by counting ranks (:func:`_rank_select`: a handful of values, no branch on the data, which a sort
    mispredicts)."""
    return _rank_select(dev, count, (count - 1) // 2)


@kernel
def _largest(dev: np.ndarray, count: int) -> float:
    """The largest of ``dev[:count]`` (finite, ``count`` ≥ 1)."""
    out = dev[0]
    for i in range(1, count):
        out = max(out, dev[i])
    return out


@kernel
def misfits(points: np.ndarray, xyz: np.ndarray, valid: np.ndarray, as_marker: np.ndarray, exclude: np.ndarray,
            index: np.ndarray, distance: np.ndarray, spread: np.ndarray, chiral: np.ndarray, hand: np.ndarray,
            min_references: int, clear: float) -> tuple[np.ndarray, np.ndarray]:
    """The largest and the lower-median deviation (n, C) of ``points`` (n, C, 3), each judged as marker
    ``as_marker[c]`` against its references (``index`` (M, K) columns, −1: none; their ``distance`` and
    ``spread`` (M, K) mm; ``exclude[c]`` left out) measured in the same frame of ``xyz`` (n, M, 3) where
    ``valid`` (n, M): ``|d − distance| / spread``, the point's distance ``d`` to each reference as
    :func:`gazepipe.stages.geometry.norm3` computes it. The largest is inf where the point is :func:`flipped`;
    both NaN with fewer than ``min_references`` deviations."""
    n, n_c = points.shape[0], points.shape[1]
    worst = np.full((n, n_c), np.nan)
    median = np.full((n, n_c), np.nan)
    dev = np.empty(index.shape[1])
    for s in range(n):
        for c in range(n_c):
            mk = as_marker[c]
            p0, p1, p2 = points[s, c, 0], points[s, c, 1], points[s, c, 2]
            count = _deviations_at(p0, p1, p2, xyz, valid, s, mk, exclude[c], index, distance, spread, dev)
            if count < min_references:
                continue
            median[s, c] = _lower_median(dev, count)
            worst[s, c] = _largest(dev, count)
            if _is_flipped(p0, p1, p2, xyz, valid, s, chiral[mk], hand[mk], exclude[c], clear):
                worst[s, c] = np.inf
    return worst, median


@kernel
def screen(xyz: np.ndarray, judged: np.ndarray, valid: np.ndarray, rows: np.ndarray, index: np.ndarray,
           distance: np.ndarray, spread: np.ndarray, chiral: np.ndarray, hand: np.ndarray, tolerance: np.ndarray,
           min_references: int, clear: float) -> tuple[np.ndarray, np.ndarray]:
    """(suspect, displaced) (n, M) bool in frames ``rows`` (n,) of ``xyz`` (T, M, 3): each ``judged`` (T, M)
    sample whose :func:`misfits` against its own marker's references measured in ``valid`` (T, M), largest
    or lower median, is above its marker's ``tolerance`` (M,). The same decisions as comparing
    :func:`misfits` with the tolerances, without judging what cannot be suspect (a sample not judged, a
    marker of infinite tolerance) nor the handedness of a sample already suspect by a distance."""
    n, n_m = rows.size, judged.shape[1]
    suspect = np.zeros((n, n_m), dtype=np.bool_)
    displaced = np.zeros((n, n_m), dtype=np.bool_)
    dev = np.empty(index.shape[1])
    for i in range(n):
        s = rows[i]
        for c in range(n_m):
            tol = tolerance[c]
            if not judged[s, c] or tol == np.inf:
                continue
            p0, p1, p2 = xyz[s, c, 0], xyz[s, c, 1], xyz[s, c, 2]
            count = _deviations_at(p0, p1, p2, xyz, valid, s, c, -1, index, distance, spread, dev)
            if count < min_references:
                continue
            displaced[i, c] = _lower_median(dev, count) > tol
            suspect[i, c] = _largest(dev, count) > tol or _is_flipped(p0, p1, p2, xyz, valid, s, chiral[c],
                                                                        hand[c], -1, clear)
    return suspect, displaced


@kernel
def _hand_kept_at(p0: float, p1: float, p2: float, xyz: np.ndarray, valid: np.ndarray, s: int, tri: np.ndarray,
                  hand: np.ndarray, clear: float) -> bool:
    """Whether the point ``(p0, p1, p2)`` in frame ``s`` leaves one of the chiral triples ``tri`` (J, 3) (−1:
    none; those without a handedness ``hand`` (J,) left out) with all three corners measured in ``valid`` with
    its handedness, by a volume of at least ``clear``."""
    for j in range(tri.shape[0]):
        a, b, c = tri[j, 0], tri[j, 1], tri[j, 2]
        if a < 0 or b < 0 or c < 0 or hand[j] == 0.0:
            continue
        if not (valid[s, a] and valid[s, b] and valid[s, c]):
            continue
        vol = _volume_from(p0, p1, p2, xyz, s, a, b, c)
        if np.abs(vol) >= clear and _sign(vol) == hand[j]:
            return True
    return False


@kernel
def vouched(xyz: np.ndarray, seen: np.ndarray, cols: np.ndarray, pair: np.ndarray, index: np.ndarray,
            distance: np.ndarray, spread: np.ndarray, chiral: np.ndarray, hand: np.ndarray, tolerance: np.ndarray,
            min_references: int, clear: float, steady_mm: float) -> np.ndarray:
    """(n, K) bool: the markers ``cols`` (K,) that their references ``seen`` (n, M) in each frame of ``xyz``
    (n, M, 3) put where they are: their largest :func:`misfits` there at most their ``tolerance`` (not
    suspect by distance nor handedness), and either within tolerance (``|d − distance| ≤ tolerance ×
    spread``) of at least ``min_references`` seen references whose spread is at most ``steady_mm`` and that
    are neither marker of ``pair``, or with one chiral triple seen and kept (:func:`_hand_kept_at`).
    :func:`gazepipe.stages.clean.swaps._vouched_for`'s test, frame by frame."""
    n, n_k = seen.shape[0], cols.size
    out = np.zeros((n, n_k), dtype=np.bool_)
    dev = np.empty(index.shape[1])
    for s in range(n):
        for k in range(n_k):
            mk = cols[k]
            tol = tolerance[mk]
            p0, p1, p2 = xyz[s, mk, 0], xyz[s, mk, 1], xyz[s, mk, 2]
            count = _deviations_at(p0, p1, p2, xyz, seen, s, mk, -1, index, distance, spread, dev)
            if count < min_references or not _largest(dev, count) <= tol:
                continue
            if tol != np.inf and _is_flipped(p0, p1, p2, xyz, seen, s, chiral[mk], hand[mk], -1, clear):
                continue                                  # its largest misfit inf: beyond a finite tolerance
            placed = 0
            for r in range(index.shape[1]):
                ref = index[mk, r]
                if ref < 0 or not spread[mk, r] <= steady_mm or ref == pair[0] or ref == pair[1] or not seen[s, ref]:
                    continue
                dx = p0 - xyz[s, ref, 0]
                dy = p1 - xyz[s, ref, 1]
                dz = p2 - xyz[s, ref, 2]
                d = np.sqrt((dx * dx + dy * dy) + dz * dz)
                if np.abs(d - distance[mk, r]) <= tol * spread[mk, r]:
                    placed += 1
            out[s, k] = placed >= min_references or _hand_kept_at(p0, p1, p2, xyz, seen, s, chiral[mk], hand[mk],
                                                                  clear)
    return out


# ------------------------------------------------------------------------------------- rest speed and spikes

@kernel
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:
    """Sum of ``a[lo:lo + n]``, ``n`` at most 128, in numpy's order: one accumulator below 8 values, else eight
    (one per position modulo 8) joined pairwise, then the rest one by one."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@kernel
def _pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:
    """Sum of ``a[lo:lo + n]`` in numpy's pairwise order (:func:`_block_sum` over blocks of up to 128; a longer
    stretch halved, the first half a multiple of 8, and the halves' sums added): the bits ``np.sum`` gives
    along a contiguous axis. The halving tree is walked with explicit stacks (a recursive kernel cannot be
    cached)."""
    if n <= 128:
        return _block_sum(a, lo, n)
    seg_lo = np.empty(128, dtype=np.int64)
    seg_n = np.empty(128, dtype=np.int64)
    split = np.zeros(128, dtype=np.bool_)            # a stretch whose halves are summed: add them
    sums = np.empty(128)
    top, n_sums = 1, 0
    seg_lo[0], seg_n[0] = lo, n
    while top > 0:
        top -= 1
        at, size = seg_lo[top], seg_n[top]
        if split[top]:
            sums[n_sums - 2] = sums[n_sums - 2] + sums[n_sums - 1]
            n_sums -= 1
        elif size <= 128:
            sums[n_sums] = _block_sum(a, at, size)
            n_sums += 1
        else:
            half = size // 2
            half -= half % 8
            split[top] = True                          # after both halves
            seg_lo[top + 1], seg_n[top + 1], split[top + 1] = at + half, size - half, False
            seg_lo[top + 2], seg_n[top + 2], split[top + 2] = at, half, False
            top += 3
    return sums[0]


@kernel
def onset_fit(shapes: np.ndarray, amp: np.ndarray, noise_sq: float, still: float, y: np.ndarray
              ) -> tuple[int, int, int]:
    """The exhaustive least-squares fit of :func:`gazepipe.stages.clean.rests.refine_onset`: of every onset
    shape ``shapes`` (K, T0, F) (each τ's smoothed shape at each onset t0, at the F fitted frames) times every
    amplitude ``amp`` (A,) (mm/s), the one whose speed ``√(g² + noise_sq) + still`` is nearest ``y`` (F,) mm/s in
    squared error (summed in numpy's order). Returns its (shape, amplitude, onset) indices, the first in that
    order at the least error (0, 0, 0 when none is finite)."""
    n_k, n_t0, n_f = shapes.shape
    best, bk, ba, bt = np.inf, 0, 0, 0
    buf = np.empty(n_f)
    for k in range(n_k):
        for ia in range(amp.size):
            a = amp[ia]
            for it in range(n_t0):
                for f in range(n_f):
                    g = a * shapes[k, it, f]
                    v = (np.sqrt(g * g + noise_sq) + still) - y[f]
                    buf[f] = v * v
                sse = _pairwise_sum(buf, 0, n_f)
                if sse < best:
                    best, bk, ba, bt = sse, k, ia, it
    return bk, ba, bt


@kernel
def _sorted_middle(buf: np.ndarray, w: int, min_count: int) -> tuple[float, int]:
    """:func:`_nan_median_of` by sorting ``buf[:w]`` in place by insertion, NaN last (numpy's order: ``a < b``,
    or ``b`` NaN and ``a`` not), and averaging the two middle values of the finite count."""
    for i in range(1, w):
        v = buf[i]
        j = i
        while j > 0 and (v < buf[j - 1] or (buf[j - 1] != buf[j - 1] and v == v)):
            buf[j] = buf[j - 1]
            j -= 1
        buf[j] = v
    count = 0
    for i in range(w):
        if np.isfinite(buf[i]):
            count += 1
    lo = buf[max(count - 1, 0) // 2]
    hi = lo if (w == 1 or count % 2 == 1) else buf[count // 2]
    if count < max(min_count, 1):
        return np.nan, count
    return 0.5 * (lo + hi), count


@kernel
def _nan_median_of(buf: np.ndarray, w: int, min_count: int) -> tuple[float, int]:
    """Median of the finite values among ``buf[:w]`` (a short window, reordered in place; NaN left out) and
    their count: the two middle values of the window sorted NaN last, averaged as
    :func:`gazepipe.stages.clean.spikes._sorted_median` does; NaN with fewer than ``max(min_count, 1)`` finite
    values. Without an infinite value the two middle values are found by counting ranks among the finite
    values (no branch on the data, which a sort mispredicts); with one, by sorting (:func:`_sorted_middle`)."""
    for i in range(w):
        if np.isinf(buf[i]):
            return _sorted_middle(buf, w, min_count)
    count = 0
    for i in range(w):
        v = buf[i]
        if v == v:
            buf[count] = v                         # the finite values first
            count += 1
    if count < max(min_count, 1):
        return np.nan, count
    lo_rank, hi_rank = (count - 1) // 2, count // 2
    lo, hi = buf[0], buf[0]
    for i in range(count):
        rank = 0
        for j in range(count):
            rank += (buf[j] < buf[i]) | ((buf[j] == buf[i]) & (j < i))
        lo = buf[i] if rank == lo_rank else lo
        hi = buf[i] if rank == hi_rank else hi
    return 0.5 * (lo + hi), count


@kernel
def nan_medians(lines: np.ndarray, min_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Median (NaN left out) and finite count of each row of ``lines`` (N, W) (:func:`_nan_median_of`)."""
    n, w = lines.shape
    med = np.empty(n)
    count = np.empty(n, dtype=np.int64)
    buf = np.empty(w)
    for i in range(n):
        buf[:] = lines[i]
        med[i], count[i] = _nan_median_of(buf, w, min_count)
    return med, count


@kernel
def _rank_select(buf: np.ndarray, w: int, rank: int) -> float:
    """The value of ``rank`` (0: the smallest) among ``buf[:w]`` (no NaN), by counting ranks."""
    out = buf[0]
    for i in range(w):
        r = 0
        for j in range(w):
            r += (buf[j] < buf[i]) | ((buf[j] == buf[i]) & (j < i))
        out = buf[i] if r == rank else out
    return out


@kernel
def _judged_steps(xyz: np.ndarray, present: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The frames ``t`` (n,) where at least two of the markers ``cols`` (K,) are ``present`` at ``t`` and
    ``t + 1``, and those markers' steps from ``t`` to ``t + 1`` there (n, K, 3) mm (NaN where not both)."""
    n_t, n_k = xyz.shape[0], cols.size
    rows = np.empty(max(n_t - 1, 0), dtype=np.int64)
    n = 0
    for t in range(n_t - 1):
        seen = 0
        for k in range(n_k):
            seen += present[t + 1, cols[k]] and present[t, cols[k]]
        if seen >= 2:
            rows[n] = t
            n += 1
    step = np.full((n, n_k, 3), np.nan)
    for i in range(n):
        t = rows[i]
        for k in range(n_k):
            c = cols[k]
            if present[t + 1, c] and present[t, c]:
                for d in range(3):
                    step[i, k, d] = xyz[t + 1, c, d] - xyz[t, c, d]
    return rows[:n], step


@kernel
def _median_steps(step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of ``step`` (n, K, 3), the component-wise median step (n, 3) and the median step length (n,)
    over the markers (NaN left out; lengths as ``np.linalg.norm`` computes them)."""
    n, n_k = step.shape[0], step.shape[1]
    med = np.empty((n, 3))
    length = np.empty(n)
    buf = np.empty(n_k)
    for i in range(n):
        for d in range(3):
            for k in range(n_k):
                buf[k] = step[i, k, d]
            med[i, d] = _nan_median_of(buf, n_k, 1)[0]
        for k in range(n_k):
            s0, s1, s2 = step[i, k, 0], step[i, k, 1], step[i, k, 2]
            buf[k] = np.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
        length[i] = _nan_median_of(buf, n_k, 1)[0]
    return med, length


@kernel
def cluster_jumps(xyz: np.ndarray, present: np.ndarray, cols: np.ndarray, jump_mm: float, spread: float,
                  side: int) -> np.ndarray:
    """(T, K) bool: the samples of the cluster's markers ``cols`` (K,) whose step from the frame before
    departs from the cluster's median step by more than ``jump_mm + spread ×`` its step length
    (:func:`gazepipe.stages.clean.rests.position_jumps`): over the frames where at least two of them are
    ``present`` in both (:func:`_judged_steps`), the median step and step length (:func:`_median_steps`), that
    length's running median over ``side`` frames each side of those frames (the ends repeated, as
    ``scipy.ndimage.median_filter(mode="nearest")``), and each sample's distance from the median step (NaN
    as 0, inf as the largest float: ``np.nan_to_num``). Positions (T, M, 3) mm."""
    out = np.zeros((xyz.shape[0], cols.size), dtype=np.bool_)
    rows, step = _judged_steps(xyz, present, cols)
    med, length = _median_steps(step)
    n, w = rows.size, 2 * side + 1
    buf = np.empty(w)
    for i in range(n):
        for j in range(w):
            buf[j] = length[min(max(i + j - side, 0), n - 1)]
        bound = jump_mm + spread * _rank_select(buf, w, side)
        for k in range(cols.size):
            if not (present[rows[i] + 1, cols[k]] and present[rows[i], cols[k]]):
                continue
            e0, e1, e2 = step[i, k, 0] - med[i, 0], step[i, k, 1] - med[i, 1], step[i, k, 2] - med[i, 2]
            dev = np.sqrt((e0 * e0 + e1 * e1) + e2 * e2)
            if np.isnan(dev):
                dev = 0.0
            elif dev == np.inf:
                dev = 1.7976931348623157e308
            out[rows[i] + 1, k] = dev > bound
    return out


@kernel
def pair_distances(xyz: np.ndarray, valid: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(T, P) the distance (mm) in each frame of ``xyz`` (T, M, 3) between markers ``first[p]`` and
    ``second[p]``, NaN where either is not ``valid`` (T, M); as :func:`gazepipe.stages.geometry.norm3`
    computes it."""
    n_t, n_p = valid.shape[0], first.size
    out = np.empty((n_t, n_p))
    for t in range(n_t):
        for p in range(n_p):
            i, j = first[p], second[p]
            if valid[t, i] and valid[t, j]:
                dx = xyz[t, i, 0] - xyz[t, j, 0]
                dy = xyz[t, i, 1] - xyz[t, j, 1]
                dz = xyz[t, i, 2] - xyz[t, j, 2]
                out[t, p] = np.sqrt((dx * dx + dy * dy) + dz * dz)
            else:
                out[t, p] = np.nan
    return out


@kernel
def least_pair_deviation(pairs: np.ndarray, typical: np.ndarray, first: np.ndarray, second: np.ndarray,
                         n_k: int) -> np.ndarray:
    """(T, K) for each of ``n_k`` markers, the smallest ``|pairs − typical|`` (``pairs`` (T, P) between markers
    ``first[p]`` and ``second[p]``, 0 ≤ index < K; NaN left out) over the pairs it is in, NaN where fewer than
    two of those are finite: :func:`gazepipe.stages.clean.spikes.cluster_deviation`'s reduction."""
    n_t, n_p = pairs.shape
    out = np.empty((n_t, n_k))
    best = np.empty(n_k)
    count = np.empty(n_k, dtype=np.int64)
    for t in range(n_t):
        best[:] = np.nan
        count[:] = 0
        for p in range(n_p):
            e = np.abs(pairs[t, p] - typical[p])
            if e != e:
                continue
            for end in (first[p], second[p]):
                if best[end] != best[end] or e < best[end]:
                    best[end] = e
                if np.isfinite(e):
                    count[end] += 1
        for k in range(n_k):
            out[t, k] = best[k] if count[k] >= 2 else np.nan
    return out


@kernel
def _nan_min(a: float, b: float) -> float:
    """``np.minimum`` of two floats (NaN wins)."""
    return a if (a < b or a != a) else b


@kernel
def _nan_max(a: float, b: float) -> float:
    """``np.maximum`` of two floats (NaN wins)."""
    return a if (a > b or a != a) else b


@kernel
def running_medians(padded: np.ndarray, half: int, min_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Median (NaN left out) and finite count over the ``2·half + 1`` rows of ``padded`` (T + 2·half, K) from
    each row on: (T, K) each (:func:`_nan_median_of`). Five-row windows take a min/max network first (the sort
    where it gives no finite value), as the
    array code did (median3 of the fifth value and the max of the pairs' minima and the min of their maxima)."""
    n = padded.shape[0] - 2 * half
    k_cols = padded.shape[1]
    w = 2 * half + 1
    med = np.empty((max(n, 0), k_cols))
    count = np.empty((max(n, 0), k_cols), dtype=np.int64)
    buf = np.empty(w)
    for t in range(n):
        for k in range(k_cols):
            if w == 5:
                a, b, c, d, e = padded[t, k], padded[t + 1, k], padded[t + 2, k], padded[t + 3, k], padded[t + 4, k]
                f = _nan_max(_nan_min(a, b), _nan_min(c, d))
                g = _nan_min(_nan_max(a, b), _nan_max(c, d))
                fast = _nan_max(_nan_min(f, g), _nan_min(e, _nan_max(f, g)))
                if np.isfinite(fast):
                    med[t, k], count[t, k] = fast, 5
                    continue
            for i in range(w):
                buf[i] = padded[t + i, k]
            med[t, k], count[t, k] = _nan_median_of(buf, w, min_count)
    return med, count


@kernel
def pair_distance_stats(xyz: np.ndarray, ok: np.ndarray, body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The median (mm) and the spread (1.4826 × the median absolute deviation, mm) over the frames of ``xyz``
    (S, M, 3) of each body marker's distance to every other body marker (``body`` (M,) bool), from the frames
    where ``ok`` (S, M) has both: (M, M) each, row ``m`` for the distances from marker ``m``, NaN where fewer
    than ``max(10, half of m's frames)`` such frames hold a finite distance (or where a marker is no body
    marker, and on the diagonal). Distances as :func:`gazepipe.stages.geometry.norm3` computes it: the same
    bits from either end, so each pair is measured once and its statistics given to both ends that have
    enough frames."""
    n_s, n_m = ok.shape
    median = np.full((n_m, n_m), np.nan)
    spread = np.full((n_m, n_m), np.nan)
    buf = np.empty(n_s)
    need = np.empty(n_m, dtype=np.int64)
    for m in range(n_m):
        need[m] = max(10, int(np.count_nonzero(ok[:, m])) // 2)
    for m in range(n_m):
        if not body[m]:
            continue
        for j in range(m + 1, n_m):
            if not body[j]:
                continue
            n = 0
            for s in range(n_s):
                if ok[s, m] and ok[s, j]:
                    dx = xyz[s, m, 0] - xyz[s, j, 0]
                    dy = xyz[s, m, 1] - xyz[s, j, 1]
                    dz = xyz[s, m, 2] - xyz[s, j, 2]
                    d = np.sqrt((dx * dx + dy * dy) + dz * dz)
                    if np.isfinite(d):
                        buf[n] = d
                        n += 1
            if n < need[m] and n < need[j]:
                continue
            mid = _median_of(buf, n)
            for i in range(n):
                buf[i] = np.abs(buf[i] - mid)
            mad = 1.4826 * _median_of(buf, n)
            if n >= need[m]:
                median[m, j], spread[m, j] = mid, mad
            if n >= need[j]:
                median[j, m], spread[j, m] = mid, mad
    return median, spread


# ------------------------------------------------------------------------------------------- take statistics

@kernel
def step_statistics(xyz: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each marker's steps (mm) between consecutive frames where ``valid`` (T, M) holds in both: their count
    (M,), their 99th percentile (M,; numpy's linear method; NaN with fewer than 10) and their largest (M,; 0 with
    none). A step is ``sqrt((dx² + dy²) + dz²)``, as :func:`gazepipe.stages.geometry.norm3`."""
    n_t, n_m = valid.shape
    count = np.zeros(n_m, dtype=np.int64)
    p99 = np.full(n_m, np.nan)
    top = np.zeros(n_m)
    steps = np.empty(max(n_t - 1, 0))
    for m in range(n_m):
        n = 0
        for f in range(n_t - 1):
            if valid[f, m] and valid[f + 1, m]:
                dx = xyz[f + 1, m, 0] - xyz[f, m, 0]
                dy = xyz[f + 1, m, 1] - xyz[f, m, 1]
                dz = xyz[f + 1, m, 2] - xyz[f, m, 2]
                steps[n] = np.sqrt((dx * dx + dy * dy) + dz * dz)
                n += 1
        count[m] = n
        if n:
            top[m] = np.max(steps[:n])
        if n >= 10:
            p99[m] = _quantile_of(steps, n, 0.99)
    return count, p99, top


@kernel
def third_difference_mads(xyz: np.ndarray, valid: np.ndarray, step: int, min_frames: int) -> np.ndarray:
    """Each marker's median absolute deviation (unscaled, mm) per axis, (M, 3), of its third differences
    ``((x₃ − 3 x₂) + 3 x₁) − x₀`` over the runs of four measured frames starting at frames ``0, step, 2 step, …
    < T − 3``; NaN where fewer than ``min_frames`` runs. Medians as numpy's."""
    n_t, n_m = valid.shape
    out = np.full((n_m, 3), np.nan)
    if n_t < 4:
        return out
    n_f = (n_t - 3 + step - 1) // step
    d = np.empty(n_f)
    for m in range(n_m):
        for c in range(3):
            n = 0
            for i in range(n_f):
                f = i * step
                if valid[f, m] and valid[f + 1, m] and valid[f + 2, m] and valid[f + 3, m]:
                    d[n] = ((xyz[f + 3, m, c] - 3.0 * xyz[f + 2, m, c]) + 3.0 * xyz[f + 1, m, c]) - xyz[f, m, c]
                    n += 1
            if n < min_frames:
                break
            med = _median_of(d, n)
            for i in range(n):
                d[i] = abs(d[i] - med)
            out[m, c] = _median_of(d, n)
    return out
