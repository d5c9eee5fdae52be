"""The ``clean`` stage (SPEC §3.2, Pejsa 5.2.2.1): spikes, gap filling, root stabilisation, optional
low-pass, rest-period cropping.

Pure functions on :class:`~gazepipe.model.Markers`; no file I/O. Positions stay on lab axes (the character
frame is the ``frames`` stage's business); after stabilisation the root marker sits at the lab origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gazepipe.errors import StageError
from gazepipe.model import FILL_CODES, Markers, MarkerSet
from gazepipe.stages.gapfill import G_MM_S2, METHODS, fill_gaps, remove_spikes
from gazepipe.stages.vectors import cross3, up_vector

UNFILLED = FILL_CODES["unfilled"]


@dataclass(frozen=True)
class CleanParams:
    """Parameters of :func:`clean_markers` (every threshold of SPEC §3.2).

    Attributes
    ----------
    max_gap_s : longest gap (s) that gets filled; longer gaps stay unfilled.
    remove_spikes : run spike removal before gap filling.
    spike_max_accel_mm_s2, spike_min_step_mm, spike_max_piece_s : thresholds of
        :func:`gazepipe.stages.gapfill.remove_spikes` (a second difference above
        max(accel / rate², min_step) is implausible; pieces cut off by such breaks shorter than max_piece_s
        become gaps). Defaults: 50 g, 100 mm, 0.5 s.
    fill_methods : candidate gap-filling methods, best chosen per gap (:func:`gazepipe.stages.gapfill.fill_gaps`).
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
        ``rest_refine``). Measured by tests/test_clean.py.
    rest_refine : move the end of every rest of at least 0.7 s to where the noise-free speed reaches the
        threshold, from a fit of the smoothed speed's rise (:func:`refine_onset`). Without it the end of the
        first rest of the sample session's gaze shifts comes 1–2 frames early (median −2); with it the
        median error is 0 and every end is within 1 frame. The rests themselves (which frames are still, the
        noise floor) do not change.
    remove_heading : also rotate every frame about the lab vertical so the root segment's left direction
        (its first marker minus its second, horizontal part) points along lab +X.

    Each field's metadata gives its allowed values (:func:`gazepipe.pipeline.registry.value_problem`).
    """

    max_gap_s: float = field(default=1.0, metadata={"min": 0})
    remove_spikes: bool = True
    spike_max_accel_mm_s2: float = field(default=50.0 * G_MM_S2, metadata={"gt": 0})
    spike_min_step_mm: float = field(default=100.0, metadata={"min": 0})
    spike_max_piece_s: float = field(default=0.5, metadata={"min": 0})
    fill_methods: tuple[str, ...] = field(default=METHODS, metadata={"choices": METHODS})
    lowpass_hz: float | None = field(default=None, metadata={"gt": 0})
    lowpass_order: int = field(default=2, metadata={"min": 1})
    rest_speed_mm_s: float = field(default=6.0, metadata={"gt": 0})
    rest_merge_s: float = field(default=1.0 / 6.0, metadata={"min": 0})
    rest_min_s: float = field(default=0.25, metadata={"min": 0})
    rest_filter_hz: float = field(default=1.75, metadata={"gt": 0})
    rest_refine: bool = True
    remove_heading: bool = False


@dataclass
class CleanResult:
    """Output of :func:`clean_markers`.

    Attributes
    ----------
    markers : cleaned, stabilised, cropped markers (mm, lab axes, root at the origin); ``first_frame`` is the
        source frame number of the first kept row.
    frames : (N,) int64 row indices of the kept rows in the uncropped take (``crop[0] .. crop[1]-1``).
    fill_code : (N, M) int8 :data:`~gazepipe.model.FILL_CODES` of every kept sample.
    crop : (start, stop) half-open, in rows of the uncropped take.
    rests : rest periods (start, stop) half-open, in rows of the uncropped take.
    speed_mm_s : (T,) mean subject-marker speed of the uncropped take (NaN where unknown).
    neutral : the cleaned (uncropped) frames of the first rest period, for neutral calibration
        (``None`` when no rest was found; for a take of kind ``neutral`` without a rest, the whole take, with a
        QC warning). Give the ``neutral`` take's (else the take's own) to :func:`~gazepipe.stages.frames.compute_frames`.
    qc : JSON-ready record (see :func:`clean_markers`).
    """

    markers: Markers
    frames: np.ndarray
    fill_code: np.ndarray
    crop: tuple[int, int]
    rests: list[tuple[int, int]]
    speed_mm_s: np.ndarray
    neutral: Markers | None
    qc: dict


# --------------------------------------------------------------------------------------------- filtering

def double_pass_correction(order: int, passes: int = 2) -> float:
    """Cutoff correction C of a Butterworth filter of ``order`` run ``passes`` times.

    One pass has |H|² = 1 / (1 + (ω/ω_d)^(2n)); p passes have |H|^(2p). Asking the cascade for −3 dB
    (|H|^(2p) = 1/2) at ω_c gives ω_c/ω_d = (2^(1/p) − 1)^(1/(2n)) = C, so the single pass is designed at
    ω_d = ω_c / C. For n = 2, p = 2: C = (√2 − 1)^(1/4) ≈ 0.802.
    """
    return float((2.0 ** (1.0 / passes) - 1.0) ** (1.0 / (2.0 * order)))


def zero_phase_sos(cutoff_hz: float, rate_hz: float, order: int = 2) -> np.ndarray:
    """Second-order sections of one pass of a Butterworth low-pass whose forward–backward (sosfiltfilt)
    response is −3 dB at ``cutoff_hz``.

    The correction C of :func:`double_pass_correction` applies to the analogue prototype, so it is applied
    to the pre-warped frequency: tan(π f_d / fs) = tan(π f_c / fs) / C, which makes the digital double pass
    exactly −3 dB at f_c (the bilinear transform maps the prototype's ω to tan(π f / fs)).
    """
    if not 0.0 < cutoff_hz < rate_hz / 2.0:
        raise ValueError(f"low-pass cutoff {cutoff_hz} Hz must lie in (0, {rate_hz / 2.0}) Hz")
    c = double_pass_correction(order)
    wd = np.arctan(np.tan(np.pi * cutoff_hz / rate_hz) / c) / np.pi * 2.0  # fraction of Nyquist
    from scipy import signal  # imported here: scipy.signal is slow to import and rarely needed

    return signal.butter(order, wd, btype="low", output="sos")


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open (start, stop) runs of True in a 1-D bool array."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(d[0::2].tolist(), d[1::2].tolist(), strict=True))


def lowpass_runs(xyz: np.ndarray, valid: np.ndarray, sos: np.ndarray,
                 padtype: str = "odd") -> tuple[np.ndarray, int]:
    """Zero-phase filter every marker's runs of valid samples separately (never across a gap).

    Parameters
    ----------
    xyz : (T, M, 3) positions; valid : (T, M) bool.
    sos : one pass of the filter (see :func:`zero_phase_sos`).
    padtype : edge extension of ``scipy.signal.sosfiltfilt`` (``odd`` keeps trends; ``even`` keeps a still
        edge still).

    Returns the filtered copy and the number of runs too short for the filter's padding (left unfiltered).
    """
    from scipy import signal

    out = xyz.copy()
    padlen = 3 * (2 * len(sos) + 1)
    short = 0
    for m in range(xyz.shape[1]):
        for a, b in _runs(valid[:, m]):
            if b - a <= padlen:
                short += 1
                continue
            out[a:b, m] = signal.sosfiltfilt(sos, xyz[a:b, m], axis=0, padtype=padtype, padlen=padlen)
    return out, short


# --------------------------------------------------------------------------------------------- rests

def gaussian_runs(xyz: np.ndarray, valid: np.ndarray, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    """Gaussian low-pass (−3 dB at ``cutoff_hz``, σ = √(ln 2)/(2π f) s) of every marker's runs of valid samples
    separately (never across a gap; edges reflected so a still edge stays still)."""
    from scipy import ndimage

    sigma = np.sqrt(np.log(2.0)) / (2.0 * np.pi * cutoff_hz) * rate_hz   # in samples
    out = xyz.copy()
    for m in range(xyz.shape[1]):
        for a, b in _runs(valid[:, m]):
            out[a:b, m] = ndimage.gaussian_filter1d(xyz[a:b, m], sigma, axis=0, mode="reflect", truncate=4.0)
    return out


def mean_speed(xyz: np.ndarray, valid: np.ndarray, rate_hz: float, filter_hz: float | None) -> np.ndarray:
    """Per-frame mean over markers of the speed (mm/s) by central differences, (T,); NaN where no marker has
    a speed. Positions are first smoothed by :func:`gaussian_runs` at ``filter_hz`` when it is given.
    """
    pos = xyz if filter_hz is None else gaussian_runs(xyz, valid, filter_hz, rate_hz)
    pos = np.where(valid[..., None], pos, np.nan)
    vel = np.full_like(pos, np.nan)
    if len(pos) >= 3:
        vel[1:-1] = (pos[2:] - pos[:-2]) * (rate_hz / 2.0)
    if len(pos) >= 2:  # one-sided at the ends
        vel[0] = (pos[1] - pos[0]) * rate_hz
        vel[-1] = (pos[-1] - pos[-2]) * rate_hz
    speed = np.linalg.norm(vel, axis=2)
    n = np.sum(np.isfinite(speed), axis=1)
    total = np.nansum(speed, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, total / np.maximum(n, 1), np.nan)


def rest_periods(speed: np.ndarray, rate_hz: float, threshold: float, merge_s: float,
                 min_s: float) -> list[tuple[int, int]]:
    """Rest periods (start, stop), half-open rows, from a per-frame speed (Pejsa 5.2.2.1 steps 2–3).

    Still = speed below ``threshold`` (NaN is not still); still runs separated by fewer than
    ``merge_s · rate`` frames merge; merged rests shorter than ``min_s · rate`` frames are dropped.
    """
    still = np.nan_to_num(speed, nan=np.inf) < threshold
    runs = _runs(still)
    merged: list[list[int]] = []
    for a, b in runs:
        if merged and (a - merged[-1][1]) < merge_s * rate_hz:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    return [(a, b) for a, b in merged if (b - a) >= min_s * rate_hz - 1e-9]


# Share of the subject's markers taken to be moving at a motion's onset, for how the noise floor f adds to the
# noise-free mean speed g: a moving marker's speed adds to its noise in quadrature, a still one's noise is
# added as it is, so the mean is √(g² + (q·f)²) + (1 − q)·f. A gaze shift starts with the head (a fifth to a
# third of the markers); measured on the sample session and on whole-segment moves, q = 0.3 leaves a median
# bias of 0 frames on both (q = 0: +1 frame on whole-segment moves; q = 1: −1 frame on the sample session).
ONSET_MOVING_SHARE = 0.3


_ONSET_TAUS = np.array([0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0])   # τ grid, in σ
_ONSET_STEP = 0.02                                                         # fine grid, in σ


def _onset_profiles(x_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-smoothed (σ = 1) onset shapes h_τ(d) = d² for 0 ≤ d < τ, then on with the slope 2τ they
    reached (τ² + 2τ(d − τ)); 0 before the onset. Returns the grid x (in σ) and the shapes (len(τ), len(x))."""
    x = np.arange(-6.0, x_max + 6.0, _ONSET_STEP)
    d = np.clip(x, 0.0, None)[None, :]
    tau = _ONSET_TAUS[:, None]
    h = np.where(d < tau, d * d, tau * tau + 2.0 * tau * (d - tau))
    u = np.arange(-4.0, 4.0 + _ONSET_STEP / 2, _ONSET_STEP)
    k = np.exp(-0.5 * u * u)
    k /= k.sum()
    return x, np.stack([np.convolve(row, k, mode="same") for row in h])


def refine_onset(speed: np.ndarray, b: int, sigma: float, threshold: float, lo: int, hi: int) -> int:
    """Unbiased first frame at or above ``threshold`` (the end of a rest) from a Gaussian-smoothed speed.

    The smoothed speed crosses the threshold early: the Gaussian (σ samples) spreads the motion's onset back.
    Model of the noise-free speed after the onset t0: A·((t − t0)/σ)² up to t0 + τσ, then on with the slope it
    reached (a smooth start, then a steady rise); smoothed by the same Gaussian and combined with the rest's
    noise floor f (the median speed of the rest before the window; see ``ONSET_MOVING_SHARE``), it is fitted to
    the smoothed speed from b − 3σ to the end of its rise (4·threshold or its first maximum) by exhaustive
    least squares over t0 (0.1-sample steps within 2σ of b), τ and A (log grids), which has no local minima to
    fall into. Returns the first frame where the fitted noise-free speed reaches the threshold, within
    [b − 1, b + 2σ]; ``b`` itself when the window is too short or not finite. ``lo``/``hi`` bound the frames
    the fit may use (the rest's start, the next rest's start).
    """
    n = len(speed)
    reach = int(np.ceil(3.0 * sigma))
    w0 = max(lo, b - reach)
    seg = speed[b:min(hi, b + 3 * reach)]
    stop = np.flatnonzero((seg >= 4.0 * threshold) | (np.diff(seg, append=np.inf) < 0))   # rise ends
    w1 = b + int(stop[0]) + 1 if len(stop) else b + len(seg)
    step = max(1, int(sigma // 3))          # the smoothed speed varies over σ: a few samples per σ suffice
    frames = np.arange(w0, w1, step)
    y = speed[frames]
    rest = speed[max(lo, w0 - 3 * reach):max(lo, b - reach)]
    if len(frames) < 5 or w1 > n or not np.isfinite(y).all():
        return b
    floor = float(np.median(rest)) if len(rest) >= 3 and np.isfinite(rest).all() else float(speed[w0])
    q = ONSET_MOVING_SHARE
    t0 = np.arange(b - 2.0 * sigma - 1.0, b + 2.0 * sigma, min(0.1, 0.05 * sigma))
    xd = (frames[None, :] - t0[:, None]) / sigma                             # (T0, F), in σ
    xs, prof = _onset_profiles(float(xd.max()))
    amp = threshold * np.geomspace(1e-3, 1e3, 161)                           # A, 4.4 % steps
    best = (np.inf, 0, 0, 0)
    for ik, p in enumerate(prof):
        g = amp[:, None, None] * np.interp(xd, xs, p)[None]                  # (A, T0, F)
        sse = np.sum((np.sqrt(g * g + (q * floor) ** 2) + (1.0 - q) * floor - y) ** 2, axis=-1)
        ia, it = np.unravel_index(int(np.argmin(sse)), sse.shape)
        if sse[ia, it] < best[0]:
            best = (float(sse[ia, it]), ia, ik, it)
    _, ia, ik, it = best
    a, tau = amp[ia], _ONSET_TAUS[ik]
    if a * tau * tau >= threshold:
        d_c = np.sqrt(threshold / a)
    else:
        d_c = tau + (threshold - a * tau * tau) / (2.0 * a * tau)
    t_c = t0[it] + d_c * sigma
    return int(np.clip(np.ceil(t_c - 1e-9), b - 1, b + int(np.ceil(2.0 * sigma))))


def refine_rests(rests: list[tuple[int, int]], speed: np.ndarray, rate_hz: float, filter_hz: float,
                 threshold: float) -> list[tuple[int, int]]:
    """Rest periods whose end (the onset of the motion after them) is moved to where the noise-free speed
    reaches the threshold (:func:`refine_onset`), for rests long enough to give the noise floor (at least
    9σ of the speed filter: 0.7 s at any rate; short pauses inside motion are left as found).

    Only ends: a motion decelerating into a rest often settles with a slow tail rather than to a still floor,
    and the smoothed speed's crossing there is already close (sample session: starts of the gaze shifts'
    second rests median 0, −1..+1 frames; of the gaze_follow takes' last rests 0..+2). The same fit in reversed
    time was measured and moved the gaze shifts' second-rest starts to a median of −1 (shortening the gaze_map
    duration) and the gaze_follow ones to −2..−1, so it is not applied."""
    sigma = np.sqrt(np.log(2.0)) / (2.0 * np.pi * filter_hz) * rate_hz
    reach = int(np.ceil(3.0 * sigma))
    n = len(speed)
    out = []
    for i, (a, b) in enumerate(rests):
        if b < n and b - a >= 3 * reach:
            nxt = rests[i + 1][0] if i + 1 < len(rests) else n
            b = max(a + 1, min(refine_onset(speed, b, sigma, threshold, a, nxt), nxt))
        out.append((a, b))
    return out


def crop_bounds(rests: list[tuple[int, int]], speed: np.ndarray, kind: str,
                tolerance: int = 0) -> tuple[tuple[int, int], list[str]]:
    """Crop (start, stop) for a take of ``kind`` and its QC warnings; raises ``ValueError`` with a short
    phrase when the rests the kind needs are missing.

    ``gaze_shift``: [end of the first rest, end of the second rest). ``neutral``: everything. Other kinds:
    without the leading rest (one that starts at most ``tolerance`` frames after the first frame with a known
    speed) and the trailing rest (likewise before the last).
    """
    n = len(speed)
    warnings: list[str] = []
    if kind == "neutral":
        return (0, n), warnings
    if kind == "gaze_shift":
        if len(rests) < 2:
            raise ValueError(f"found {len(rests)} rest period(s), a gaze_shift take needs two "
                             "(the wait before the cue and the fixation on the target)")
        if len(rests) > 2:
            warnings.append(f"{len(rests)} rest periods; cropped between the first two")
        return (rests[0][1], rests[1][1]), warnings
    known = np.flatnonzero(np.isfinite(speed))
    if len(known) == 0:
        raise ValueError("no frame with a known marker speed")
    first, last = int(known[0]), int(known[-1])
    start, stop = 0, n
    if rests and rests[0][0] <= first + tolerance:
        start = rests[0][1]
    else:
        warnings.append("no leading rest period; kept from the first frame")
    if rests and rests[-1][1] > last - tolerance:
        stop = rests[-1][0]
    else:
        warnings.append("no trailing rest period; kept to the last frame")
    if stop <= start:
        raise ValueError("the whole take is at rest: no motion to keep")
    return (start, stop), warnings


# --------------------------------------------------------------------------------------------- steps

def stabilise(xyz: np.ndarray, root: int, up: np.ndarray | None = None,
              left_pair: tuple[int, int] | None = None) -> np.ndarray:
    """Translate every frame so marker ``root`` is at the origin; frames where it is NaN become all NaN.

    With ``up`` and ``left_pair`` (the root segment's first and second marker), also rotate each frame about
    ``up`` so the horizontal part of (first − second) points along lab +X (frames where that is undefined
    become NaN).
    """
    out = xyz - xyz[:, root : root + 1, :]
    if up is None or left_pair is None:
        return out
    from scipy.spatial.transform import Rotation

    left = out[:, left_pair[0]] - out[:, left_pair[1]]
    left = left - (left @ up)[:, None] * up
    ex = np.zeros(3)
    ex[int(np.argmax(np.abs(up) < 0.5))] = 1.0  # lab X (or Y when X is vertical)
    ey = cross3(up, ex)
    ang = np.arctan2(left @ ey, left @ ex)           # heading of "left" about up, from ex
    ok = np.isfinite(ang) & (np.linalg.norm(left, axis=1) > 1e-9)
    res = np.full_like(out, np.nan)
    if ok.any():
        rot = Rotation.from_rotvec(-ang[ok, None] * up[None, :])
        pts = out[ok]
        res[ok] = pts @ np.swapaxes(rot.as_matrix(), 1, 2)  # R · p for every point, as row vectors
    return res


def _marker_qc(fill_code: np.ndarray, valid_in: np.ndarray, labels: list[str], rate_hz: float,
               spikes: np.ndarray) -> dict:
    """Per-marker QC from the gaps (after spike removal) and the fill codes."""
    out: dict = {}
    for m, lab in enumerate(labels):
        gaps = _runs(~valid_in[:, m])
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


def _fill(markers: Markers, markerset: MarkerSet, params: CleanParams,
          qc: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spikes → gaps, then gap filling. Returns (xyz, fill_code, valid after spike removal)."""
    valid = markers.valid & np.isfinite(markers.xyz).all(axis=2)
    xyz = np.where(valid[..., None], markers.xyz, np.nan)
    spikes = np.zeros(markers.n_markers, dtype=np.int64)
    if params.remove_spikes:
        valid, spikes = remove_spikes(xyz, valid, markers.rate_hz, max_accel_mm_s2=params.spike_max_accel_mm_s2,
                                      min_step_mm=params.spike_min_step_mm, max_piece_s=params.spike_max_piece_s)
        xyz = np.where(valid[..., None], xyz, np.nan)
    qc["spikes_removed"] = int(spikes.sum())
    qc["gaps"] = []
    if valid.all():  # nothing to fill
        code = np.zeros(valid.shape, dtype=np.int8)
    else:
        pos = {lab: i for i, lab in enumerate(markers.labels)}
        clusters = [[pos[n] for n in s.markers if n in pos] for s in markerset.segments]
        res = fill_gaps(xyz, valid, markers.rate_hz, clusters=[c for c in clusters if len(c) >= 2],
                        max_gap_s=params.max_gap_s, methods=tuple(params.fill_methods))
        code = np.asarray(res.fill_code, dtype=np.int8)
        xyz = np.where((code != UNFILLED)[..., None], np.asarray(res.xyz, dtype=np.float64), np.nan)
        qc["gaps"] = [{"marker": markers.labels[g.marker], "start": int(g.start), "stop": int(g.stop),
                       "method": g.method,
                       "errors_mm": {k: (None if not np.isfinite(v) else float(v)) for k, v in g.errors.items()},
                       "weights": {k: float(v) for k, v in g.weights.items()}}
                      for g in res.gaps]
    qc["markers"] = _marker_qc(code, valid, markers.labels, markers.rate_hz, spikes)
    return xyz, code, valid


def _rest_positions(xyz: np.ndarray, valid: np.ndarray, labels: list[str], markerset: MarkerSet,
                    subj: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Subject positions for rest speeds: relative to the mean of the root marker and the root segment's
    markers rather than to the root marker alone.

    Both remove the body's translation (Pejsa's reason to stabilise first), but every stabilised marker carries
    the root marker's noise; the mean of four markers has half of it, which lowers the speed noise floor by
    about a third and lets the speed filter be lighter (closer rest bounds). Frames where one of those markers
    is unfilled have no rest speed.
    """
    ref = [labels.index(n) for n in (markerset.root, *markerset.root_segment.markers) if n in labels]
    offset = xyz[:, ref].mean(axis=1, keepdims=True)          # NaN where any of them is unfilled
    pos = xyz[:, subj] - offset
    return pos, valid[:, subj] & np.isfinite(pos).all(axis=2)


def clean_markers(markers: Markers, markerset: MarkerSet, kind: str, params: CleanParams | None = None,
                  *, path: str | None = None, take: str | None = None) -> CleanResult:
    """Clean one take's markers (SPEC §3.2).

    Steps: spike removal → gap filling (clusters = the markerset's segments) → root stabilisation (lab axes,
    optional heading removal; frames without the root marker become unfilled) → optional zero-phase
    low-pass per run of valid samples → rest detection on the subject's markers → cropping by ``kind``.

    Raises :class:`~gazepipe.errors.StageError` (one line, naming ``path``/``take``) when the root marker is
    missing or the rest periods the kind needs are not found.

    ``qc`` holds: ``markers`` (per marker: gaps after spike removal, longest gap in frames and seconds, spikes
    removed, samples per fill method, unfilled samples), ``spikes_removed`` (total), ``gaps`` (every gap:
    marker, start, stop, method, each method's validation error in mm), ``root_missing_frames``, ``lowpass`` (cutoff,
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

    xyz, code, _ = _fill(markers, markerset, params, qc)

    # 3. stabilisation
    up = left_pair = None
    if params.remove_heading:
        rs = markerset.root_segment
        if len(rs.markers) < 2 or any(n not in labels for n in rs.markers[:2]):
            raise StageError(path, f"heading removal needs the root segment {rs.name!r}'s first two markers",
                             take=take)
        up = up_vector(markerset.up_axis)
        left_pair = (labels.index(rs.markers[0]), labels.index(rs.markers[1]))
    xyz = stabilise(xyz, root, up, left_pair)
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
    subj = [labels.index(n) for n in markerset.subject_markers if n in labels]
    speed = mean_speed(*_rest_positions(xyz, valid, labels, markerset, subj), rate, params.rest_filter_hz)
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

    def _slice(a: int, b: int) -> Markers:
        return replace(markers, xyz=xyz[a:b].copy(), valid=valid[a:b].copy(),
                       first_frame=int(markers.first_frame) + a, warnings=list(markers.warnings))

    neutral = _slice(*rests[0]) if rests else None
    if kind == "neutral" and neutral is None and markers.n_frames:
        neutral = _slice(0, markers.n_frames)
        qc["warnings"].append("no rest period in the neutral take; its every frame is the neutral pose")
    return CleanResult(markers=_slice(start, stop), frames=np.arange(start, stop, dtype=np.int64),
                       fill_code=code[start:stop].copy(), crop=(int(start), int(stop)), rests=rests,
                       speed_mm_s=speed, neutral=neutral, qc=qc)


__all__ = ["CleanParams", "CleanResult", "clean_markers", "crop_bounds", "double_pass_correction", "gaussian_runs",
           "lowpass_runs", "mean_speed", "refine_onset", "refine_rests", "rest_periods", "stabilise",
           "zero_phase_sos"]
