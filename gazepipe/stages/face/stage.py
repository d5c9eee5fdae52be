"""face stage: align raw tracked and hand-cleaned blendshapes, with Berson's frame-rate-free derivatives.

Berson et al. (seed 002, section 3.1, eq. 1) describe facial animation by its normalised forward derivatives

    x⁽ᵏ⁾[n] = (x⁽ᵏ⁻¹⁾[n+1] − x⁽ᵏ⁻¹⁾[n]) / Δt[n],    Δt[n] = t[n+1] − t[n],

so a model trained on them does not depend on the frame rate, and dropped frames (a longer Δt) need no
resampling. The order-k derivative needs k forward steps, so the last K aligned frames have no complete row and
are left out (K = 1: the last frame), counted in QC, as are tracked rows without a clean counterpart.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gazepipe.arkit import normalise_name
from gazepipe.errors import StageError
from gazepipe.model import FaceTrack
from gazepipe.stages.face.params import FaceParams
from gazepipe.stages.face.qc import FaceQC

__all__ = ["FaceAligned", "align_face", "forward_derivatives"]


@dataclass
class FaceAligned:
    """Tracked and clean blendshapes on the same frames, with their forward derivatives.

    Attributes
    ----------
    names : blendshape names, canonical ARKit spelling and order.
    timecode : (M,) str timecode of each row (the tracked file's).
    time_s : (M,) float64 seconds since the tracked file's first row.
    frame_index : (M,) int64 capture frame of each row in the tracked file (gaps: dropped or unmatched frames).
    dt_s : (M,) float64 forward step t[n+1] − t[n] to the next aligned row, seconds.
    tracked, clean : (M, 52) float32 blendshape values.
    d_tracked, d_clean : (M, K, 52) float64 forward derivatives of orders 1..K (units: 1/s^k).
    k : the highest derivative order K.
    qc : counts and figures for the QC report.
    """

    names: tuple[str, ...]
    timecode: np.ndarray
    time_s: np.ndarray
    frame_index: np.ndarray
    dt_s: np.ndarray
    tracked: np.ndarray
    clean: np.ndarray
    d_tracked: np.ndarray
    d_clean: np.ndarray
    k: int
    qc: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.time_s.shape[0])


def forward_derivatives(x: np.ndarray, dt: np.ndarray, k: int) -> np.ndarray:
    """Forward derivatives of orders 1..k (Berson eq. 1), each divided by that frame's dt.

    Parameters
    ----------
    x : (N, D) values at N frames.
    dt : (N − 1,) forward time steps in seconds, dt[n] = t[n+1] − t[n].
    k : highest order, >= 1.

    Returns
    -------
    (N − k, k, D) float64: [n, i − 1] is the order-i derivative at frame n, for the frames that have all k.
    """
    x = np.asarray(x, dtype=np.float64)
    dt = np.asarray(dt, dtype=np.float64)
    n = x.shape[0]
    if k < 1:
        raise ValueError(f"derivative order must be >= 1, got {k}")
    if dt.shape != (n - 1,):
        raise ValueError(f"dt must have shape ({n - 1},), got {dt.shape}")
    m = max(n - k, 0)
    out = np.empty((m, k, x.shape[1]), dtype=np.float64)
    cur = x
    for i in range(k):
        cur = np.diff(cur, axis=0) / dt[: cur.shape[0] - 1, None]
        out[:, i] = cur[:m]
    return out


def _match(t_trk: np.ndarray, t_cln: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one nearest matching of sorted times within ``tol``: (tracked rows, clean rows, |error|)."""
    j = np.searchsorted(t_cln, t_trk)
    lo = np.clip(j - 1, 0, t_cln.size - 1)
    hi = np.clip(j, 0, t_cln.size - 1)
    use_hi = np.abs(t_cln[hi] - t_trk) < np.abs(t_cln[lo] - t_trk)
    c = np.where(use_hi, hi, lo)
    err = np.abs(t_cln[c] - t_trk)
    rows = np.flatnonzero(err < tol)
    # a clean row matched twice keeps its closest tracked row
    order = np.lexsort((err[rows], c[rows]))
    rows = rows[order]
    _, first = np.unique(c[rows], return_index=True)
    rows = np.sort(rows[first])
    return rows, c[rows], err[rows]


def align_face(tracked: FaceTrack, clean: FaceTrack, params: FaceParams | None = None, *,
               paths: tuple[str | Path, str | Path] | None = None) -> FaceAligned:
    """Align a take's tracked and clean blendshapes on timecode and add forward derivatives (SPEC §3.6).

    A tracked row is kept when the clean file has a row within half a capture frame (1 / (2·rate_hz)) of its
    timecode; each clean row pairs with at most one tracked row; rows written while tracking was lost
    (``FaceTrack.valid`` False) pair with none (counted as unmatched). dt and the derivatives run over the aligned
    rows, so a dropped or unmatched frame simply makes that step longer (Berson's formulation needs no fixed
    rate). The last ``k`` aligned rows lack a forward derivative of order ``k`` and are left out.

    Parameters
    ----------
    tracked : raw tracking of the take.
    clean : the hand-cleaned animation of the same take.
    params : the stage's parameters (default :class:`FaceParams`): ``k``, the highest derivative order.
    paths : the tracked and the clean file, named by the errors (None: errors name no file).

    Returns
    -------
    FaceAligned, with QC counts: rows read, dropped capture frames, unmatched rows, rows left out at the end.

    Raises
    ------
    StageError : no or too few rows in common.
    """
    k = (params or FaceParams()).k
    if k < 1:
        raise ValueError(f"derivative order k must be >= 1, got {k}")
    trk_path, cln_path = paths if paths is not None else (None, None)
    other = f" of {cln_path}" if cln_path is not None else ""
    for track, path, what in ((tracked, trk_path, "tracked"), (clean, cln_path, "clean")):
        if track.n_frames <= k:
            raise StageError(path, f"{track.n_frames} data row(s) in the {what} file: aligning a face take "
                                   f"needs more than {k}")
    if tuple(tracked.names) != tuple(clean.names):
        raise StageError(trk_path, f"the tracked blendshape channels differ from the clean ones{other}")
    names = tuple(normalise_name(n) or n for n in tracked.names)
    tol = 0.5 / float(tracked.rate_hz)
    # rows written while tracking was lost hold no values: they match nothing (a longer step, as a dropped frame)
    t_ok, c_ok = np.flatnonzero(tracked.valid_rows), np.flatnonzero(clean.valid_rows)
    rows, crow, err = (_match(tracked.timecode_s[t_ok], clean.timecode_s[c_ok], tol) if t_ok.size and c_ok.size
                       else (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)))
    rows, crow = t_ok[rows], c_ok[crow]
    if rows.size <= k:
        raise StageError(trk_path, f"only {rows.size} tracked row(s) have a clean counterpart{other} within half "
                                   f"a frame (need more than {k}); do the two files share a timecode?")
    t = tracked.time_s[rows]
    dt = np.diff(t)
    d_trk = forward_derivatives(tracked.values[rows], dt, k)
    d_cln = forward_derivatives(clean.values[crow], dt, k)
    m = rows.size - k
    keep, ckeep = rows[:m], crow[:m]
    qc = FaceQC(
        rows_tracked=tracked.n_frames,
        rows_clean=clean.n_frames,
        dropped_frames_tracked=int(tracked.dropped_frames),
        dropped_frames_clean=int(clean.dropped_frames),
        rows_matched=int(rows.size),
        unmatched_tracked=int(tracked.n_frames - rows.size),
        unmatched_clean=int(clean.n_frames - rows.size),
        last_frames_dropped=int(k),
        rows_out=int(m),
        k=int(k),
        max_match_error_s=float(err.max()),
        dt_min_s=float(dt[:m].min()),
        dt_median_s=float(np.median(dt[:m])),
        dt_max_s=float(dt[:m].max()),
        warnings=(),                  # the alignment itself has none; the unit adds the readers'
    ).to_record()
    return FaceAligned(
        names=names,
        timecode=tracked.timecode[keep],
        time_s=t[:m],
        frame_index=tracked.frame_index[keep],
        dt_s=dt[:m],
        tracked=tracked.values[keep],
        clean=clean.values[ckeep],
        d_tracked=d_trk,
        d_clean=d_cln,
        k=int(k),
        qc=qc,
    )
