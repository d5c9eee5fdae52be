"""A few plot elements written straight as SVG text: the report's axes, lines, spans, rasters, ticks and legends,
laid out as the matplotlib figures that drew the plots before laid them out (same sizes, fonts, colours, tick
positions and labels: matplotlib's own locators and formatters), without matplotlib's figure machinery, which
made drawing a take's four plots cost half a CPU second (each tick and text several artists, each measured twice).

Lengths are points (72 a inch), y downwards, as in matplotlib's SVGs. Text is kept as text (the browser sets it
in DejaVu Sans or its fallback); legends are laid out from DejaVu Sans's advance widths."""

from __future__ import annotations

import base64
import hashlib
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from html import escape
from typing import Any

import numpy as np

#: advance widths of DejaVu Sans, thousandths of an em, of the characters ' ' (32) to '~' (126)
_WIDTHS = (
    318, 401, 460, 838, 636, 950, 780, 275, 390, 390, 500, 838, 318, 361, 318, 337, 636, 636, 636, 636, 636, 636,
    636, 636, 636, 636, 337, 337, 838, 838, 838, 531, 1000, 684, 686, 698, 770, 632, 575, 775, 752, 295, 295, 656,
    557, 863, 748, 787, 603, 787, 695, 635, 611, 732, 684, 989, 685, 611, 685, 390, 337, 390, 838, 500, 500, 613,
    635, 550, 635, 615, 352, 635, 634, 278, 278, 579, 278, 974, 634, 612, 635, 635, 411, 521, 392, 634, 592, 818,
    592, 592, 525, 636, 337, 636, 838)
_OTHER_WIDTHS = {"−": 838, "–": 500, "±": 838, "°": 500, "×": 838, "µ": 636, "·": 318}
#: tick marks and label gaps (matplotlib's defaults, points) and the text sizes of the plots
TICK, PAD, MINOR_TICK = 3.5, 3.5, 2.0
TICK_SIZE, LABEL_SIZE, TITLE_SIZE, LEGEND_SIZE = 8.0, 8.0, 9.0, 7.0
#: matplotlib's dash pattern of ``--`` per point of line width
_DASH = (3.7, 1.6)
_FONT = "font-family: 'DejaVu Sans'"


def text_width(s: str, size: float) -> float:
    """Width in points of ``s`` set in DejaVu Sans at ``size`` points (no kerning)."""
    return size * sum(_WIDTHS[o - 32] if 32 <= (o := ord(c)) < 127 else _OTHER_WIDTHS.get(c, 600) for c in s) / 1000


def num(v: float) -> str:
    """A coordinate as SVG text: at most 3 decimals, no trailing zeros."""
    s = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if s in ("", "-0") else s


def _nums(a: np.ndarray) -> np.ndarray:
    """:func:`num` of every element (2 decimals: a hundredth of a point), as strings."""
    r = np.round(np.asarray(a, np.float64), 2) + 0.0        # + 0.0: no -0
    return np.char.mod("%.6g", r)


def polyline(px: np.ndarray, py: np.ndarray) -> str:
    """SVG path data through the points (``px``, ``py``), broken where either is not finite."""
    ok = np.isfinite(px) & np.isfinite(py)
    if not ok.any():
        return ""
    start = ok & ~np.concatenate([[False], ok[:-1]])
    cmd = np.where(start[ok], "M", "L")
    return " ".join(np.char.add(np.char.add(np.char.add(cmd, _nums(px[ok])), " "), _nums(py[ok])))


def dots(px: np.ndarray, py: np.ndarray) -> str:
    """SVG path data of a zero-length segment at each finite point (drawn as a dot by a round line cap)."""
    ok = np.isfinite(px) & np.isfinite(py)
    return " ".join(np.char.add(np.char.add(np.char.add("M", _nums(px[ok])), " "), np.char.add(_nums(py[ok]), "h0")))


def dash_style(lw: float, dashed: bool) -> str:
    return f"; stroke-dasharray: {num(_DASH[0] * lw)},{num(_DASH[1] * lw)}" if dashed else ""


def png(codes: np.ndarray, colours: Sequence[str]) -> bytes:
    """An indexed-colour PNG of ``codes`` (rows × columns of indices into ``colours``, ``#rrggbb``)."""
    h, w = codes.shape
    rows = np.zeros((h, w + 1), np.uint8)
    rows[:, 1:] = codes
    plte = bytes.fromhex("".join(c.lstrip("#") for c in colours))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 3, 0, 0, 0))
            + chunk(b"PLTE", plte) + chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)) + chunk(b"IEND", b""))


def nearest(codes: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``codes`` resampled to ``shape`` (rows, columns), each pixel the cell under its centre."""
    h, w = codes.shape
    ri = np.minimum(((np.arange(shape[0]) + 0.5) * h / shape[0]).astype(np.int64), h - 1)
    ci = np.minimum(((np.arange(shape[1]) + 0.5) * w / shape[1]).astype(np.int64), w - 1)
    return codes[np.ix_(ri, ci)]


def text(x: float, y: float, s: str, size: float, anchor: str = "start", rotate: float = 0.0,
         bold: bool = False) -> str:
    """A text whose baseline starts (``anchor``: or is centred, or ends) at (``x``, ``y``)."""
    turn = f' transform="rotate({num(rotate)} {num(x)} {num(y)})"' if rotate else ""
    weight = "; font-weight: bold" if bold else ""
    return (f'<text style="font-size: {num(size)}px; {_FONT}; text-anchor: {anchor}{weight}" x="{num(x)}" '
            f'y="{num(y)}"{turn}>{escape(s, quote=False)}</text>')


# --------------------------------------------------------------------------------------------- scales

def tick_space(length_pt: float, along_x: bool) -> int:
    """matplotlib's number of ticks an axis has room for (``Axis.get_tick_space``; its automatic locators use
    at most 9)."""
    # (a millionth of slack: an axes 2 inches tall measures 143.99999999999997 points after its margins)
    return max(int(np.floor(length_pt / (TICK_SIZE * (3 if along_x else 2)) + 1e-6)), 1)


def linear_ticks(lo: float, hi: float, length_pt: float, along_x: bool) -> tuple[list[float], list[str], str]:
    """matplotlib's automatic ticks of a linear axis from ``lo`` to ``hi`` (``AutoLocator``,
    ``ScalarFormatter``): positions, labels and the offset text ('' without)."""
    from matplotlib import ticker

    loc = ticker.MaxNLocator(nbins=int(np.clip(tick_space(length_pt, along_x), 1, 9)), steps=[1, 2, 2.5, 5, 10])
    ticks = [float(t) for t in loc.tick_values(lo, hi) if _within(t, lo, hi)]
    fmt = ticker.ScalarFormatter()
    fmt.create_dummy_axis()
    axis: Any = fmt.axis
    axis.set_view_interval(lo, hi)
    axis.set_data_interval(lo, hi)
    labels = [str(s) for s in fmt.format_ticks(ticks)]
    return ticks, labels, str(fmt.get_offset())


def log_ticks(lo: float, hi: float, length_pt: float) -> tuple[list[float], list[str], list[float]]:
    """matplotlib's ticks of a log axis from ``lo`` to ``hi`` (``LogLocator``, majors labelled ``%g``): major
    positions, their labels, minor positions."""
    from matplotlib import ticker

    n = int(np.clip(tick_space(length_pt, False), 2, 9))
    major = [float(t) for t in ticker.LogLocator(numticks=n).tick_values(lo, hi) if _within(t, lo, hi)]
    minor = [float(t) for t in ticker.LogLocator(subs="auto", numticks=n).tick_values(lo, hi)
             if _within(t, lo, hi) and not any(np.isclose(t, m) for m in major)]
    return major, [f"{t:g}" for t in major], minor


def _within(t: float, lo: float, hi: float) -> bool:
    a, b = min(lo, hi), max(lo, hi)
    tol = 1e-10 * max(abs(b - a), 1e-300)
    return bool(a - tol <= t <= b + tol)


def nonsingular(a: float, b: float, expander: float = 0.05) -> tuple[float, float]:
    """matplotlib's limits of an axis from ``a`` to ``b``: widened by ``expander`` of their size when (nearly)
    equal, ``±expander`` around zero."""
    maxabs = max(abs(a), abs(b))
    if maxabs < 1e6 * np.finfo(float).tiny / 1e-15:
        return -expander, expander
    if b - a <= maxabs * 1e-15:
        return (-expander, expander) if a == 0 and b == 0 else (a - expander * abs(a), b + expander * abs(b))
    return a, b


def autoscale(values: Sequence[np.ndarray], margin: float = 0.05, log: bool = False) -> tuple[float, float]:
    """matplotlib's automatic limits of the data ``values`` (finite ones; positive ones on a log axis): their
    range widened by ``margin`` of it on each side (in log space on a log axis)."""
    flat = np.concatenate([np.asarray(v, np.float64).ravel() for v in values]) if values else np.zeros(0)
    flat = flat[np.isfinite(flat) & ((flat > 0) if log else True)]
    if not flat.size:
        return (1.0, 10.0) if log else (-0.055, 0.055)
    lo, hi = float(flat.min()), float(flat.max())
    if log:
        if lo == hi:    # a constant: the decades strictly below and above it (matplotlib's LogLocator.nonsingular)
            lo, hi = 10.0 ** (np.ceil(np.log10(lo)) - 1), 10.0 ** (np.floor(np.log10(hi)) + 1)
        a, b = float(np.log10(lo)), float(np.log10(hi))
        d = (b - a) * margin
        return 10 ** (a - d), 10 ** (b + d)
    a, b = nonsingular(lo, hi, expander=0.05)
    d = (b - a) * margin
    return a - d, b + d


# ----------------------------------------------------------------------------------------------- axes

@dataclass
class Axes:
    """A plot area ``left``, ``top``, ``width``, ``height`` (points) showing ``xlim`` × ``ylim``."""

    left: float
    top: float
    width: float
    height: float
    xlim: tuple[float, float] = (0.0, 1.0)
    ylim: tuple[float, float] = (0.0, 1.0)
    ylog: bool = False
    clip: str = ""
    parts: list[str] = field(default_factory=list)

    @property
    def bottom(self) -> float:
        return self.top + self.height

    def px(self, x: Any) -> Any:
        a, b = self.xlim
        return self.left + (np.asarray(x, np.float64) - a) * (self.width / (b - a))

    def py(self, y: Any) -> Any:
        a, b = self.ylim
        y = np.asarray(y, np.float64)
        if self.ylog:
            with np.errstate(divide="ignore", invalid="ignore"):
                y, a, b = np.log10(y), np.log10(a), np.log10(b)
        return self.bottom - (y - a) * (self.height / (b - a))

    def line(self, x: np.ndarray, y: np.ndarray, colour: str, lw: float, dashed: bool = False,
             alpha: float = 1.0, cap: str = "square") -> None:
        """A polyline in data coordinates, broken at NaNs (one path)."""
        d = polyline(self.px(x), self.py(y))
        if d:
            opacity = f"; stroke-opacity: {num(alpha)}" if alpha != 1.0 else ""
            self.parts.append(f'<path d="{d}" clip-path="url(#{self.clip})" style="fill: none; stroke: {colour}; '
                              f'stroke-width: {num(lw)}; stroke-linecap: {cap}{opacity}{dash_style(lw, dashed)}"/>')

    def dashes(self, x: np.ndarray, y: np.ndarray, colour: str, width: float, lw: float = 1.0) -> None:
        """A horizontal mark ``width`` points wide centred on each point (matplotlib's ``_`` marker; one path)."""
        px, py = self.px(x), self.py(y)
        ok = np.isfinite(px) & np.isfinite(py)
        if ok.any():
            d = " ".join(np.char.add(np.char.add(np.char.add("M", _nums(px[ok] - width / 2)), " "),
                                     np.char.add(_nums(py[ok]), f"h{num(width)}")))
            self.parts.append(f'<path d="{d}" style="fill: none; stroke: {colour}; stroke-width: {num(lw)}"/>')

    def dots(self, x: np.ndarray, y: np.ndarray, colour: str, size: float) -> None:
        """A dot of diameter ``size`` points at each point (one path)."""
        d = dots(self.px(x), self.py(y))
        if d:
            self.parts.append(f'<path d="{d}" clip-path="url(#{self.clip})" style="fill: none; stroke: {colour}; '
                              f'stroke-width: {num(size)}; stroke-linecap: round"/>')

    def vspan(self, a: float, b: float, colour: str, alpha: float) -> None:
        x0, x1 = float(self.px(a)), float(self.px(b))
        self.parts.append(f'<rect x="{num(x0)}" y="{num(self.top)}" width="{num(x1 - x0)}" height="{num(self.height)}" '
                          f'clip-path="url(#{self.clip})" style="fill: {colour}; opacity: {num(alpha)}"/>')

    def vline(self, x: float, colour: str, lw: float, dashed: bool = False) -> None:
        """A vertical line across the axes at ``x`` (data)."""
        px = num(float(self.px(x)))
        self.parts.append(f'<path d="M{px} {num(self.bottom)}V{num(self.top)}" clip-path="url(#{self.clip})" '
                          f'style="fill: none; stroke: {colour}; stroke-width: {num(lw)}; stroke-linecap: square'
                          f'{dash_style(lw, dashed)}"/>')

    def hline(self, y: float, colour: str, lw: float, dashed: bool = False) -> None:
        """A horizontal line across the axes at ``y`` (data)."""
        py = num(float(self.py(y)))
        self.parts.append(f'<path d="M{num(self.left)} {py}H{num(self.left + self.width)}" '
                          f'clip-path="url(#{self.clip})" style="fill: none; stroke: {colour}; '
                          f'stroke-width: {num(lw)}; stroke-linecap: square{dash_style(lw, dashed)}"/>')

    def image(self, codes: np.ndarray, colours: Sequence[str]) -> None:
        """``codes`` (rows top to bottom) filling the axes, one cell per pixel of a 100-dpi raster of the axes
        (nearest cell: what matplotlib's ``imshow(interpolation="nearest")`` embeds in an SVG)."""
        if not codes.size:
            return
        shape = (max(int(round(self.height / 72 * 100)), 1), max(int(round(self.width / 72 * 100)), 1))
        data = base64.b64encode(png(nearest(codes, shape), colours)).decode()
        self.parts.append(f'<image x="{num(self.left)}" y="{num(self.top)}" width="{num(self.width)}" '
                          f'height="{num(self.height)}" preserveAspectRatio="none" '
                          f'style="image-rendering: crisp-edges; image-rendering: pixelated" '
                          f'xlink:href="data:image/png;base64,{data}"/>')

    def spines(self) -> None:
        """The left and bottom edges."""
        self.parts.append(f'<path d="M{num(self.left)} {num(self.top)}V{num(self.bottom)}H{num(self.left + self.width)}"'
                          ' style="fill: none; stroke: #000000; stroke-width: 0.8; stroke-linejoin: miter; '
                          'stroke-linecap: square"/>')

    def xticks(self, ticks: Sequence[float], labels: Sequence[str]) -> None:
        """Tick marks below the axes at ``ticks`` (data) with their labels."""
        xs = [float(v) for v in self.px(np.asarray(ticks, np.float64))] if len(ticks) else []
        d = "".join(f"M{num(x)} {num(self.bottom)}v{num(TICK)}" for x in xs)
        if d:
            self.parts.append(f'<path d="{d}" style="stroke: #000000; stroke-width: 0.8"/>')
        y = self.bottom + TICK + PAD + 0.76 * TICK_SIZE
        self.parts.extend(text(x, y, s, TICK_SIZE, "middle") for x, s in zip(xs, labels, strict=True))

    def names_below(self, x: Sequence[float], names: Sequence[str], size: float, rotate: float) -> None:
        """Tick marks below the axes at ``x`` (data) with ``names`` rotated by ``rotate`` degrees (90 or less),
        their right ends at the tick (matplotlib's ``ha="center"`` when upright, ``ha="right"`` otherwise)."""
        xs = [float(v) for v in self.px(np.asarray(x, np.float64))] if len(x) else []
        d = "".join(f"M{num(v)} {num(self.bottom)}v{num(TICK)}" for v in xs)
        if d:
            self.parts.append(f'<path d="{d}" style="stroke: #000000; stroke-width: 0.8"/>')
        top = self.bottom + TICK + PAD
        r = np.radians(rotate)
        a, dsc = 0.76 * size, 0.24 * size
        if rotate >= 90:    # upright: centred on the tick
            dx, dy = (a - dsc) / 2, 0.0
        else:               # slanted: the bounding box's top right corner at the tick
            dx, dy = -dsc * np.sin(r), a * np.cos(r)
        self.parts.extend(text(v + dx, top + dy, s, size, "end", rotate=-rotate) for v, s in zip(xs, names, strict=True))

    def yticks(self, ticks: Sequence[float], labels: Sequence[str], minor: Sequence[float] = ()) -> float:
        """Tick marks left of the axes at ``ticks`` (data) with their labels, and unlabelled ``minor`` ones;
        the width of the widest label."""
        ys = [float(v) for v in self.py(np.asarray(ticks, np.float64))] if len(ticks) else []
        ms = [float(v) for v in self.py(np.asarray(minor, np.float64))] if len(minor) else []
        d = "".join(f"M{num(self.left)} {num(y)}h{num(-TICK)}" for y in ys)
        if d:
            self.parts.append(f'<path d="{d}" style="stroke: #000000; stroke-width: 0.8"/>')
        d = "".join(f"M{num(self.left)} {num(y)}h{num(-MINOR_TICK)}" for y in ms)
        if d:
            self.parts.append(f'<path d="{d}" style="stroke: #000000; stroke-width: 0.6"/>')
        x = self.left - TICK - PAD
        self.parts.extend(text(x, y + 0.38 * TICK_SIZE, s, TICK_SIZE, "end") for y, s in zip(ys, labels, strict=True))
        return max((text_width(s, TICK_SIZE) for s in labels), default=0.0)

    def auto_xticks(self) -> None:
        ticks, labels, offset = linear_ticks(*self.xlim, self.width, True)
        self.xticks(ticks, labels)
        if offset:
            self.parts.append(text(self.left + self.width, self.bottom + TICK + PAD + 1.76 * TICK_SIZE, offset,
                                   TICK_SIZE, "end"))

    def auto_yticks(self) -> float:
        ticks, labels, offset = linear_ticks(*self.ylim, self.height, False)
        if offset:
            self.parts.append(text(self.left, self.top - 0.24 * TICK_SIZE, offset, TICK_SIZE))
        return self.yticks(ticks, labels)

    def xlabel(self, s: str, ticks_labelled: bool = True) -> None:
        below = TICK + PAD + 0.76 * TICK_SIZE + 1.5 * LABEL_SIZE if ticks_labelled else TICK + 4 + 0.76 * LABEL_SIZE
        self.parts.append(text(self.left + self.width / 2, self.bottom + below, s, LABEL_SIZE, "middle"))

    def ylabel(self, s: str, labels_width: float, size: float = LABEL_SIZE) -> None:
        x = self.left - TICK - PAD - labels_width - 4 - 0.24 * size
        y = self.top + self.height / 2
        self.parts.append(text(x, y, s, size, "middle", rotate=-90))

    def title(self, s: str, centred: bool = False, size: float = TITLE_SIZE) -> None:
        x = self.left + self.width / 2 if centred else self.left
        self.parts.append(text(x, self.top - 6, s, size, "middle" if centred else "start"))


# --------------------------------------------------------------------------------------------- legend

@dataclass(frozen=True)
class Key:
    """A legend entry: ``kind`` ``line`` (``dashed`` or not), ``patch`` (a filled box), ``square`` or
    ``dash`` (a marker), its colour, line width, opacity and label."""

    kind: str
    colour: str
    label: str
    lw: float = 1.0
    dashed: bool = False
    alpha: float = 1.0


def legend(keys: Sequence[Key], x: float, y: float, right: bool, below: bool, handle: float = 2.0,
           spacing: float = 2.0, ncol: int | None = None) -> list[str]:
    """Legend entries with no frame in ``ncol`` columns (all in one row by default), laid out as matplotlib lays
    out ``legend(ncol=...)``: anchored at (``x``, ``y``) by its lower (``below``: upper) right (``right``) or
    left corner, 0.2 font sizes away, 0.4 more inside; handles ``handle`` font sizes long, columns ``spacing``
    apart, filled column by column."""
    fs = LEGEND_SIZE
    hl, pad, sep = handle * fs, 0.8 * fs, spacing * fs
    cols = [c for c in np.array_split(np.arange(len(keys)), ncol or max(len(keys), 1)) if c.size]
    widths = [max(hl + pad + text_width(keys[i].label, fs) for i in c) for c in cols]
    total = sum(widths) + sep * (len(cols) - 1)
    rows, pitch = max((c.size for c in cols), default=1), 1.47 * fs
    inset = 0.6 * fs
    x0 = x - inset - total if right else x + inset
    base = y + inset + 0.76 * fs if below else y - inset - 0.24 * fs - (rows - 1) * pitch
    out: list[str] = []
    for c, w in zip(cols, widths, strict=True):
        for r, i in enumerate(c.tolist()):
            b = base + r * pitch
            out.append(_handle(keys[i], x0, b - 0.35 * fs, hl, fs))
            out.append(text(x0 + hl + pad, b, keys[i].label, fs))
        x0 += w + sep
    return out


def _handle(k: Key, x: float, mid: float, hl: float, fs: float) -> str:
    if k.kind == "patch":
        h = 0.7 * fs
        opacity = f"; opacity: {num(k.alpha)}" if k.alpha != 1.0 else ""
        return (f'<rect x="{num(x)}" y="{num(mid - h / 2)}" width="{num(hl)}" height="{num(h)}" '
                f'style="fill: {k.colour}{opacity}"/>')
    if k.kind == "dash":     # a ``_`` marker
        return (f'<path d="M{num(x + hl / 2 - 3)} {num(mid)}h6" style="fill: none; stroke: {k.colour}; '
                f'stroke-width: {num(k.lw)}"/>')
    if k.kind == "square":
        s = 6.0
        return (f'<rect x="{num(x + hl / 2 - s / 2)}" y="{num(mid - s / 2)}" width="{num(s)}" height="{num(s)}" '
                f'style="fill: {k.colour}; stroke: {k.colour}"/>')
    return (f'<path d="M{num(x)} {num(mid)}h{num(hl)}" style="fill: none; stroke: {k.colour}; '
            f'stroke-width: {num(k.lw)}; stroke-linecap: square{dash_style(k.lw, k.dashed)}"/>')


# --------------------------------------------------------------------------------------------- figure

class Canvas:
    """An SVG of ``width`` × ``height`` inches; ``salt`` makes its clip ids unique in a page."""

    def __init__(self, width: float, height: float, salt: str) -> None:
        self.w, self.h = width * 72, height * 72
        self.salt = hashlib.sha256(salt.encode()).hexdigest()[:10]
        self.axes: list[Axes] = []
        self.parts: list[str] = []

    def grid(self, rows: int, cols: int, left: float, right: float, bottom: float, top: float, wspace: float,
             hspace: float) -> list[Axes]:
        """``rows`` × ``cols`` axes, row by row, within margins (inches), ``wspace`` and ``hspace`` of an axes'
        width and height apart (matplotlib's subplot grid)."""
        x0, x1, y0, y1 = left * 72, self.w - right * 72, top * 72, self.h - bottom * 72
        cw = (x1 - x0) / (cols + wspace * (cols - 1))
        ch = (y1 - y0) / (rows + hspace * (rows - 1))
        return [self.add_axes(x0 + j * cw * (1 + wspace), x0 + j * cw * (1 + wspace) + cw,
                              y0 + i * ch * (1 + hspace) + ch, y0 + i * ch * (1 + hspace))
                for i in range(rows) for j in range(cols)]

    def add_axes(self, left: float, right: float, bottom: float, top: float, **kw: Any) -> Axes:
        """An axes ``left`` … ``right`` (points from the left) × ``top`` … ``bottom`` (points from the top)."""
        ax = Axes(left, top, right - left, bottom - top, clip=f"c{self.salt}_{len(self.axes)}", **kw)
        self.axes.append(ax)
        return ax

    def render(self) -> str:
        clips = "".join(f'<clipPath id="{a.clip}"><rect x="{num(a.left)}" y="{num(a.top)}" width="{num(a.width)}" '
                        f'height="{num(a.height)}"/></clipPath>' for a in self.axes)
        body = "\n".join(p for a in self.axes for p in a.parts) + "\n" + "\n".join(self.parts)
        return (f'<svg width="{num(self.w)}pt" height="{num(self.h)}pt" viewBox="0 0 {num(self.w)} {num(self.h)}" '
                f'version="1.1">\n<defs>\n<style type="text/css">*{{stroke-linejoin: round; stroke-linecap: butt}}'
                f'</style>\n{clips}\n</defs>\n<rect x="0" y="0" width="{num(self.w)}" height="{num(self.h)}" '
                f'style="fill: #ffffff"/>\n{body.strip()}\n</svg>')
