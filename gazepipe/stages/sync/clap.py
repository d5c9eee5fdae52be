"""sync stage, mocap side: the clapper's contact instants in the clapper markers' trajectories (Klein 5.1).

A clapper carrying one marker on each arm is snapped shut in view of the head camera; the clap is the contact
instant, when the closing of the clapper arms ends (:func:`mocap_claps`). The robust-statistics helpers here are
shared with the video side (:mod:`gazepipe.stages.sync.video`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from gazepipe.stages.clean.filters import true_runs

__all__ = ["Clap", "clap_profile", "clapper_distance", "mocap_claps"]

_MAD = 1.4826  # MAD → standard deviation for Gaussian noise


def _robust_sigma(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan")
    return float(_MAD * np.median(np.abs(x - np.median(x))))


def _score(z: float, lo: float, hi: float) -> float:
    """Linear map of a signal-to-noise ratio onto 0..1: ``lo`` (just detectable) → 0, ``hi`` → 1."""
    if not np.isfinite(z):
        return 1.0 if z > 0 else 0.0
    return float(np.clip((z - lo) / (hi - lo), 0.0, 1.0))


@dataclass
class Clap:
    """A clap found in the mocap.

    Attributes
    ----------
    time_s : contact instant, seconds on the mocap clock (0 at the take's first frame).
    frame : the same instant as a fractional frame index (time_s · rate).
    confidence : 0..1, how clearly the closing stands out of the noise (see :func:`mocap_claps`).
    closing_speed_mm_s : fastest closing speed of the distance between the markers.
    open_mm, shut_mm : distance held before the closing, and the plateau after it.
    margin_mm : tolerance around ``shut_mm`` used to decide that the clapper is shut.
    gap_frames : clapper frames missing between the last closing frame and the shut plateau (the contact was
        extrapolated across them); 0 when the contact was seen.
    timing_s : how well ``time_s`` is known, s (one standard deviation; see :func:`_contact_crossing`).
    """

    time_s: float
    frame: float
    confidence: float
    closing_speed_mm_s: float
    open_mm: float
    shut_mm: float
    margin_mm: float
    gap_frames: int = 0
    timing_s: float = 0.0


def clapper_distance(clap_a_xyz: np.ndarray, clap_b_xyz: np.ndarray, valid_a: np.ndarray,
                     valid_b: np.ndarray) -> np.ndarray:
    """(T,) distance in mm between the two clapper markers, NaN where either is invalid."""
    d = np.linalg.norm(np.asarray(clap_a_xyz, float) - np.asarray(clap_b_xyz, float), axis=1)
    ok = np.asarray(valid_a, bool) & np.asarray(valid_b, bool) & np.isfinite(d)
    return np.where(ok, d, np.nan)


#: the contact refined below one frame is known to this share of a mocap frame at best, however little noise: the
#: approach is modelled as a quadratic over its last frames, and how it ends inside the last frame is not sampled
#: (``bench/bench_claps_truth.py --calibrate`` checks that the stated timing covers the error at 30–240 Hz)
CONTACT_MODEL_FRAMES = 1.0 / 24.0
#: a quadratic fit over more than three frames is kept while its misfit is within this many times the noise's
#: (reduced chi-square); beyond, the approach is not one quadratic over those frames and fewer are fitted
FIT_MISFIT = 4.0


@dataclass(frozen=True)
class _Root:
    """Where a fitted approach reaches the shut value: ``at`` frames after the fit's last frame, ``sd`` its
    standard uncertainty from the distance noise (frames), ``misfit`` the fit's reduced chi-square (NaN with no
    spare frame); ``x``, ``coef``, ``sigma_d``: the fit (frames from its last frame, polynomial, noise), for
    :meth:`sd_at`."""

    at: float
    sd: float
    misfit: float
    x: tuple[float, ...] = ()
    coef: tuple[float, ...] = ()
    sigma_d: float = 0.0

    def sd_at(self, at: float) -> float:
        """The distance noise carried to an instant ``at`` frames after the fit's last frame (the fitted value's
        standard deviation there over the fitted slope there), frames."""
        deg = len(self.coef) - 1
        weights = np.vander([at], deg + 1) @ np.linalg.pinv(np.vander(np.asarray(self.x), deg + 1))
        slope = float(np.polyval(np.polyder(np.asarray(self.coef)), at))
        return float(self.sigma_d * np.linalg.norm(weights) / abs(slope)) if slope < 0 else float("inf")


def _fit_root(d: np.ndarray, idx: np.ndarray, shut: float, sigma_d: float) -> _Root | None:
    """The approach over frames ``idx`` (a quadratic, or a line through two) solved for ``shut``: the first
    solution from a quarter frame before the last frame on; its noise propagated from ``sigma_d`` (the fitted
    value's standard deviation at the solution over the slope there)."""
    x = (idx - idx[-1]).astype(np.float64)
    y = d[idx] - shut
    deg = 2 if idx.size >= 3 else 1
    vander = np.vander(x, deg + 1)
    coef, *_ = np.linalg.lstsq(vander, y, rcond=None)
    if deg == 1:
        if coef[0] == 0:
            return None
        root = float(-coef[1] / coef[0])
    else:
        r = np.roots(coef)
        r = r[np.abs(r.imag) < 1e-9].real
        r = r[r >= -0.25]
        if not r.size:
            return None
        root = float(r.min())
    rss = float(np.sum((vander @ coef - y) ** 2))
    dof = idx.size - deg - 1
    fit = _Root(root, 0.0, rss / (dof * sigma_d ** 2) if dof > 0 else float("nan"), tuple(x), tuple(coef), sigma_d)
    sd = fit.sd_at(root)
    return None if not np.isfinite(sd) else dataclasses.replace(fit, sd=sd)


def _approach(d: np.ndarray, last: int, shut: float, sigma_d: float, opened: float, n_fit: int) -> _Root | None:
    """The approach up to frame ``last`` solved for ``shut`` (frames after ``last``), fitted on as many of its
    last frames (three to ``n_fit``, measured, below the open distance by more than 3 σ_d: closing) as one
    quadratic explains within :data:`FIT_MISFIT`; with fewer than three closing frames, the one before them
    (the arms at rest, open) joins them; None when under two frames are left."""
    idx = np.arange(max(last - n_fit + 1, 0), last + 1)
    idx = idx[np.isfinite(d[idx])]
    if idx.size == 0 or idx[-1] != last:
        return None
    closing = d[idx] < opened - 3.0 * sigma_d
    first = idx.size - int(np.argmin(closing[::-1])) if not closing.all() else 0
    if idx.size - first < 3:
        first = max(first - 1, 0)
    idx = idx[first:]
    if idx.size < 2:
        return None
    best = _fit_root(d, idx[-3:], shut, sigma_d)
    for n in range(4, idx.size + 1):
        r = _fit_root(d, idx[-n:], shut, sigma_d)
        if r is None or not r.misfit <= FIT_MISFIT:
            break
        best = r
    return best


def _contact_crossing(d: np.ndarray, k0: int, shut: float, sigma_d: float, n_fit: int,
                      opened: float) -> tuple[float, float]:
    """Fractional frame where the closing trajectory reaches ``shut``, near the first frame k0 within the margin,
    and its standard uncertainty (frames).

    The arms stop abruptly at contact, so the distance has a kink there: interpolating linearly between the
    two frames around the crossing would put the contact up to a frame late. Instead the closing trajectory
    is fitted on its last frames before k0 (:func:`_approach`) and solved for ``shut``, within [k0 − 1, k0]. When
    that solution lies beyond k0 and frame k0 is still more than 2 σ_d above the shut value (closing, only within
    the margin), the trajectory is refitted up to k0 and solved within [k0, k0 + 1]. When the frames just before
    k0 are missing (a ghost sample taken out at contact, a marker lost), the trajectory up to the last measured
    frame is solved within the gap.

    The uncertainty is the distance noise carried through the fit, and the model's own
    (:data:`CONTACT_MODEL_FRAMES`, growing as the square of how far the fit is carried past its last frame), at
    most that of a contact anywhere between the last frame seen open and k0 (their distance over √12); a fit
    reaching shut past k0 puts the contact at k0 (the first frame shut), and one that does not reach shut within
    the frames a gap hid (the closing hidden by it) leaves the contact halfway across them.
    """
    last = k0 - 1
    while last > 0 and not np.isfinite(d[last]):
        last -= 1
    root = _approach(d, last, shut, sigma_d, opened, n_fit)
    k = k0
    while (last == k - 1 and root is not None and root.at > 1.0 and d[k] - shut > 2.0 * sigma_d
           and k + 1 < d.size and k - k0 < 3):
        # frame k, though within the band, is still closing (a wide band under noise): the approach goes on
        later = _approach(d, k, shut, sigma_d, opened, n_fit)
        if later is None:
            break
        if later.at <= 1.0 or not np.isfinite(d[k + 1]):
            return float(k + np.clip(later.at, 0.0, 1.0)), min(_root_sd(later, 1.0), 1.0 / np.sqrt(12.0))
        last, k, root = k, k + 1, later
    span = float(k - last)                    # the contact lies between the last frame seen open and k
    uniform = span / np.sqrt(12.0)
    if root is None or (span > 1.0 and root.at > span):
        # no fit reaches shut within the frames a gap hid (the closing hidden by it): anywhere between them
        return float(last) + 0.5 * span, uniform
    at = float(np.clip(root.at, 0.0, span))
    if at != root.at:                         # the fit's noise at the contact reported (k0, or the last frame seen)
        root = dataclasses.replace(root, sd=min(root.sd_at(at), root.sd))
    return float(last + at), min(_root_sd(root, max(at, 1.0)), uniform)


def _root_sd(root: _Root, reach: float) -> float:
    """A contact's standard uncertainty, frames: the noise's through the fit, and the model's
    (:data:`CONTACT_MODEL_FRAMES`), which grows as the square of ``reach`` (frames from the fit's last frame to the
    contact; one within the next frame)."""
    return float(np.hypot(root.sd, CONTACT_MODEL_FRAMES * reach * reach))


def _plateau_start(d: np.ndarray, s: int, shut: float, margin: float, near: float, n_shut: int) -> int | None:
    """First frame from ``s`` within ``near`` of ``shut`` from which the next ``n_shut`` measured frames all stay
    that near; None when there is none. (A frame still closing inside the band, at a high rate, is told apart
    from the contact by :func:`_contact_crossing`.)"""
    close = np.abs(d - shut) <= near                # NaN compares False
    measured = np.isfinite(d)
    for k in np.flatnonzero(close[s:]) + s:
        ahead = slice(k, min(k + n_shut, d.size))
        if not (close[ahead] | ~measured[ahead]).all() or not measured[ahead].any():
            continue
        return int(k)
    return None


def mocap_claps(clap_a_xyz: np.ndarray, clap_b_xyz: np.ndarray, valid_a: np.ndarray, valid_b: np.ndarray,
                rate_hz: float, *, speed_k: float = 8.0, min_speed_mm_s: float = 100.0,
                min_depth_mm: float = 20.0, margin_mm: float = 1.0, margin_k: float = 5.0,
                plateau_s: float = 0.3, open_s: float = 0.3, fit_s: float = 0.08,
                min_separation_s: float = 1.0, lag_s: float = 0.02, z_lo: float = 8.0,
                z_hi: float = 40.0, min_shut_s: float = 0.1, bounce_mm: float = 8.0,
                max_gap_s: float = 0.2) -> list[Clap]:
    """Every clap in the clapper markers' trajectories.

    Parameters
    ----------
    clap_a_xyz, clap_b_xyz : (T, 3) marker positions, mm (NaN allowed where invalid).
    valid_a, valid_b : (T,) validity masks.
    rate_hz : mocap frame rate; frame i is at i / rate_hz seconds.
    speed_k, min_speed_mm_s : a closing event is a run of frames whose distance velocity is below
        −max(speed_k · σ_v, min_speed_mm_s), σ_v the robust (MAD) spread of the distance velocity over the
        whole take.
    lag_s : the distance velocity is a central difference over ± max(1, round(lag_s · rate)) frames, so that
        its noise, and the confidence, do not grow with the frame rate.
    min_depth_mm : the distance must drop at least this much (open − shut).
    margin_mm, margin_k : the clapper counts as shut within max(margin_mm, margin_k · σ_d) of the shut value,
        σ_d the robust spread of the distance on the plateau after the closing.
    plateau_s : the plateau after the fastest closing from which the shut value is taken (its median); the
        clapper must stay shut over most of it, or the event is not a clap.
    open_s : the open distance is the largest one in the ``open_s`` before the closing.
    fit_s : length of the closing trajectory fitted to refine the contact (at least three frames).
    min_separation_s : two claps closer than this are one (the faster closing is kept).
    z_lo, z_hi : confidence = the smaller of the closing speed over σ_v and the depth over σ_d, mapped
        linearly so that ``z_lo`` (the detection floor) gives 0 and ``z_hi`` or more gives 1.
    min_shut_s, bounce_mm : the contact is the start of the shut plateau: the first frame, after the fastest
        closing, within ``bounce_mm`` (or the margin, when larger) of the shut value from which the distance
        stays that near for ``min_shut_s``. A stick that rebounds or chatters a few millimetres for a frame or
        two right after contact neither ends the plateau nor moves the contact after the bounce. The shut value
        is read from the closing run's end on (a slow clap's fastest frame is far before its contact).
    max_gap_s : a clapper marker may be missing for up to this long across the contact: the plateau is read
        from the first measured frames after the closing, and the contact extrapolated into the gap
        (``Clap.gap_frames``); the confidence is scaled by 1 − (missing time / ``max_gap_s``).

    Returns
    -------
    The claps in time order. Each is the start of the shut plateau after the fastest closing of its event,
    refined below one frame by solving the fitted closing trajectory for the shut value (see
    :func:`_contact_crossing`).
    """
    d = clapper_distance(clap_a_xyz, clap_b_xyz, valid_a, valid_b)
    T = d.size
    rate = float(rate_hz)
    lag = max(1, round(lag_s * rate))
    if T < 2 * lag + 5:
        return []
    v = np.full(T, np.nan)
    v[lag:-lag] = (d[2 * lag:] - d[:-2 * lag]) * (rate / (2 * lag))
    sigma_v = _robust_sigma(v)
    if not np.isfinite(sigma_v):
        return []
    thr = max(speed_k * sigma_v, min_speed_mm_s)
    closing = np.nan_to_num(v, nan=0.0) < -thr
    n_plat = max(5, round(plateau_s * rate))
    n_open = max(3, round(open_s * rate))
    n_fit = max(3, round(fit_s * rate))
    n_gap = max(1, round(max_gap_s * rate))
    found: list[Clap] = []
    for s, e in true_runs(closing):
        f = s + int(np.nanargmin(v[s:e]))
        # the plateau's first measured frames: a marker lost for a few frames across the contact only delays it
        # (from the closing's end: a slow clap's fastest frame is far from its contact)
        p0 = max(f + 1, e)
        seen = p0 + np.flatnonzero(np.isfinite(d[p0: p0 + n_plat + n_gap]))[:n_plat]
        if seen.size < 0.8 * n_plat:
            continue  # not enough of the plateau seen (end of the take or occluded)
        plat = d[seen]
        shut = float(np.nanmedian(plat))
        sigma_d = max(_robust_sigma(plat), sigma_v * np.sqrt(2.0) * lag / rate)
        margin = max(margin_mm, margin_k * sigma_d)
        tail = plat[len(plat) // 2:]
        if np.count_nonzero(np.abs(tail - shut) <= margin) < 0.8 * tail.size:
            continue  # the clapper does not stay shut: not a clap
        before = d[max(s - n_open, 0): f + 1]
        if not np.any(np.isfinite(before)):
            continue
        opened = float(np.nanmax(before))
        if opened - shut < min_depth_mm:
            continue
        k0 = _plateau_start(d, s, shut, margin, max(bounce_mm, margin), max(2, round(min_shut_s * rate)))
        if k0 is None:
            continue
        frame, sd_frames = _contact_crossing(d, k0, shut, sigma_d, n_fit, opened)
        last_seen = k0 - 1
        while last_seen > f and not np.isfinite(d[last_seen]):
            last_seen -= 1
        speed = float(-v[f])
        z = min(speed / max(sigma_v, 1e-12), (opened - shut) / max(sigma_d, 1e-12))
        unseen = int(k0 - 1 - last_seen)
        # a contact extrapolated across missing frames is only as sure as the share of max_gap_s left unseen
        seen_share = float(np.clip(1.0 - unseen / rate / max_gap_s, 0.0, 1.0))
        clap = Clap(time_s=frame / rate, frame=frame, confidence=_score(z, z_lo, z_hi) * seen_share,
                    closing_speed_mm_s=speed, open_mm=opened, shut_mm=shut, margin_mm=margin,
                    gap_frames=unseen, timing_s=sd_frames / rate)
        if found and clap.time_s - found[-1].time_s < min_separation_s:
            if clap.closing_speed_mm_s > found[-1].closing_speed_mm_s:
                found[-1] = clap
            continue
        found.append(clap)
    return found



def clap_profile(d: np.ndarray, rate_hz: float, clap: Clap, step_s: float, before_s: float = 1.0,
                 after_s: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """How fast the clapper moved around a clap, for finding the same motion in the video.

    Parameters
    ----------
    d : (T,) clapper distance, mm, NaN where unknown (:func:`clapper_distance`).
    rate_hz : mocap frame rate.
    clap : the clap.
    step_s : grid step (the video's frame interval), seconds.
    before_s, after_s : the profile spans [−before_s, after_s] seconds around the contact.

    Returns
    -------
    offsets_s : (P,) seconds from the contact, every ``step_s``.
    speed : (P,) |d'| at those instants, mm/s: the distance moved between consecutive frames over their
        interval, placed at the interval's midpoint (as a video frame difference is), with the gaps of d
        bridged linearly, interpolated onto the grid.
    """
    t = np.arange(d.size, dtype=np.float64) / rate_hz
    ok = np.isfinite(d)
    filled = np.interp(t, t[ok], d[ok]) if ok.any() else np.zeros_like(t)
    mid = t[:-1] + 0.5 / rate_hz
    speed = np.abs(np.diff(filled)) * rate_hz
    offsets = np.arange(-round(before_s / step_s), round(after_s / step_s) + 1) * step_s
    return offsets, np.interp(clap.time_s + offsets, mid, speed, left=0.0, right=0.0)
