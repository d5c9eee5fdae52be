"""The report's plots written as SVG directly (:mod:`gazepipe.report.take_plots`, :mod:`gazepipe.report.plots`):
each draws every series with its data where it belongs (read back from the SVG: the raster's pixels, the paths'
points), and its axes have the ticks and labels matplotlib gave them."""

from __future__ import annotations

import base64
import re
import struct
import zlib

import numpy as np
import pytest

from gazepipe.model import FILL_CODES
from gazepipe.report import svg as S
from gazepipe.report import take_plots as P
from gazepipe.stages.clean.qc import GapQC


def _image(svg: str) -> tuple[np.ndarray, list[str], tuple[float, float, float, float]]:
    """The first raster of ``svg``: its palette indices (rows × columns), its palette and its place."""
    m = re.search(r'<image x="([\d.]+)" y="([\d.]+)" width="([\d.]+)" height="([\d.]+)"[^>]*base64,([^"]+)"', svg)
    assert m is not None
    data = base64.b64decode(m.group(5))
    w, h = struct.unpack(">II", data[16:24])
    chunks, i = {}, 8
    while i < len(data):
        n = struct.unpack(">I", data[i:i + 4])[0]
        chunks.setdefault(data[i + 4:i + 8], b"")
        chunks[data[i + 4:i + 8]] += data[i + 8:i + 8 + n]
        i += 12 + n
    rows = np.frombuffer(zlib.decompress(chunks[b"IDAT"]), np.uint8).reshape(h, w + 1)
    assert not rows[:, 0].any()                      # no filter
    plte = chunks[b"PLTE"]
    palette = ["#" + plte[k:k + 3].hex() for k in range(0, len(plte), 3)]
    return rows[:, 1:], palette, tuple(float(m.group(k)) for k in range(1, 5))  # type: ignore[return-value]


def _paths(svg: str, stroke: str) -> list[np.ndarray]:
    """The points (x, y) of every path stroked with ``stroke``."""
    out = []
    for d in re.findall(rf'<path d="([^"]+)"[^>]*stroke: {stroke};', svg):
        nums = re.findall(r"[ML](-?[\d.e+-]+) (-?[\d.e+-]+)", d)
        out.append(np.array(nums, np.float64).reshape(-1, 2))
    return out


def _vlines(svg: str, stroke: str) -> list[float]:
    """The x of every vertical line across an axes stroked with ``stroke``."""
    return [float(x) for x in re.findall(rf'<path d="M(-?[\d.]+) [\d.]+V[\d.]+"[^>]*stroke: {stroke};', svg)]


def _bands(svg: str, stroke: str) -> list[np.ndarray]:
    """The points of every range-bar path (butt caps) stroked with ``stroke``."""
    return [np.array(re.findall(r"[ML](-?[\d.]+) (-?[\d.]+)", d), np.float64).reshape(-1, 2)
            for d in re.findall(rf'<path d="([^"]+)"[^>]*stroke: {stroke}; [^"]*stroke-linecap: butt', svg)]


def _texts(svg: str) -> list[str]:
    return re.findall(r">([^<>]+)</text>", svg)


def _gap(marker: str, start: int, stop: int, method: str) -> GapQC:
    return GapQC(marker=marker, start=start, stop=stop, method=method, error_mm=None, reason="", errors_mm={},
                 weights={})


def test_gap_timeline_draws_each_gap_in_its_row_and_colour() -> None:
    labels = ["A", "B", "C"]
    gaps = [_gap("B", 100, 300, "pca"), _gap("C", 600, 900, "unfilled")]
    svg = P.gap_timeline(labels, 1000, 100.0, gaps, (50, 950), None, "t")
    codes, palette, (x, y, w, h) = _image(svg)
    colour = np.array(palette)[codes]
    rows = codes.shape[0]
    col = lambda f: int(f / 1000 * codes.shape[1])          # noqa: E731 - frame → raster column
    row = lambda i: int((i + 0.5) / 3 * rows)              # noqa: E731 - marker → raster row
    assert colour[row(1), col(200)] == P.FILL_COLOURS["pca"] and colour[row(0), col(200)] == P.FILL_COLOURS["measured"]
    assert colour[row(2), col(750)] == P.FILL_COLOURS["unfilled"] and colour[row(1), col(750)] == P.FILL_COLOURS["measured"]
    assert (codes == FILL_CODES["pca"]).sum() == pytest.approx(codes.shape[1] * 0.2 * rows / 3, rel=0.05)
    # the crop bounds as lines at 0.5 s and 9.5 s of 10 s, the names of the markers and of the fill methods
    xs = sorted(_vlines(svg, "#000000"))
    assert xs == pytest.approx([x + 0.05 * w, x + 0.95 * w], abs=0.01)
    assert {"A", "B", "C", *FILL_CODES, "crop bounds", "time (s)"} <= set(_texts(svg))


def test_speed_plot_draws_the_trace_threshold_and_crop() -> None:
    speed = np.full(1000, 5.0)
    speed[400] = 500.0                                    # one peak at 4 s of 10 s
    svg = P.speed_plot(speed, 100.0, (100, 900), [(0, 100)], 20.0, "s")
    trace = [p for p in _paths(svg, "#333333") if len(p) > 2]
    assert len(trace) == 1 and len(trace[0]) == 1000       # every sample, one path
    pts = trace[0]
    top = pts[np.argmin(pts[:, 1])]
    assert (top[0] - pts[0, 0]) / (pts[-1, 0] - pts[0, 0]) == pytest.approx(400 / 999, abs=1e-3)
    threshold = _paths(svg, "#2ca02c")
    assert len(threshold) == 2                             # the line and its legend key
    # log axis: the threshold (20) lies between the trace's floor (5) and its peak (500) as log10 says
    y_thr = threshold[0][0, 1]
    assert (pts[0, 1] - y_thr) / (pts[0, 1] - top[1]) == pytest.approx(np.log10(4) / 2, abs=1e-3)
    assert {"10", "100", "mm/s", "rest threshold 20 mm/s", "crop bounds"} <= set(_texts(svg))
    assert len(_vlines(svg, "#d62728")) == 2 and len(_paths(svg, "#d62728")) == 3   # and the legend key


def test_clap_plot_has_a_panel_per_clap_with_each_sample() -> None:
    rate = 100.0
    d = np.full(1000, 30.0)
    d[195:205] = 150.0
    svg = P.clap_plot(d, rate, [2.0, 7.0], [2.001, None], "c")
    assert _texts(svg).count("time from mocap clap (s)") == 2
    assert "clap 1 at 2.00 s, video +1.0 ms" in _texts(svg) and "clap 2 at 7.00 s" in _texts(svg)
    dots = re.findall(r'<path d="([^"]+)"[^>]*stroke-linecap: round', svg)
    assert [d_.count("h0") for d_ in dots] == [201, 201]    # one dot per sample within ±1 s
    assert len(_vlines(svg, "#ff7f0e")) == 1                # one video clap
    assert len(_vlines(svg, "#1f77b4")) == 2                # both mocap claps


def test_eye_plot_marks_invalid_and_filled_frames() -> None:
    t = np.arange(1000) / 100.0
    conf = np.full(1000, 0.9)
    valid = np.ones(1000, bool)
    filled = np.zeros(1000, bool)
    valid[200:300] = False
    filled[600:650] = True
    svg = P.eye_plot(t, conf, valid, filled, 0.8, "e")
    codes, palette, _ = _image(svg)
    colour = np.array(palette)[codes[0]]
    n = codes.shape[1]
    assert colour[int(0.25 * n)] == "#f4c2c2" and colour[int(0.625 * n)] == "#c6dbef" and colour[int(0.45 * n)] == "#ffffff"
    assert (colour == "#f4c2c2").mean() == pytest.approx(0.1, abs=0.01)
    assert len(_paths(svg, "#333333")[0]) == 1000
    assert {"confidence", "invalid", "slerp-filled", "gate 0.8", "0.0", "1.0"} <= set(_texts(svg))


@pytest.mark.parametrize("lo,hi,length,along_x", [(0.0, 56.3, 583.2, True), (-1.1, 1.05, 180.0, True),
                                                  (-0.02, 1.02, 93.6, False), (21.0, 157.0, 111.6, False),
                                                  (3.1, 1203.0, 583.2, True), (-0.055, 0.055, 111.6, False)])
def test_linear_ticks_are_matplotlibs(lo: float, hi: float, length: float, along_x: bool) -> None:
    import matplotlib

    with matplotlib.rc_context({"font.size": S.TICK_SIZE}):   # the plots' tick labels: their spacing
        want = _matplotlib_ticks(lo, hi, length, along_x)
    ticks, labels, _ = S.linear_ticks(lo, hi, length, along_x)
    assert list(zip(ticks, labels, strict=True)) == want


def _matplotlib_ticks(lo: float, hi: float, length: float, along_x: bool) -> list[tuple[float, str]]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(length / 72 + 1, length / 72 + 1), dpi=100)
    ax = fig.add_axes((0.5 / (length / 72 + 1), 0.5 / (length / 72 + 1), length / 72 / (length / 72 + 1),
                       length / 72 / (length / 72 + 1)))
    axis = ax.xaxis if along_x else ax.yaxis
    (ax.set_xlim if along_x else ax.set_ylim)(lo, hi)
    fig.canvas.draw()
    want = [(float(v), t.get_text()) for v, t in zip(axis.get_majorticklocs(), axis.get_majorticklabels(), strict=True)
            if min(lo, hi) - 1e-9 <= v <= max(lo, hi) + 1e-9]
    return want


def test_log_ticks_are_matplotlibs() -> None:
    import matplotlib
    from matplotlib.figure import Figure

    with matplotlib.rc_context({"font.size": S.TICK_SIZE}):
        fig = Figure(figsize=(3, 3), dpi=100)
        ax = fig.add_axes((0.2, 0.2, 0.6, 0.6))
        ax.set_yscale("log")
        ax.set_ylim(1.3, 180.0)
        fig.canvas.draw()
    major = [float(v) for v in ax.yaxis.get_majorticklocs() if 1.3 <= v <= 180.0]
    minor = [float(v) for v in ax.yaxis.get_minorticklocs() if 1.3 <= v <= 180.0]
    got_major, labels, got_minor = S.log_ticks(1.3, 180.0, 0.6 * 3 * 72)
    assert got_major == pytest.approx(major) and labels == [f"{v:g}" for v in major]
    assert got_minor == pytest.approx([m for m in minor if not np.isclose(major, m).any()])


def test_plots_are_byte_stable() -> None:
    d = np.linspace(10, 100, 500)
    assert P.clap_plot(d, 100.0, [2.0], [2.0], "x") == P.clap_plot(d.copy(), 100.0, [2.0], [2.0], "x")
    assert P.clap_plot(d, 100.0, [2.0], [2.0], "x") != P.clap_plot(d, 100.0, [2.0], [2.0], "y")   # clip ids


def test_feature_plot_draws_each_poses_band_and_median() -> None:
    from gazepipe.report import plots

    rng = np.random.default_rng(0)
    poses = np.repeat(np.array(["sit", "walk"]), 500)
    values = np.column_stack([rng.uniform(0, 1, 1000), np.where(poses == "walk", 10.0, 0.0)])
    svg = plots.feature_plot(values, poses, ["head.fwd.x", "head.fwd.y"], "t", "f", "mm")
    bands = {c: _bands(svg, c) for c in ("#1f77b4", "#ff7f0e")}   # sit, walk
    assert [len(b) for b in bands.values()] == [1, 1] and all(len(b[0]) == 4 for b in bands.values())
    sit, walk = bands["#1f77b4"][0], bands["#ff7f0e"][0]
    # element 0: the 5–95 % band of uniform values (0.05 … 0.95) for both; element 1: 0 for sit, 10 for walk
    y0, y10 = sit[3, 1], walk[3, 1]
    to_value = lambda y: 10 * (y0 - y) / (y0 - y10)   # noqa: E731 - SVG y → data
    assert to_value(sit[0, 1]) == pytest.approx(0.05, abs=0.02) and to_value(sit[1, 1]) == pytest.approx(0.95, abs=0.02)
    assert walk[0, 0] > sit[0, 0]                            # poses side by side, in order
    medians = re.findall(r'<path d="M([\d. ]+)h6 M([\d. ]+)h6" style="fill: none; stroke: #1f77b4', svg)
    assert len(medians) == 1
    assert {"fwd.x", "fwd.y", "head", "sit (500 rows)", "walk (500 rows)", "t (mm)", "mm"} <= set(_texts(svg))


def test_scalar_features_plot_has_a_panel_per_feature() -> None:
    from gazepipe.report import plots

    poses = np.repeat(np.array(["a", "b", "c"]), 100)
    cols = {f"f{k}": np.arange(300, dtype=np.float64) * (k + 1) for k in range(7)}
    svg = plots.scalar_features_plot(cols, poses, "s", {"f0": "mm"})
    assert all(f"f{k}" in _texts(svg) for k in range(7)) and _texts(svg).count("a") == 7
    assert len(re.findall(r"<clipPath", svg)) == 12         # two rows of six panels
    assert len(_bands(svg, "#2ca02c")) == 7                  # pose c's band in every panel
    assert "mm" in _texts(svg) and _texts(svg).count("value (no unit recorded)") == 6


def test_an_axes_of_whole_inches_has_matplotlibs_number_of_ticks() -> None:
    # 2 inches less margins computed in points is 143.99999999999997: room for 9 y ticks, as matplotlib counts
    assert S.tick_space(2.4 * 72 - 0.4 * 72, False) == S.tick_space(144.0, False) == 9
    from gazepipe.report import plots

    values = np.tile([[-1.0], [1.0]], (200, 30))           # bands from -1 to 1: limits ±1.1, 9 bins of 0.25
    svg = plots.feature_plot(values, np.repeat(np.array(["a", "b"]), 200), [], "t", "x")
    assert {"−1.00", "−0.75", "0.00", "0.25", "1.00"} <= set(_texts(svg))


def test_limits_are_matplotlibs_for_a_constant_trace() -> None:
    import matplotlib
    from matplotlib.figure import Figure

    with matplotlib.rc_context({"font.size": S.TICK_SIZE}):
        fig = Figure()
        ax = fig.add_subplot(111)
        ax.plot([0, 1, 2], [4.0, 4.0, 4.0])
        ax.set_yscale("log")
        log_lim = ax.get_ylim()
        ax2 = fig.add_subplot(212)
        ax2.plot([0, 1, 2], [4.0, 4.0, 4.0])
        lin_lim = ax2.get_ylim()
    assert S.autoscale([np.full(3, 4.0)], log=True) == pytest.approx(log_lim)
    assert S.autoscale([np.full(3, 4.0)]) == pytest.approx(lin_lim)
    assert S.autoscale([np.array([1.0, 30.0, np.nan])]) == pytest.approx((1.0 - 1.45, 30.0 + 1.45))
