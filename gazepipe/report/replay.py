"""A take's 3D replay: what the page shows, prepared from the take's tables and QC records (pure numpy here; the
Plotly figure and the page are :mod:`gazepipe.report.replay_page`).

- **Where**: the cleaned markers' own axes (millimetres, lab axes with the root marker at the origin: the
  clean stage's stabilisation), where the datasets are computed. The raw capture is brought there frame by
  frame by the shift (and, with ``clean.remove_heading``, the turn) that the stabilisation applied, measured
  on the samples that are the same in both tables; outside the crop, by the raw root marker.
- **How each sample was made** (:func:`sample_categories`): the cleaned table's ``fill`` code, a removed spike
  (``spike``: the sample was refilled) or unfilled (``valid`` false: drawn where the marker was last seen).
- **The worst moments** (:func:`worst_moments`): the largest estimated fill errors, the segment rotations
  filled across gaps, the label swaps, the stretches of kept frames that give no dataset row (with why) and
  the largest removed spike; each names the frame the page jumps to.
- **Which frames** (:func:`choose_frames`): a regular stride over the whole take, and every frame of a short
  window around each worst moment.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gazepipe.model import FILL_CODES, FILL_NAMES, Markers, MarkerSet

#: the sample categories the page colours, in legend order: the fill codes (:data:`gazepipe.model.FILL_CODES`),
#: then a removed spike (refilled)
CATEGORIES: tuple[str, ...] = (*FILL_NAMES, "spike")
SPIKE = len(FILL_NAMES)
UNFILLED = FILL_CODES["unfilled"]
MEASURED = FILL_CODES["measured"]

#: half a worst moment's full-rate window, seconds (at most :data:`WINDOW_MAX_FRAMES` frames a side)
WINDOW_S = 0.4
WINDOW_MAX_FRAMES = 24
#: frames a replay starts with: the stride is chosen so the take and the windows fit in about this many
MAX_FRAMES = 600


class ReplayUnavailable(Exception):
    """A take with nothing to replay (no raw markers, its clean stage failed...): ``str()`` says why."""


@dataclass(frozen=True)
class Moment:
    """One of a take's worst moments: what (``kind``), the frame to look at and a label naming both."""

    kind: str       # fill_error | rotation | swap | no_row | spike
    frame: int      # the take's frame (0-based row of its capture, the tables' ``frame`` column)
    label: str
    detail: str = ""


@dataclass
class ReplayInputs:
    """What a take's replay is made from (arrays of its tables, facts of its QC records, its markerset).

    ``raw``: the whole take as captured (markers_raw); ``clean``: the kept frames (markers table: stabilised,
    cropped), its take frame numbers ``clean_frames`` and per sample ``fill`` (codes), ``spike``,
    ``fill_error_mm``. ``joints``: the frames stage's columns used (``frame``, ``char_rot``, ``char_origin``,
    ``quat`` (N, S, 4), ``head_centre``, ``target_dir``, ``rot_filled``), or ``None``. ``swaps``: (marker a,
    marker b, start, stop, repaired) in take frames; ``rotation_errors``: (segment index, first take frame,
    stop, method, error_deg) of the filled rotation gaps. ``feeds``: whether its frames give dataset rows
    (gaze_follow and gaze_shift takes); ``needs_target``: whether a row needs the target direction
    (gaze_follow)."""

    key: str
    kind: str
    markerset: MarkerSet
    raw: Markers
    clean: Markers
    clean_frames: np.ndarray
    fill: np.ndarray
    spike: np.ndarray
    fill_error_mm: np.ndarray
    crop: tuple[int, int]
    swaps: list[tuple[str, str, int, int, bool]] = field(default_factory=list)
    joints: dict[str, np.ndarray] | None = None
    rotation_errors: list[tuple[int, int, int, str | None, float | None]] = field(default_factory=list)
    heading_removed: bool = False
    feeds: bool = True
    needs_target: bool = False


# ------------------------------------------------------------------------------------------- the samples

def sample_categories(fill: np.ndarray, spike: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(T, M) index into :data:`CATEGORIES` of each cleaned sample: unfilled where not valid, else a removed
    spike where ``spike``, else its fill code."""
    cat = np.asarray(fill, dtype=np.int8).copy()
    cat[np.asarray(spike, dtype=bool)] = SPIKE
    cat[~np.asarray(valid, dtype=bool)] = UNFILLED
    return cat


def last_seen(valid: np.ndarray) -> np.ndarray:
    """(T, M) the row each sample is drawn from: its own where valid, else the marker's last valid row before
    (the first after, before its first valid sample; -1 for a marker never valid)."""
    T = valid.shape[0]
    rows = np.arange(T)[:, None]
    before = np.where(valid, rows, -1)
    np.maximum.accumulate(before, axis=0, out=before)
    after = np.where(valid, rows, T)
    after = np.minimum.accumulate(after[::-1], axis=0)[::-1]
    return np.where(before >= 0, before, np.where(after < T, after, -1))


def _interp_rows(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """(T, K) ``values`` with the rows not ``known`` interpolated linearly between known ones (held at the
    ends)."""
    out = values.copy()
    k = np.flatnonzero(known)
    t = np.arange(len(values))
    for j in range(values.shape[1]):
        out[:, j] = np.interp(t, k, values[k, j])
    return out


def raw_transform(inp: ReplayInputs) -> tuple[np.ndarray | None, np.ndarray]:
    """How each raw frame moves into the cleaned markers' axes: ``(rot, shift)``, cleaned = rot · raw + shift,
    ``rot`` (T, 3, 3) or ``None`` (no turn: the heading was not removed), ``shift`` (T, 3).

    Inside the crop it is measured on the markers whose cleaned sample is measured and raw sample valid (the
    same sample in both tables): their mean shift, or with the heading removed a rigid fit of them. Outside the
    crop (no cleaned frame) the raw root marker goes to the origin, turned as the nearest fitted frame. Frames
    where neither tells are interpolated from their neighbours (NaN when no frame tells).
    """
    raw, clean = inp.raw, inp.clean
    T = raw.n_frames
    shift = np.full((T, 3), np.nan)
    rot = np.broadcast_to(np.eye(3), (T, 3, 3)).copy() if inp.heading_removed else None
    fitted = np.zeros(T, dtype=bool)
    common = [(raw.labels.index(lab), j) for j, lab in enumerate(clean.labels) if lab in raw.labels]
    rows = np.asarray(inp.clean_frames, dtype=np.int64)
    inside = (rows >= 0) & (rows < T)
    rows_in = rows[inside]
    if common and rows_in.size:
        ri = np.array([a for a, _ in common])
        ci = np.array([b for _, b in common])
        p_raw = raw.xyz[rows_in][:, ri]                    # (K, C, 3)
        p_cln = clean.xyz[inside][:, ci]
        same = (raw.valid[rows_in][:, ri] & clean.valid[inside][:, ci]
                & (np.asarray(inp.fill)[inside][:, ci] == MEASURED))
        n_same = same.sum(axis=1)
        if rot is not None:
            from gazepipe.stages.geometry import kabsch

            for k in np.flatnonzero(n_same >= 3):
                a, b = p_raw[k][same[k]], p_cln[k][same[k]]
                r = kabsch(a, b[None])[0]                   # b - mean(b) ≈ r (a - mean(a))
                rot[rows_in[k]] = r
                shift[rows_in[k]] = b.mean(axis=0) - r @ a.mean(axis=0)
                fitted[rows_in[k]] = True
        else:
            d = np.where(same[:, :, None], p_cln - p_raw, 0.0).sum(axis=1)
            ok = n_same >= 1
            shift[rows_in[ok]] = d[ok] / n_same[ok, None]
            fitted[rows_in[ok]] = True
    if inp.markerset.root in raw.labels:   # outside the crop: the raw root marker to the origin
        r_idx = raw.labels.index(inp.markerset.root)
        frame = np.arange(T)
        use = ((frame < inp.crop[0]) | (frame >= inp.crop[1])) & raw.valid[:, r_idx] & ~fitted
        if use.any():
            p = raw.xyz[use, r_idx]
            if rot is not None:
                if fitted.any():
                    f = np.flatnonzero(fitted)
                    rot[use] = rot[f[np.clip(np.searchsorted(f, np.flatnonzero(use)), 0, f.size - 1)]]
                p = np.einsum("tij,tj->ti", rot[use], p)
            shift[use] = -p
            fitted |= use
    if fitted.any() and not fitted.all():
        f = np.flatnonzero(fitted)
        if rot is not None:
            missing = np.flatnonzero(~fitted)
            rot[missing] = rot[f[np.clip(np.searchsorted(f, missing), 0, f.size - 1)]]
        shift = _interp_rows(shift, fitted)
    return rot, shift


def raw_in_clean_axes(inp: ReplayInputs, frames: np.ndarray | None = None,
                      transform: tuple[np.ndarray | None, np.ndarray] | None = None) -> np.ndarray:
    """(len(frames), M_raw, 3) raw positions of ``frames`` (default: every frame) moved into the cleaned
    markers' axes by :func:`raw_transform` (NaN where the raw sample is a gap or no frame tells the move)."""
    rot, shift = transform if transform is not None else raw_transform(inp)
    f = np.arange(inp.raw.n_frames) if frames is None else np.asarray(frames, dtype=np.int64)
    p = inp.raw.xyz[f]
    if rot is not None:
        p = np.einsum("tij,tmj->tmi", rot[f], p)
    return p + shift[f][:, None, :]


def head_and_target(inp: ReplayInputs) -> tuple[np.ndarray, np.ndarray]:
    """(T_kept, 3) each: the eyes' centre the target direction is measured from (the joints table's head
    centre, placed by its character frame; else the ``head_centre`` marker; else the head segment's
    centroid) and the gaze target marker, on the cleaned frames (NaN where unknown)."""
    clean, ms = inp.clean, inp.markerset
    n = clean.n_frames
    head = np.full((n, 3), np.nan)
    j = inp.joints
    if j is not None and len(j["frame"]):
        from gazepipe.stages.geometry import from_wxyz

        pos = np.searchsorted(inp.clean_frames, j["frame"])
        pos = np.clip(pos, 0, max(n - 1, 0))
        hit = (inp.clean_frames[pos] == j["frame"]) if n else np.zeros(len(j["frame"]), bool)
        q, o, h = j["char_rot"], j["char_origin"], j["head_centre"]
        ok = hit & np.isfinite(q).all(axis=1) & np.isfinite(o).all(axis=1) & np.isfinite(h).all(axis=1)
        if ok.any():
            head[pos[ok]] = o[ok] + from_wxyz(q[ok]).apply(h[ok])
    fallback = None
    if ms.head_centre and ms.head_centre in clean.labels:
        fallback = clean.xyz[:, clean.labels.index(ms.head_centre)]
    elif ms.segments:
        idx = [clean.labels.index(m) for m in ms.segments[-1].markers if m in clean.labels]
        if idx:
            pts = clean.xyz[:, idx]
            full = np.isfinite(pts).all(axis=(1, 2))
            fallback = np.where(full[:, None], np.nanmean(pts, axis=1) if full.any() else np.nan, np.nan)
    if fallback is not None:
        miss = ~np.isfinite(head).all(axis=1)
        head[miss] = fallback[miss]
    target = np.full((n, 3), np.nan)
    if ms.target and ms.target in clean.labels:
        target = clean.xyz[:, clean.labels.index(ms.target)].copy()
    return head, target


# --------------------------------------------------------------------------------------- worst moments

def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of each run of True in a 1-D mask."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def dropped_frames(inp: ReplayInputs) -> tuple[np.ndarray, list[str]]:
    """Per kept frame, the first reason it gives no dataset row ('' where it gives one), as the datasets
    decide it from the joints table: no character frame, a segment's rotation missing (named), no target
    direction (gaze_follow). A take that feeds no dataset drops none; without a joints table, the frames with
    an unfilled marker are counted, reason 'no joints table'."""
    n = inp.clean.n_frames
    why = [""] * n
    if not inp.feeds or n == 0:
        return np.zeros(n, dtype=bool), why
    j = inp.joints
    if j is None:
        bad = (np.asarray(inp.fill) == UNFILLED).any(axis=1)
        return bad, ["no joints table" if b else "" for b in bad]
    reason = np.full(n, "", dtype=object)
    pos = np.clip(np.searchsorted(inp.clean_frames, j["frame"]), 0, n - 1)
    hit = inp.clean_frames[pos] == j["frame"]
    reason[:] = "no joints row"
    names = [s.name for s in inp.markerset.segments]
    r = np.full(len(j["frame"]), "", dtype=object)
    seg_ok = np.isfinite(j["quat"]).all(axis=2)                      # (N, S)
    no_char = ~np.isfinite(j["char_rot"]).all(axis=1)
    r[no_char] = "no character frame (root segment)"
    miss = (r == "") & ~seg_ok.all(axis=1)
    for i in np.flatnonzero(miss):
        gone = [names[s] if s < len(names) else f"segment {s}" for s in np.flatnonzero(~seg_ok[i])]
        r[i] = f"{', '.join(gone[:3])}{' ...' if len(gone) > 3 else ''} rotation missing"
    if inp.needs_target:
        no_t = (r == "") & ~np.isfinite(j["target_dir"]).all(axis=1)
        r[no_t] = "no target direction"
    reason[pos[hit]] = r[hit]
    bad = reason != ""
    return bad, [str(x) for x in reason]


def _apart(frames: list[int], f: int, near: int) -> bool:
    return all(abs(f - g) > near for g in frames)


def worst_moments(inp: ReplayInputs, max_per_kind: dict[str, int] | None = None) -> list[Moment]:
    """The take's worst moments, most telling first: stretches without dataset rows (the longest two, with
    why), label swaps (three), the largest estimated fill errors (two gaps), filled segment rotations (the two
    least sure) and the largest removed spike. Each label names the frame the page jumps to."""
    lim = {"no_row": 2, "swap": 3, "fill_error": 2, "rotation": 2, "spike": 1, **(max_per_kind or {})}
    frames = np.asarray(inp.clean_frames, dtype=np.int64)
    near = window_half(float(inp.raw.rate_hz))
    out = _no_row_moments(inp, frames, lim["no_row"]) + _swap_moments(inp, lim["swap"])
    out += _fill_error_moments(inp, frames, lim["fill_error"], near)
    out += _rotation_moments(inp, lim["rotation"], near)
    if lim["spike"]:
        out += _spike_moment(inp, frames)
    return out


def _no_row_moments(inp: ReplayInputs, frames: np.ndarray, limit: int) -> list[Moment]:
    """The longest stretches of kept frames without a dataset row, at their middles, with why."""
    bad, why = dropped_frames(inp)
    out = []
    for a, b in sorted(sorted(runs(bad), key=lambda r: (-(r[1] - r[0]), r[0]))[:limit]):
        f = int(frames[(a + b - 1) // 2])
        out.append(Moment("no_row", f, f"no dataset row: {why[(a + b - 1) // 2]} · frame {f}",
                          f"frames {frames[a]}-{frames[b - 1]} ({b - a} frames) give no dataset row"))
    return out


def _swap_moments(inp: ReplayInputs, limit: int) -> list[Moment]:
    """The longest label swaps, at their first frames, in time order."""
    out = []
    swaps = sorted(inp.swaps, key=lambda s: (-(s[3] - s[2]), s[2]))[:limit]
    for a_lab, b_lab, start, stop, repaired in sorted(swaps, key=lambda s: s[2]):
        f = int(min(max(start, 0), inp.raw.n_frames - 1))
        how = "repaired" if repaired else "made gaps"
        out.append(Moment("swap", f, f"label swap {a_lab}/{b_lab} ({how}) · frame {f}",
                          f"{a_lab} and {b_lab} carried each other's names over frames {start}-{stop - 1}"))
    return out


def _fill_error_moments(inp: ReplayInputs, frames: np.ndarray, limit: int, near: int) -> list[Moment]:
    """The filled runs with the largest estimated error, at each run's worst sample, at least ``near`` frames
    apart."""
    err = np.asarray(inp.fill_error_mm, dtype=np.float64)
    found: list[tuple[float, int, int]] = []        # (error, row, marker) of each filled run's worst sample
    if err.size:
        fin = np.isfinite(err)
        for mk in np.flatnonzero(fin.any(axis=0)).tolist():
            for a, b in runs(fin[:, mk]):
                pk = a + int(np.argmax(err[a:b, mk]))
                found.append((float(err[pk, mk]), pk, mk))
    chosen: list[int] = []
    out = []
    for e, k, m in sorted(found, key=lambda x: (-x[0], x[1], x[2])):
        f = int(frames[k])
        if len(chosen) == limit or not _apart(chosen, f, near):
            continue
        chosen.append(f)
        method = CATEGORIES[int(inp.fill[k, m])]
        label = inp.clean.labels[m]
        out.append(Moment("fill_error", f, f"fill error {e:.1f} mm: {label} ({method}) · frame {f}",
                          f"{label} filled by {method}, estimated error {e:.1f} mm"))
    return out


def _rotation_moments(inp: ReplayInputs, limit: int, near: int) -> list[Moment]:
    """Segment rotations filled across gaps, the least sure (largest estimated error, then longest) first, at
    each run's middle, at least ``near`` frames apart."""
    j = inp.joints
    if j is None or "rot_filled" not in j or not len(j["frame"]):
        return []
    names = [s.name for s in inp.markerset.segments]
    cands: list[tuple[float, int, int, int, str]] = []
    for s in range(j["rot_filled"].shape[1]):
        for a, b in runs(j["rot_filled"][:, s]):
            fa, fb = int(j["frame"][a]), int(j["frame"][b - 1])
            known = [(err_deg, meth) for seg, lo, hi, meth, err_deg in inp.rotation_errors
                     if seg == s and lo <= fa and fb < hi]
            rot_e, rot_method = known[-1] if known else (None, None)
            cands.append((-(rot_e if rot_e is not None else 0.0), -(b - a), s, (fa + fb) // 2,
                          rot_method or "filled"))
    chosen: list[int] = []
    out = []
    for neg_e, neg_len, seg_i, mid, how in sorted(cands):
        if len(chosen) == limit or not _apart(chosen, mid, near):
            continue
        chosen.append(mid)
        name = names[seg_i] if seg_i < len(names) else f"segment {seg_i}"
        e_txt = f", {-neg_e:.1f}° estimated" if neg_e else ""
        out.append(Moment("rotation", int(mid), f"rotation filled: {name} ({how}{e_txt}) · frame {mid}",
                          f"{name}'s rotation filled across {-neg_len} frames"))
    return out


def _spike_moment(inp: ReplayInputs, frames: np.ndarray) -> list[Moment]:
    """The removed spike farthest from its refilled position (raw sample against cleaned), if any."""
    if not np.asarray(inp.spike).any():
        return []
    clean = inp.clean
    rows, cols = np.nonzero(inp.spike)
    at = np.unique(frames[rows])
    at = at[(at >= 0) & (at < inp.raw.n_frames)]
    raw_at = raw_in_clean_axes(inp, at)
    ri = {lab: i for i, lab in enumerate(inp.raw.labels)}
    best: tuple[float, int, int] | None = None
    for row, col in zip(rows.tolist(), cols.tolist(), strict=True):
        r = ri.get(clean.labels[col])
        fr = int(frames[row])
        if r is None or not (0 <= fr < inp.raw.n_frames):
            continue
        dist = float(np.linalg.norm(raw_at[np.searchsorted(at, fr), r] - clean.xyz[row, col]))
        if np.isfinite(dist) and (best is None or dist > best[0]):
            best = (dist, row, col)
    if best is None:
        return []
    dist, row, col = best
    fr = int(frames[row])
    return [Moment("spike", fr, f"removed spike: {clean.labels[col]} {dist:.0f} mm off · frame {fr}",
                   f"{clean.labels[col]}'s sample was {dist:.0f} mm from its refilled position")]


# -------------------------------------------------------------------------------------------- the frames

def window_half(rate_hz: float) -> int:
    """Frames a side of a worst moment kept at full rate."""
    return int(max(1, min(WINDOW_MAX_FRAMES, round(WINDOW_S * rate_hz))))


def choose_frames(n_frames: int, moments: list[int], rate_hz: float, budget: int = MAX_FRAMES
                  ) -> tuple[np.ndarray, int, int]:
    """The frames a replay shows, sorted: every frame of a window around each moment (:func:`window_half` a
    side, narrowed when the windows alone would take more than half of ``budget``; the moment itself always),
    and a regular stride over the whole take chosen so the total is about ``budget``. Returns
    ``(frames, stride, frames a side of each moment)``."""
    if n_frames <= 0:
        return np.zeros(0, dtype=np.int64), 1, 0
    moments = sorted({int(m) for m in moments if 0 <= m < n_frames})
    half = window_half(rate_hz)
    while half > 0 and len(moments) * (2 * half + 1) > budget // 2:
        half //= 2
    keep = np.zeros(n_frames, dtype=bool)
    for m in moments:
        keep[max(0, m - half):m + half + 1] = True
    left = max(budget - int(keep.sum()), 2)
    stride = max(1, int(np.ceil(n_frames / left)))
    keep[::stride] = True
    keep[n_frames - 1] = True
    return np.flatnonzero(keep).astype(np.int64), stride, half


def axis_ranges(points: list[np.ndarray], pad: float = 0.08) -> np.ndarray:
    """(3, 2) equal-scale-ready ranges (min, max per axis) holding the points (each (..., 3); NaN ignored), each
    widened by ``pad`` of the largest extent, at least 200 mm wide."""
    pts = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in points]) if points \
        else np.zeros((0, 3))
    pts = pts[np.isfinite(pts).all(axis=1)]
    if pts.shape[0] == 0:
        return np.array([[-1000.0, 1000.0]] * 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    margin = pad * float(max((hi - lo).max(), 200.0))
    lo, hi = lo - margin, hi + margin
    small = (hi - lo) < 200.0
    mid = (lo + hi) / 2
    lo[small], hi[small] = mid[small] - 100.0, mid[small] + 100.0
    return np.stack([lo, hi], axis=1)


def robust_points(xyz: np.ndarray, q: float = 1.0) -> np.ndarray:
    """The per-axis ``q`` and ``100 - q`` percentiles of finite points (2, 3): a raw capture's far ghosts do
    not set the view."""
    p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    if p.shape[0] == 0:
        return np.zeros((0, 3))
    return np.percentile(p, [q, 100 - q], axis=0)


def stick_pairs(markerset: MarkerSet, labels: list[str]) -> list[tuple[int, int]]:
    """Index pairs of ``labels`` joined by a stick: within each segment, a triangle or a cluster of up to five
    markers joined all to all, a larger one as a ring; and the root marker to the root segment's markers."""
    idx = {lab: i for i, lab in enumerate(labels)}
    pairs: list[tuple[int, int]] = []
    for s in markerset.segments:
        ms = [idx[m] for m in s.markers if m in idx]
        if len(ms) <= 5:
            pairs += [(a, b) for i, a in enumerate(ms) for b in ms[i + 1:]]
        else:
            pairs += [(ms[i], ms[(i + 1) % len(ms)]) for i in range(len(ms))]
    if markerset.root in idx and markerset.segments:
        r = idx[markerset.root]
        pairs += [(r, i) for i in (idx[m] for m in markerset.root_segment.markers if m in idx) if i != r]
    return list(dict.fromkeys(pairs))


def stick_path(pairs: list[tuple[int, int]]) -> list[int]:
    """A vertex sequence drawing every pair once as a polyline, ``-1`` where the pen lifts: each pen stroke
    follows unused pairs from its last vertex as long as it can (a triangle is one stroke of four vertices)."""
    left = list(pairs)
    path: list[int] = []
    while left:
        a, b = left.pop(0)
        stroke = [a, b]
        while True:
            cur = stroke[-1]
            nxt = next((k for k, (p, q) in enumerate(left) if cur in (p, q)), None)
            if nxt is None:
                break
            p, q = left.pop(nxt)
            stroke.append(q if p == cur else p)
        if path:
            path.append(-1)
        path += stroke
    return path


#: length of the spike drawn along each segment's normal, mm
NORMAL_MM = 100.0


def segment_normals(markerset: MarkerSet, labels: list[str], xyz: np.ndarray) -> np.ndarray:
    """(T, 3 S, 3): per frame and segment of at least three markers, a stroke from the centroid of its first
    three markers along their plane's normal ((m1 - m0) x (m2 - m0), :data:`NORMAL_MM` long), then NaN (the pen
    lifts). Two of those markers carrying each other's names flip it, which shows a label swap."""
    idx = {lab: i for i, lab in enumerate(labels)}
    tri = [[idx[m] for m in s.markers[:3]] for s in markerset.segments
           if len(s.markers) >= 3 and all(m in idx for m in s.markers[:3])]
    T = xyz.shape[0]
    if not tri:
        return np.zeros((T, 0, 3))
    p = xyz[:, np.array(tri)]                                     # (T, S, 3 markers, 3)
    u, v = p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0]
    n = np.stack([u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1], u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
                  u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1)
    with np.errstate(all="ignore"):
        n = n / np.sqrt((n * n).sum(axis=-1, keepdims=True)) * NORMAL_MM
    c = p.mean(axis=2)
    out = np.stack([c, c + n, np.full_like(c, np.nan)], axis=2)   # (T, S, 3, 3)
    return out.reshape(T, -1, 3)


def summary(inp: ReplayInputs) -> dict[str, Any]:
    """Counts the page states under the figure: frames, kept frames, samples per category."""
    cat = sample_categories(inp.fill, inp.spike, inp.clean.valid)
    counts = {CATEGORIES[c]: int(n) for c, n in zip(*np.unique(cat, return_counts=True), strict=True)}
    return {"frames": inp.raw.n_frames, "kept": inp.clean.n_frames, "rate_hz": float(inp.raw.rate_hz),
            "samples": counts}


# ------------------------------------------------------------------------------------------- reading

#: the take tables a replay reads (their bytes key the cached page)
REPLAY_TABLES = ("markers_raw", "markers", "joints")
_JOINT_COLUMNS = ["frame", "char_rot", "char_origin", "quat", "head_centre", "target_dir", "rot_filled"]


def _stage_error(entry: Any, stage: str) -> str | None:
    """The one-line error of the take's ``stage`` unit when it failed, else ``None``."""
    rec = entry.records.get(stage)
    if rec is None or rec.get("status") == "ok":
        return None
    return str(rec.get("error") or rec.get("status") or "failed").splitlines()[0]


def load_replay_inputs(layout: Any, entry: Any, markerset: MarkerSet | None) -> ReplayInputs:
    """Read what the replay of ``entry`` (a :class:`gazepipe.report.collect.TakeEntry`) needs from the output
    folder ``layout``. Raises :class:`ReplayUnavailable` saying why when there is nothing to replay: a face
    take, no raw or cleaned markers (naming the stage that failed), an unreadable table or markerset."""
    from gazepipe.errors import GazepipeError
    from gazepipe.io.parquet import read_table
    from gazepipe.schemas import expected_schema
    from gazepipe.schemas.base import check_table
    from gazepipe.schemas.joints import list_to_numpy
    from gazepipe.schemas.markers import check_markers_meta, table_to_markers
    from gazepipe.stages.clean.qc import CleanQC
    from gazepipe.stages.frames.qc import FramesQC

    key = entry.key
    if entry.kind == "face":
        raise ReplayUnavailable(f"{key} is a face take: blendshape tracks, no markers to replay")
    if markerset is None:
        raise ReplayUnavailable(f"{key}: its session's markerset cannot be read (`gazepipe status` says why)")

    def read(name: str, columns: list[str] | None = None):
        path = layout.table(entry.session, entry.take, name)
        if not path.exists():
            return None
        try:
            table = read_table(path, columns=columns)
            if columns is None:
                schema = expected_schema(name, table)
                if schema is not None:
                    check_table(table, schema, path=str(path))
                check_markers_meta(table, str(path))
            return table
        except GazepipeError as exc:
            raise ReplayUnavailable(f"{key}: {exc.one_line()}") from None
        except Exception as exc:   # a table that decodes into nonsense
            raise ReplayUnavailable(f"{key}: {path}: unreadable ({type(exc).__name__}: {exc})") from None

    raw_t = read("markers_raw")
    if raw_t is None:
        why = _stage_error(entry, "ingest")
        raise ReplayUnavailable(f"{key}: no raw markers to replay: " + (f"its ingest failed ({why})" if why else
                                                                         "ingest has not run on it"))
    clean_t = read("markers")
    if clean_t is None:
        why = _stage_error(entry, "clean")
        raise ReplayUnavailable(f"{key}: no cleaned markers to replay: " + (
            f"its clean stage failed ({why})" if why else "the clean stage has not run on it (`gazepipe run`)"))
    raw = table_to_markers(raw_t)[0]
    clean, frames, fill, meta = table_to_markers(clean_t)
    M, T = clean.n_markers, clean.n_frames
    spike = clean_t.column("spike").to_numpy(zero_copy_only=False).astype(bool).reshape(M, T).T
    err = clean_t.column("fill_error_mm").to_numpy(zero_copy_only=False).astype(np.float64).reshape(M, T).T
    del raw_t, clean_t
    cqc = entry.qc(CleanQC)
    crop = tuple(int(x) for x in (meta.get("crop") or (cqc.crop if cqc is not None else
                                                        (int(frames[0]) if T else 0, int(frames[-1]) + 1 if T else 0))))
    swaps = [] if cqc is None else [(s.markers[0], s.markers[1], int(s.start), int(s.stop), bool(s.repaired))
                                    for s in cqc.swaps]
    joints = None
    jt = read("joints", _JOINT_COLUMNS)
    if jt is not None:
        S = len(markerset.segments)
        try:
            n = jt.num_rows
            joints = {"frame": jt.column("frame").to_numpy().astype(np.int64)}
            for c, w in (("char_rot", 4), ("char_origin", 3), ("head_centre", 3), ("target_dir", 3)):
                joints[c] = list_to_numpy(jt.column(c), w).astype(np.float64)
            width = jt.schema.field("quat").type.list_size
            joints["quat"] = list_to_numpy(jt.column("quat"), width).astype(np.float64).reshape(n, width // 4, 4)
            joints["rot_filled"] = list_to_numpy(jt.column("rot_filled"), width // 4).astype(bool)
            if width // 4 != S:
                joints = None     # a markerset edited since: the rotations cannot be named
        except Exception:   # an odd joints table costs the rotation moments and the head centre, not the replay
            joints = None
    fqc = entry.qc(FramesQC)
    rot_err = [] if fqc is None else [(int(g.segment), crop[0] + int(g.start), crop[0] + int(g.stop), g.method,
                                       None if g.error_deg is None else float(g.error_deg))
                                      for g in fqc.rotation_gaps if g.filled]
    return ReplayInputs(key=key, kind=entry.kind, markerset=markerset, raw=raw, clean=clean,
                        clean_frames=np.asarray(frames, dtype=np.int64), fill=fill if fill is not None else
                        np.zeros((T, M), np.int8), spike=spike, fill_error_mm=err, crop=(crop[0], crop[1]),
                        swaps=swaps, joints=joints, rotation_errors=rot_err,
                        heading_removed=bool(entry.params("clean").get("remove_heading", False)),
                        feeds=entry.kind in ("gaze_follow", "gaze_shift"), needs_target=entry.kind == "gaze_follow")
