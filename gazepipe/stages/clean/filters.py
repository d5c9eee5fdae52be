"""Zero-phase filtering of marker trajectories run by run (SPEC §3.2 step 4, and the rest speeds of step 5).

Every filter here works on each marker's runs of valid samples separately and never across a gap: a Butterworth
low-pass run forward and backward (its cutoff corrected so the pair is −3 dB where asked) and a Gaussian
low-pass. Positions are (T, M, 3) float64 mm; ``valid`` is (T, M) bool; runs are half-open row ranges.
"""

from __future__ import annotations

from typing import Literal

import numpy as np


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


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open (start, stop) runs of True in a 1-D bool array."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(d[0::2].tolist(), d[1::2].tolist(), strict=True))


def lowpass_runs(xyz: np.ndarray, valid: np.ndarray, sos: np.ndarray,
                 padtype: Literal["odd", "even"] = "odd") -> tuple[np.ndarray, int]:
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
        for a, b in true_runs(valid[:, m]):
            if b - a <= padlen:
                short += 1
                continue
            out[a:b, m] = signal.sosfiltfilt(sos, xyz[a:b, m], axis=0, padtype=padtype, padlen=padlen)
    return out, short


def gaussian_runs(xyz: np.ndarray, valid: np.ndarray, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    """Gaussian low-pass (−3 dB at ``cutoff_hz``, σ = √(ln 2)/(2π f) s) of every marker's runs of valid samples
    separately (never across a gap; edges reflected so a still edge stays still)."""
    from scipy import ndimage

    sigma = np.sqrt(np.log(2.0)) / (2.0 * np.pi * cutoff_hz) * rate_hz   # in samples
    out = xyz.copy()
    for m in range(xyz.shape[1]):
        for a, b in true_runs(valid[:, m]):
            out[a:b, m] = ndimage.gaussian_filter1d(xyz[a:b, m], sigma, axis=0, mode="reflect", truncate=4.0)
    return out
