"""The datasets' pictures (feature distributions per pose), as inline SVG strings (matplotlib's object interface and SVG backend, no pyplot;
byte-stable: fixed hash salt, no dates).

Each function returns an SVG element ready to paste into HTML: no XML prologue, no DOCTYPE, no namespace URLs
(the HTML parser puts ``<svg>`` in the SVG namespace by itself), text kept as text.

Drawing time is mostly matplotlib's fixed cost per axes, tick and text, so the plots keep those few: no pyplot
figure manager, fixed margins (no automatic layout), one rcParams context per figure, marker names drawn as plain
text instead of one tick object each, and range bars drawn as one path per pose instead of a collection. A take's
plots, simpler and drawn for several takes at the end of every run, are written as SVG directly
(:mod:`gazepipe.report.take_plots`).
"""

from __future__ import annotations

import io
import re
import warnings
from collections.abc import Sequence
from typing import Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure

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
