"""The report's pictures, as inline SVG strings (matplotlib's object interface and SVG backend, no pyplot;
byte-stable: fixed hash salt, no dates).

Each function returns an SVG element ready to paste into HTML: no XML prologue, no DOCTYPE, no namespace URLs
(the HTML parser puts ``<svg>`` in the SVG namespace by itself), text kept as text.

Drawing time is mostly matplotlib's fixed cost per axes, tick and text, so the plots keep those few: no pyplot
figure manager, fixed margins (no automatic layout), one rcParams context per figure, marker names drawn as plain
text instead of one tick object each, and range bars drawn as one path per pose instead of a collection.
"""

from __future__ import annotations

import io
import re
import warnings
from collections.abc import Sequence
from typing import Any

import matplotlib
import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FormatStrFormatter, NullFormatter

from gazepipe.model import FILL_CODES
from gazepipe.stages.clean.qc import GapQC

#: colours of the fill methods (measured light grey, unfilled red)
FILL_COLOURS = {"measured": "#eeeeee", "linear": "#1f77b4", "pchip": "#17becf", "rigid": "#2ca02c",
                "pca": "#9467bd", "unfilled": "#d62728", "swap_repaired": "#ff7f0e"}
#: matplotlib style of every plot; titles at a fixed height (automatic placement measures every tick label, a fifth
#: of the drawing time, to put them where they already are)
_STYLE = {"font.size": 8, "axes.titlesize": 9, "axes.labelsize": 8, "legend.fontsize": 7, "svg.fonttype": "none",
          "font.family": "DejaVu Sans", "axes.spines.top": False, "axes.spines.right": False, "axes.titley": 1.0}
#: the tab10 colours, one per pose
_TAB10 = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
          "#17becf")


def _style(salt: str):
    """The rcParams of every plot (and the SVG id salt), for building and saving one figure."""
    style: dict[Any, Any] = {**_STYLE, "svg.hashsalt": salt}   # rcParams are keyed by literal names
    return matplotlib.rc_context(style)


def to_svg(fig: Figure, salt: str) -> str:
    """Render ``fig`` as an inline SVG element. ``salt`` must be unique per figure in a page (it seeds
    matplotlib's element ids, which share one id space in an HTML document)."""
    with _style(salt):
        return _svg(fig)


def _svg(fig: Figure) -> str:
    """:func:`to_svg` inside :func:`_style` (every plot builds and saves its figure in one rcParams context)."""
    buf = io.StringIO()
    fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None, "Format": None, "Type": None})
    text = buf.getvalue()
    text = text[text.index("<svg"):]
    text = re.sub(r'\s+xmlns(:\w+)?="[^"]*"', "", text, count=3)
    text = re.sub(r"<metadata>.*?</metadata>\s*", "", text, flags=re.S)
    return text.strip()


def _fig(w: float, h: float) -> Figure:
    """A figure of ``w`` × ``h`` inches outside pyplot (nothing to close; no backend or figure manager)."""
    return Figure(figsize=(w, h), dpi=100)


def _margins(fig: Figure, left: float = 0.7, right: float = 0.2, bottom: float = 0.45, top: float = 0.3,
             wspace: float = 0.25) -> None:
    """Fixed margins in inches (an automatic layout measures every label twice: slow, and not needed here)."""
    w, h = fig.get_size_inches()
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h, wspace=wspace)


def _bars(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertical bars from ``lo`` to ``hi`` at ``x`` as one polyline broken by NaNs (one SVG path for all)."""
    nan = np.full(x.shape, np.nan)
    return np.column_stack([x, x, nan]).reshape(-1), np.column_stack([lo, hi, nan]).reshape(-1)


def _percentiles(values: np.ndarray, q: Sequence[float]) -> np.ndarray:
    """``np.nanpercentile(values, q, axis=0)``; without NaNs the vectorised ``np.percentile`` (same numbers,
    without nanpercentile's column-by-column loop)."""
    if np.isnan(values).any():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # an all-NaN column: NaN, nothing drawn
            return np.nanpercentile(values, q, axis=0)
    return np.percentile(values, q, axis=0)


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


def gap_timeline(labels: Sequence[str], n_frames: int, rate_hz: float, gaps: Sequence[GapQC],
                 crop: Sequence[int] | None, raw_valid: np.ndarray | None, salt: str) -> str:
    """Markers × time, each sample coloured by how it was filled; outside the crop shaded.

    ``gaps``: the clean stage's gap records (marker, start, stop, method); without them (no clean QC) the raw
    gaps are drawn as unfilled.
    """
    code = np.full((len(labels), n_frames), FILL_CODES["measured"], dtype=np.int8)
    row = {lab: i for i, lab in enumerate(labels)}
    if gaps:
        for g in gaps:
            if g.marker in row:
                code[row[g.marker], int(g.start):int(g.stop)] = FILL_CODES[g.method]
    elif raw_valid is not None:
        code[~raw_valid.T] = FILL_CODES["unfilled"]
    names = sorted(FILL_CODES, key=FILL_CODES.__getitem__)
    cmap = ListedColormap([FILL_COLOURS[n] for n in names])
    t_end = n_frames / rate_hz
    with _style(salt):
        fig = _fig(9.0, 1.2 + 0.11 * len(labels))
        ax = fig.add_subplot(111)
        ax.imshow(code, aspect="auto", interpolation="nearest", cmap=cmap, vmin=-0.5, vmax=len(names) - 0.5,
                  extent=(0.0, t_end, len(labels) - 0.5, -0.5))
        # one text per marker name, left of its row (a tick per name is several artists each: a third of the time)
        ax.set_yticks([])
        names_at = ax.get_yaxis_transform()
        for i, lab in enumerate(labels):
            ax.text(-0.004, i, lab, transform=names_at, ha="right", va="center", fontsize=6)
        if crop is not None:
            a, b = crop[0] / rate_hz, crop[1] / rate_hz
            ax.axvspan(0.0, a, color="black", alpha=0.15, lw=0)
            ax.axvspan(b, t_end, color="black", alpha=0.15, lw=0)
            ax.axvline(a, color="black", lw=0.8)
            ax.axvline(b, color="black", lw=0.8)
        ax.set_xlabel("time (s)")
        handles: list[Any] = [Patch(color=FILL_COLOURS[n], label=n) for n in names]
        if crop is not None:
            handles += [Patch(color="black", alpha=0.15, lw=0, label="cropped out (before/after the rests)"),
                        Line2D([], [], color="black", lw=0.8, label="crop bounds")]
        ax.legend(handles=handles, ncol=len(handles), loc="lower left", bbox_to_anchor=(0.0, 1.0), frameon=False,
                  borderaxespad=0.2, columnspacing=1.0, handlelength=1.5)
        _margins(fig, left=0.8, top=0.35)
        return _svg(fig)


def speed_plot(speed: np.ndarray, rate_hz: float, crop: Sequence[int] | None, rests: Sequence[Sequence[int]],
               threshold: float | None, salt: str) -> str:
    """Mean subject-marker speed (log scale) with the rest threshold, the rests and the crop bounds."""
    t = np.arange(speed.size) / rate_hz
    with _style(salt):
        fig = _fig(9.0, 2.4)
        ax = fig.add_subplot(111)
        for a, b in rests:
            ax.axvspan(a / rate_hz, b / rate_hz, color="#2ca02c", alpha=0.15, lw=0)
        pos = np.where(speed > 0, speed, np.nan)
        ax.plot(*envelope(t, pos), color="#333333", lw=0.8, label="mean marker speed")
        if threshold is not None:
            ax.axhline(threshold, color="#2ca02c", lw=0.8, ls="--", label=f"rest threshold {threshold:g} mm/s")
        if crop is not None:
            for i, f in enumerate(crop):
                ax.axvline(f / rate_hz, color="#d62728", lw=1.0, label="crop bounds" if i == 0 else None)
        if np.isfinite(pos).any():
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))  # plain numbers: mathtext is slow
            ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_xlim(0, max(t[-1] if t.size else 1.0, 1e-3))
        ax.set_xlabel("time (s)")
        ax.set_ylabel("mm/s")
        ax.set_title("speed, rests (green) and crop", loc="left")
        ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False, ncol=3, borderaxespad=0.2)
        _margins(fig, top=0.4)
        return _svg(fig)


def clap_plot(distance: np.ndarray, rate_hz: float, mocap_s: Sequence[float], video_on_mocap_s: Sequence[float | None],
              salt: str, half_window_s: float = 1.0) -> str:
    """Clapper distance around each clap, with the mocap clap and the video clap mapped onto the mocap clock."""
    n = max(len(mocap_s), 1)
    t = np.arange(distance.size) / rate_hz
    with _style(salt):
        fig = _fig(min(3.0 * n, 9.0) + 0.6, 2.4)
        for i, (tm, tv) in enumerate(zip(mocap_s, video_on_mocap_s, strict=True)):
            ax = fig.add_subplot(1, n, i + 1)
            sel = (t >= tm - half_window_s) & (t <= tm + half_window_s)
            ax.plot(t[sel] - tm, distance[sel], color="#333333", lw=0.9, marker=".", ms=2)
            ax.axvline(0.0, color="#1f77b4", lw=1.0)
            if tv is not None:
                ax.axvline(tv - tm, color="#ff7f0e", lw=1.0, ls="--")
            ax.set_title(f"clap {i + 1} at {tm:.2f} s" + ("" if tv is None else f", video {1000 * (tv - tm):+.1f} ms"))
            ax.set_xlabel("time from mocap clap (s)")
            if i == 0:
                ax.set_ylabel("clapper distance (mm)")
        # one legend for every panel, above them (inside an axes it covers the trace)
        fig.legend(handles=[Line2D([], [], color="#1f77b4", lw=1.0, label="mocap clap"),
                            Line2D([], [], color="#ff7f0e", lw=1.0, ls="--", label="video clap on the mocap clock")],
                   loc="upper right", ncol=2, frameon=False, borderaxespad=0.2)
        _margins(fig, top=0.5)
        return _svg(fig)


def eye_plot(time_s: np.ndarray, confidence: np.ndarray, valid: np.ndarray, filled: np.ndarray,
             gate: float | None, salt: str) -> str:
    """Eye-tracking confidence on the mocap frames, the gate, invalid frames shaded, filled frames marked."""
    with _style(salt):
        fig = _fig(9.0, 2.2)
        ax = fig.add_subplot(111)
        # invalid (red) and slerp-filled (blue) frames as one background strip: a raster, whatever the length
        strip = np.where(np.asarray(filled, bool), 2, np.where(np.asarray(valid, bool), 0, 1))[None, :]
        if time_s.size:
            dt = float(np.median(np.diff(time_s))) if time_s.size > 1 else 1.0
            ax.imshow(strip, aspect="auto", interpolation="nearest", origin="lower",
                      cmap=ListedColormap(["#ffffff", "#f4c2c2", "#c6dbef"]), vmin=-0.5, vmax=2.5,
                      extent=(float(time_s[0]), float(time_s[-1]) + dt, -0.02, 1.02))
        ax.plot(*envelope(time_s, np.asarray(confidence, np.float64)), color="#333333", lw=0.7,
                label="confidence")
        ax.plot([], [], ls="none", marker="s", color="#f4c2c2", label="invalid")
        ax.plot([], [], ls="none", marker="s", color="#c6dbef", label="slerp-filled")
        if gate is not None:
            ax.axhline(gate, color="#ff7f0e", lw=0.9, ls="--", label=f"gate {gate:g}")
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("time (s)")
        ax.set_title("eye confidence", loc="left")
        ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False, ncol=4, borderaxespad=0.2)
        _margins(fig, top=0.4)
        return _svg(fig)


def element_groups(names: Sequence[str]) -> list[tuple[str, int, int]]:
    """Runs of consecutive element names sharing the part before their first dot (``pelvis.fwd.x`` →
    ``pelvis``): ``(group, first, stop)`` each."""
    out: list[tuple[str, int, int]] = []
    for i, n in enumerate(names):
        g = str(n).split(".", 1)[0]
        if out and out[-1][0] == g:
            out[-1] = (g, out[-1][1], i + 1)
        else:
            out.append((g, i, i + 1))
    return out


#: length of a tick mark and the gap from it to its label, inches (matplotlib's defaults, 3.5 pt each)
_TICK_IN = 3.5 / 72


def _element_ticks(ax: Any, x: np.ndarray, names: Sequence[str], size: float, axes_in: float) -> None:
    """A tick mark and a name (rotated, below the axes) at each ``x``: one path for all the marks and a plain
    text per name, not one tick object each (building a tick costs more than drawing it; a vector feature has
    dozens). ``axes_in`` is the axes' height in inches."""
    ax.set_xticks([])
    below = ax.get_xaxis_transform()
    mark = np.column_stack([x, x, np.full(x.shape, np.nan)]).reshape(-1)
    drop = np.tile([0.0, -_TICK_IN / axes_in, np.nan], x.size)
    ax.plot(mark, drop, color="black", lw=0.8, transform=below, clip_on=False, solid_capstyle="butt")
    for xi, name in zip(x.tolist(), names, strict=True):
        ax.text(xi, -2 * _TICK_IN / axes_in, name, transform=below, rotation=90, ha="center", va="top",
                fontsize=size)


def feature_plot(values: np.ndarray, poses: np.ndarray, names: Sequence[str], title: str, salt: str,
                 unit: str = "") -> str:
    """Per feature element, the median and the 5–95 % band of each pose's sampled training rows.

    Every element is labelled with its name (``names``, the dataset's element names); elements of one group (a
    segment, the target direction: the part of the name before its first dot) are drawn together under the
    group's name, with the rest of the name on each tick. ``unit`` labels the value axis.
    """
    pose_list = sorted(set(poses.tolist()))
    d = values.shape[1]
    x = np.arange(d)
    labels = [str(n) for n in names] if len(names) == d else [str(i) for i in range(d)]
    groups = element_groups(labels)
    grouped = 1 < len(groups) < d or (len(groups) == 1 and "." in labels[0])
    ticks = [lab.split(".", 1)[1] if grouped and "." in lab else lab for lab in labels]
    longest = max((len(t) for t in ticks), default=1)
    tick_size = 6 if d <= 24 else 5
    label_in = 0.0085 * tick_size * longest + 0.06      # inches the rotated tick names reach below the axes
    bottom = 0.3 + label_in + (0.2 if grouped else 0.0)
    axes_in = 2.0
    with _style(salt):
        fig = _fig(9.0, axes_in + 0.4 + bottom)
        ax = fig.add_subplot(111)
        for i, p in enumerate(pose_list):
            v = values[poses == p]
            lo, med, hi = _percentiles(v, [5, 50, 95])
            off = (i - (len(pose_list) - 1) / 2) * 0.8 / max(len(pose_list), 1)
            colour = _TAB10[i % 10]
            ax.plot(*_bars(x + off, lo, hi), color=colour, lw=2.0, alpha=0.5, solid_capstyle="butt")
            ax.plot(x + off, med, ls="none", marker="_", ms=6, color=colour, label=f"{p} ({v.shape[0]} rows)")
        ax.set_xlim(-0.6, d - 0.4)
        below = ax.get_xaxis_transform()
        _element_ticks(ax, x, ticks, tick_size, axes_in)
        if grouped:
            for g, a, b in groups:
                if a:
                    ax.axvline(a - 0.5, color="#bbbbbb", lw=0.5)
                ax.text((a + b - 1) / 2, -(label_in + 0.04) / axes_in, g, transform=below, ha="center", va="top",
                        fontsize=6, fontweight="bold")
        # the unit on the value axis (its first clause when long; the whole of it in the title)
        ax.set_ylabel((unit if len(unit) <= 30 else unit.split(",")[0]) if unit else "value (no unit recorded)")
        ax.set_title(f"{title} ({unit})" if unit else title, loc="left")
        ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False, ncol=min(len(pose_list), 4),
                  borderaxespad=0.2)
        _margins(fig, bottom=bottom, top=0.4)
        return _svg(fig)


def scalar_features_plot(columns: dict[str, np.ndarray], poses: np.ndarray, salt: str,
                         units: dict[str, str] | None = None) -> str:
    """One small panel per scalar feature: per pose, the median and the 5–95 % band of the sampled rows; each
    panel titled with the feature's name and its unit (``units``)."""
    pose_list = sorted(set(poses.tolist()))
    names = list(columns)
    per_row = 6
    n_rows = (len(names) + per_row - 1) // per_row
    with _style(salt):
        fig = _fig(9.0, 1.9 * n_rows + 0.4)
        for k, name in enumerate(names):
            ax = fig.add_subplot(n_rows, per_row, k + 1)
            for i, p in enumerate(pose_list):
                v = columns[name][poses == p]
                if v.size == 0:
                    continue
                lo, med, hi = _percentiles(v, [5, 50, 95])
                ax.plot([i, i], [lo, hi], color=_TAB10[i % 10], lw=3.0, alpha=0.5, solid_capstyle="butt")
                ax.plot([i], [med], ls="none", marker="_", ms=10, color=_TAB10[i % 10])
            ax.set_xticks(range(len(pose_list)), pose_list, rotation=30, ha="right", fontsize=6)
            ax.set_xlim(-0.7, len(pose_list) - 0.3)
            ax.set_title(name, fontsize=8)
            ax.set_ylabel((units or {}).get(name) or "value (no unit recorded)", fontsize=6)
        _margins(fig, left=0.6, bottom=0.5, top=0.3, wspace=0.8)
        fig.subplots_adjust(hspace=0.7)
        return _svg(fig)
