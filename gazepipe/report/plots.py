"""The datasets' pictures (feature distributions per pose), as inline SVG strings written directly
(:mod:`gazepipe.report.svg`; laid out as the matplotlib figures that drew them before: same sizes, margins, fonts,
colours, ticks and labels). Each function returns an SVG element ready to paste into HTML: no XML prologue, no
DOCTYPE, no namespace URLs (the HTML parser puts ``<svg>`` in the SVG namespace by itself), text kept as text.
A pose's range bars are one path, its medians another. A take's plots are in :mod:`gazepipe.report.take_plots`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from gazepipe.report import svg as S

#: the tab10 colours, one per pose
_TAB10 = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
          "#17becf")


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
    c = S.Canvas(9.0, 2.0 + 0.4 + bottom, salt)
    ax = c.add_axes(0.7 * 72, c.w - 0.2 * 72, c.h - bottom * 72, 0.4 * 72, xlim=(-0.6, d - 0.4))
    series = []
    for i, p in enumerate(pose_list):
        v = values[poses == p]
        lo, med, hi = _percentiles(v, [5, 50, 95])
        off = (i - (len(pose_list) - 1) / 2) * 0.8 / max(len(pose_list), 1)
        series.append((x + off, lo, med, hi, _TAB10[i % 10], f"{p} ({v.shape[0]} rows)"))
    ax.ylim = S.autoscale([a for s in series for a in (s[1], s[2], s[3])])
    if grouped:
        for _g, a, _b in groups:
            if a:
                ax.vline(a - 0.5, "#bbbbbb", 0.5)
    for xs, lo, med, hi, colour, _ in series:
        ax.line(*_bars(xs, lo, hi), colour, 2.0, alpha=0.5, cap="butt")
        ax.dashes(xs, med, colour, 6.0)
    ax.spines()
    ax.names_below(x.tolist(), ticks, tick_size, 90)
    if grouped:
        y = ax.bottom + (label_in + 0.04) * 72 + 0.76 * 6
        ax.parts.extend(S.text(float(ax.px((a + b - 1) / 2)), y, g, 6, "middle", bold=True) for g, a, b in groups)
    width = ax.auto_yticks()
    # the unit on the value axis (its first clause when long; the whole of it in the title)
    ax.ylabel((unit if len(unit) <= 30 else unit.split(",")[0]) if unit else "value (no unit recorded)", width)
    ax.title(f"{title} ({unit})" if unit else title)
    c.parts.extend(S.legend([S.Key("dash", s[4], s[5]) for s in series], ax.left + ax.width, ax.top, right=True,
                            below=False, ncol=min(len(pose_list), 4)))
    return c.render()


def scalar_features_plot(columns: dict[str, np.ndarray], poses: np.ndarray, salt: str,
                         units: dict[str, str] | None = None) -> str:
    """One small panel per scalar feature: per pose, the median and the 5–95 % band of the sampled rows; each
    panel titled with the feature's name and its unit (``units``)."""
    pose_list = sorted(set(poses.tolist()))
    names = list(columns)
    per_row = 6
    n_rows = (len(names) + per_row - 1) // per_row
    c = S.Canvas(9.0, 1.9 * n_rows + 0.4, salt)
    grid = c.grid(n_rows, per_row, 0.6, 0.2, 0.5, 0.3, wspace=0.8, hspace=0.7)
    for name, ax in zip(names, grid, strict=False):
        stats = []
        for i, p in enumerate(pose_list):
            v = columns[name][poses == p]
            if v.size:
                stats.append((i, *_percentiles(v, [5, 50, 95])))
        ax.xlim = (-0.7, len(pose_list) - 0.3)
        ax.ylim = S.autoscale([np.array([s[1:] for s in stats], np.float64).ravel()])
        for i, lo, med, hi in stats:
            ax.line(np.array([i, i], np.float64), np.array([lo, hi]), _TAB10[i % 10], 3.0, alpha=0.5, cap="butt")
            ax.dashes(np.array([i], np.float64), np.array([med]), _TAB10[i % 10], 10.0)
        ax.spines()
        ax.names_below(list(range(len(pose_list))), [str(p) for p in pose_list], 6, 30)
        width = ax.auto_yticks()
        ax.title(name, centred=True, size=8)
        ax.ylabel((units or {}).get(name) or "value (no unit recorded)", width, size=6)
    return c.render()
