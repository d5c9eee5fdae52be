"""Frame-by-frame model averaging of a gap's candidate fills (the idea of Tits, Tilmanne and Dutoit 2018).

Each method's fill of a gap is already corrected to meet the measured samples at both of its edges. Which of
them is right may change inside a long gap (a rigid fill while the segment's other markers are there, PCA when
the limb bends), so instead of one choice per gap each frame takes a weighted mean of the candidates. A
candidate's weight in a frame is its prior (inverse-square validation error, as the per-gap blend) divided by
how badly it breaks the marker's distances to the markers most rigidly linked to it in that frame: a fill that
keeps those distances where they were around the gap is physically plausible, one that stretches them is not.

The same averaging is run on the measured stretches hidden beside the gap for validation; the per-gap blend is
kept wherever it predicts them better (:func:`gazepipe.stages.clean.gapfill.fill_gaps`).
"""

from __future__ import annotations

import numpy as np

from gazepipe.stages.clean.fill_methods import distance_stats

#: neighbours whose distance to the marker is checked: the most rigidly linked ones, at most this many
N_LINKED = 4
#: ... among the markers measured in at least this share of the gap's frames (a link measured in fewer frames
#: leaves most of the gap without a residual to weight by)
LINK_MIN_SHARE = 0.5
#: ... whose distance varied by at most this (mm, standard deviation) around the gap
MAX_LINK_SD_MM = 15.0
#: floor (mm) of a link's distance spread: below marker noise, a tighter link is no more informative
LINK_SD_FLOOR_MM = 1.0
#: frames over which a candidate's distance residual is averaged before weighting (odd): weights that jump
#: from frame to frame would put steps into the fill
SMOOTH_FRAMES = 5


def linked_neighbours(xyz: np.ndarray, valid: np.ndarray, known_m: np.ndarray, m: int, s: int, e: int,
                      window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The markers most rigidly linked to ``m`` around gap ``[s, e)``.

    Candidates are measured in at least half the gap's frames; their distance to ``m`` is measured over the
    ``window`` frames on each side where both are measured and ``known_m`` (the hidden validation stretches
    excluded). Returns ``(markers (K,), mean distance (K,) mm, spread (K,) mm)``, the ``N_LINKED`` with the
    smallest spread under ``MAX_LINK_SD_MM``; empty when none qualify.
    """
    cand = np.flatnonzero(valid[s:e].mean(axis=0) >= LINK_MIN_SHARE)
    cand = cand[cand != m]
    empty = np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0)
    if cand.size == 0:
        return empty
    mu, sd = distance_stats(xyz, valid, m, cand, s, e, window, known_m)
    order = np.argsort(sd, kind="stable")[:N_LINKED]
    order = order[sd[order] <= MAX_LINK_SD_MM]
    if order.size == 0:
        return empty
    return cand[order], mu[order], np.maximum(sd[order], LINK_SD_FLOOR_MM)


def link_residuals(preds: np.ndarray, frames: np.ndarray, xyz: np.ndarray, vis: np.ndarray, links: np.ndarray,
                   dist: np.ndarray, spread: np.ndarray, vis_rows: np.ndarray | None = None) -> np.ndarray:
    """Mean squared distance error (in units of each link's spread) of fills ``preds`` (C, n, 3) at ``frames``
    against the links measured there (``vis`` (T, M) the visibility the fills saw, or ``vis_rows`` (n, M) that
    visibility in ``frames`` when given), (n, C); NaN where no link is."""
    pos = xyz[frames][:, links]                                     # (n, K, 3)
    rows = vis[frames] if vis_rows is None else vis_rows
    seen = rows[:, links] & np.isfinite(pos).all(axis=2)
    diff = np.nan_to_num(pos)[None] - preds[:, :, None, :]          # (C, n, K, 3)
    z = (np.sqrt(np.einsum("cnkd,cnkd->cnk", diff, diff)) - dist) / spread
    k = seen.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (np.where(seen[None], z * z, 0.0).sum(axis=2) / k).T


def _smooth(r: np.ndarray, cuts: np.ndarray) -> np.ndarray:
    """Running mean of ``r`` (n, C) over ``SMOOTH_FRAMES`` within each run between ``cuts`` (start indices),
    ignoring NaN."""
    out = np.empty_like(r)
    half = SMOOTH_FRAMES // 2
    bounds = [*cuts.tolist(), r.shape[0]]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        seg = r[a:b]
        ok = np.isfinite(seg)
        pad = ((half, half), (0, 0))
        cs = np.cumsum(np.pad(np.where(ok, seg, 0.0), pad), axis=0)
        cn = np.cumsum(np.pad(ok.astype(float), pad), axis=0)
        w = SMOOTH_FRAMES
        tot = np.vstack([cs[w - 1:w], cs[w:] - cs[:-w]])
        num = np.vstack([cn[w - 1:w], cn[w:] - cn[:-w]])
        with np.errstate(invalid="ignore", divide="ignore"):
            out[a:b] = tot / num
    return out


def average(preds: dict[str, np.ndarray], prior: dict[str, float], frames: np.ndarray, xyz: np.ndarray,
            vis: np.ndarray, links: tuple[np.ndarray, np.ndarray, np.ndarray],
            cuts: np.ndarray | None = None, *, vis_rows: np.ndarray | None = None) -> np.ndarray | None:
    """The frame-by-frame weighted mean (n, 3) of the candidate fills ``preds`` (method -> (n, 3) at
    ``frames``, NaN where a method has none) with weights ``prior[k] / (1 + residual_k)``, the residual being
    :func:`link_residuals` smoothed over ``SMOOTH_FRAMES`` (within the runs starting at ``cuts``). None when
    there are fewer than two candidates or no links; frames where no candidate has a value are NaN.
    ``vis_rows`` (n, M): the visibility in ``frames``, when the caller has it without a (T, M) ``vis``."""
    names = [k for k in prior if k in preds]
    if len(names) < 2 or links[0].size == 0:
        return None
    stack = np.stack([preds[k] for k in names])                     # (C, n, 3)
    res = link_residuals(stack, frames, xyz, vis, *links, vis_rows=vis_rows)
    res = _smooth(res, np.zeros(1, dtype=np.int64) if cuts is None else cuts)
    have = np.isfinite(stack).all(axis=2).T                        # (n, C)
    w = np.array([prior[k] for k in names])[None, :] / (1.0 + np.where(np.isfinite(res), res, 0.0))
    w = np.where(have, w, 0.0)
    total = w.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.einsum("nc,cnd->nd", w / total, np.nan_to_num(stack))
