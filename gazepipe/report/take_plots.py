"""A take's plots, as inline SVG strings written directly (:mod:`gazepipe.report.svg`, no matplotlib figure):
the gap timeline, the speed trace, the clap alignment and the eye confidence. They look as the matplotlib plots
that drew them before looked (same sizes, margins, fonts, colours, ticks and labels) at a small part of the cost:
a long trace is one path, a raster one PNG, each tick a few characters.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from gazepipe.model import FILL_CODES
from gazepipe.report import svg as S
from gazepipe.stages.clean.qc import GapQC

#: colours of the fill methods (measured light grey, unfilled red)
FILL_COLOURS = {"measured": "#eeeeee", "linear": "#1f77b4", "pchip": "#17becf", "rigid": "#2ca02c",
                "pca": "#9467bd", "unfilled": "#d62728", "swap_repaired": "#ff7f0e"}


def envelope(x: np.ndarray, y: np.ndarray, max_bins: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """A long trace reduced to the minimum and maximum of ``max_bins`` equal bins (drawn as a line it looks the
    same at figure resolution, peaks included); traces up to ``2 · max_bins`` samples are returned as they are."""
    n = y.size
    if n <= 2 * max_bins:
        return x, y
    edges = np.linspace(0, n, max_bins + 1).astype(np.int64)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lo = np.fmin.reduceat(y, edges[:-1])
        hi = np.fmax.reduceat(y, edges[:-1])
    xc = 0.5 * (x[edges[:-1]] + x[np.minimum(edges[1:], n) - 1])
    return np.repeat(xc, 2), np.column_stack([lo, hi]).reshape(-1)


def _frame(width: float, height: float, salt: str, left: float = 0.7, right: float = 0.2, bottom: float = 0.45,
           top: float = 0.3) -> tuple[S.Canvas, S.Axes]:
    """A canvas of ``width`` × ``height`` inches with one axes inside fixed margins (inches)."""
    c = S.Canvas(width, height, salt)
    return c, c.add_axes(left * 72, (width - right) * 72, (height - bottom) * 72, top * 72)


def fill_codes(labels: Sequence[str], n_frames: int, gaps: Sequence[GapQC], raw_valid: np.ndarray | None) -> np.ndarray:
    """Markers × frames, each sample's fill method (:data:`gazepipe.model.FILL_CODES`): the clean stage's gap
    records, or without them the raw gaps as unfilled."""
    code = np.full((len(labels), n_frames), FILL_CODES["measured"], dtype=np.int8)
    row = {lab: i for i, lab in enumerate(labels)}
    if gaps:
        for g in gaps:
            if g.marker in row:
                code[row[g.marker], int(g.start):int(g.stop)] = FILL_CODES[g.method]
    elif raw_valid is not None:
        code[~raw_valid.T] = FILL_CODES["unfilled"]
    return code


def gap_timeline(labels: Sequence[str], n_frames: int, rate_hz: float, gaps: Sequence[GapQC],
                 crop: Sequence[int] | None, raw_valid: np.ndarray | None, salt: str) -> str:
    """Markers × time, each sample coloured by how it was filled; outside the crop shaded.

    ``gaps``: the clean stage's gap records (marker, start, stop, method); without them (no clean QC) the raw
    gaps are drawn as unfilled.
    """
    code = fill_codes(labels, n_frames, gaps, raw_valid)
    names = sorted(FILL_CODES, key=FILL_CODES.__getitem__)
    t_end = n_frames / rate_hz
    c, ax = _frame(9.0, 1.2 + 0.11 * len(labels), salt, left=0.8, top=0.35)
    ax.xlim, ax.ylim = (0.0, t_end), (max(len(labels), 1) - 0.5, -0.5)
    ax.image(code, [FILL_COLOURS[n] for n in names])
    if crop is not None:
        a, b = crop[0] / rate_hz, crop[1] / rate_hz
        ax.vspan(0.0, a, "#000000", 0.15)
        ax.vspan(b, t_end, "#000000", 0.15)
        ax.vline(a, "#000000", 0.8)
        ax.vline(b, "#000000", 0.8)
    ax.spines()
    ax.auto_xticks()
    # one name per marker, left of its row
    rows = ax.py(np.arange(len(labels)))
    x = ax.left - 0.004 * ax.width
    ax.parts.extend(S.text(x, float(y) + 0.26 * 6, lab, 6, "end") for y, lab in zip(rows, labels, strict=True))
    ax.xlabel("time (s)")
    keys = [S.Key("patch", FILL_COLOURS[n], n) for n in names]
    if crop is not None:
        keys += [S.Key("patch", "#000000", "cropped out (before/after the rests)", alpha=0.15),
                 S.Key("line", "#000000", "crop bounds", lw=0.8)]
    c.parts.extend(S.legend(keys, ax.left, ax.top, right=False, below=False, handle=1.5, spacing=1.0))
    return c.render()


def speed_plot(speed: np.ndarray, rate_hz: float, crop: Sequence[int] | None, rests: Sequence[Sequence[int]],
               threshold: float | None, salt: str) -> str:
    """Mean subject-marker speed (log scale) with the rest threshold, the rests and the crop bounds."""
    t = np.arange(speed.size) / rate_hz
    pos = np.where(speed > 0, speed, np.nan)
    c, ax = _frame(9.0, 2.4, salt, top=0.4)
    ax.xlim = (0.0, max(float(t[-1]) if t.size else 1.0, 1e-3))
    ax.ylog = bool(np.isfinite(pos).any())
    ax.ylim = S.autoscale([pos] + ([np.array([threshold])] if threshold is not None else []), log=ax.ylog)
    for a, b in rests:
        ax.vspan(a / rate_hz, b / rate_hz, "#2ca02c", 0.15)
    ax.line(*envelope(t, pos), "#333333", 0.8)
    keys = [S.Key("line", "#333333", "mean marker speed", lw=0.8)]
    if threshold is not None:
        ax.hline(threshold, "#2ca02c", 0.8, dashed=True)
        keys.append(S.Key("line", "#2ca02c", f"rest threshold {threshold:g} mm/s", lw=0.8, dashed=True))
    if crop is not None:
        for f in crop:
            ax.vline(f / rate_hz, "#d62728", 1.0)
        keys.append(S.Key("line", "#d62728", "crop bounds", lw=1.0))
    ax.spines()
    ax.auto_xticks()
    if ax.ylog:
        major, labels, minor = S.log_ticks(*ax.ylim, ax.height)
        width = ax.yticks(major, labels, minor)
    else:
        width = ax.auto_yticks()
    ax.xlabel("time (s)")
    ax.ylabel("mm/s", width)
    ax.title("speed, rests (green) and crop")
    c.parts.extend(S.legend(keys, ax.left + ax.width, ax.top, right=True, below=False))
    return c.render()


def clap_plot(distance: np.ndarray, rate_hz: float, mocap_s: Sequence[float], video_on_mocap_s: Sequence[float | None],
              salt: str, half_window_s: float = 1.0) -> str:
    """Clapper distance around each clap, with the mocap clap and the video clap mapped onto the mocap clock."""
    n = max(len(mocap_s), 1)
    t = np.arange(distance.size) / rate_hz
    width, height = min(3.0 * n, 9.0) + 0.6, 2.4
    c = S.Canvas(width, height, salt)
    left, right, top, bottom = 0.7 * 72, (width - 0.2) * 72, 0.5 * 72, (height - 0.45) * 72
    aw = (right - left) / (n + 0.25 * (n - 1))           # subplots 0.25 of an axes' width apart
    for i, (tm, tv) in enumerate(zip(mocap_s, video_on_mocap_s, strict=True)):
        x0 = left + i * 1.25 * aw
        ax = c.add_axes(x0, x0 + aw, bottom, top)
        sel = (t >= tm - half_window_s) & (t <= tm + half_window_s)
        x, y = t[sel] - tm, distance[sel]
        marks = [0.0] + ([tv - tm] if tv is not None else [])
        ax.xlim = S.autoscale([x[np.isfinite(y)] if y.size else x, np.array(marks)])
        ax.ylim = S.autoscale([y])
        ax.line(x, y, "#333333", 0.9)
        ax.dots(x, y, "#333333", 2.0)
        ax.vline(0.0, "#1f77b4", 1.0)
        if tv is not None:
            ax.vline(tv - tm, "#ff7f0e", 1.0, dashed=True)
        ax.spines()
        ax.auto_xticks()
        labels_width = ax.auto_yticks()
        ax.title(f"clap {i + 1} at {tm:.2f} s" + ("" if tv is None else f", video {1000 * (tv - tm):+.1f} ms"),
                 centred=True)
        ax.xlabel("time from mocap clap (s)")
        if i == 0:
            ax.ylabel("clapper distance (mm)", labels_width)
    # one legend for every panel, above them (inside an axes it covers the trace)
    c.parts.extend(S.legend([S.Key("line", "#1f77b4", "mocap clap"),
                             S.Key("line", "#ff7f0e", "video clap on the mocap clock", dashed=True)],
                            c.w, 0.0, right=True, below=True))
    return c.render()


def eye_plot(time_s: np.ndarray, confidence: np.ndarray, valid: np.ndarray, filled: np.ndarray,
             gate: float | None, salt: str) -> str:
    """Eye-tracking confidence on the mocap frames, the gate, invalid frames shaded, filled frames marked."""
    c, ax = _frame(9.0, 2.2, salt, top=0.4)
    ax.ylim = (-0.02, 1.02)
    conf = np.asarray(confidence, np.float64)
    if time_s.size:
        dt = float(np.median(np.diff(time_s))) if time_s.size > 1 else 1.0
        ax.xlim = (float(time_s[0]), float(time_s[-1]) + dt)
        # invalid (red) and slerp-filled (blue) frames as one background strip: a raster, whatever the length
        strip = np.where(np.asarray(filled, bool), 2, np.where(np.asarray(valid, bool), 0, 1))[None, :]
        ax.image(strip.astype(np.int8), ["#ffffff", "#f4c2c2", "#c6dbef"])
    ax.line(*envelope(np.asarray(time_s, np.float64), conf), "#333333", 0.7)
    keys = [S.Key("line", "#333333", "confidence", lw=0.7), S.Key("square", "#f4c2c2", "invalid"),
            S.Key("square", "#c6dbef", "slerp-filled")]
    if gate is not None:
        ax.hline(gate, "#ff7f0e", 0.9, dashed=True)
        keys.append(S.Key("line", "#ff7f0e", f"gate {gate:g}", lw=0.9, dashed=True))
    ax.spines()
    ax.auto_xticks()
    ax.auto_yticks()
    ax.xlabel("time (s)")
    ax.title("eye confidence")
    c.parts.extend(S.legend(keys, ax.left + ax.width, ax.top, right=True, below=False))
    return c.render()
