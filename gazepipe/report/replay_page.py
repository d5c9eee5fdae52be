"""A take's 3D replay page: the Plotly figure (a plain dict: traces, animation frames, slider, buttons) of
:mod:`gazepipe.report.replay`'s data, and the HTML page that shows it with Plotly's own JavaScript
(``plotly.min.js`` from the plotly package, written once per report folder and loaded by a relative path: no
network, and the folder still works when copied).

The page is the same bytes for the same tables and records: no random ids, no dates. Coordinates are stored
as float32 typed arrays (base64, which plotly.js decodes) rounded to 0.1 mm, and a page stays under
:data:`REPLAY_MAX_BYTES`: a take too long for that gets a wider stride (the worst moments keep their windows).

Besides Plotly's controls, a few lines of script let a link (or a test) choose the frame: ``#frame=N`` shows the
take's frame N, ``#jump=K`` does what the K-th jump button does, ``#step=I`` what the slider's I-th step does;
the frame shown is kept in the plot's ``data-frame`` attribute and the page title.
"""

from __future__ import annotations

import binascii
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from gazepipe import __version__
from gazepipe.report.replay import (
    CATEGORIES,
    MAX_FRAMES,
    UNFILLED,
    Moment,
    ReplayInputs,
    axis_ranges,
    choose_frames,
    dropped_frames,
    head_and_target,
    last_seen,
    raw_in_clean_axes,
    raw_transform,
    robust_points,
    runs,
    sample_categories,
    segment_normals,
    stick_pairs,
    stick_path,
    worst_moments,
)

#: the most bytes a replay page may take (Plotly's script apart, which is shared)
REPLAY_MAX_BYTES = 2_000_000
#: the file every page loads, in the report folder (``OUT/qc/``)
PLOTLY_JS = "plotly.min.js"

#: colours of the sample categories (:data:`gazepipe.report.replay.CATEGORIES`), as the report's gap timeline
#: where they can be seen on white (measured dark grey instead of light)
COLOURS = {"measured": "#4d4d4d", "linear": "#1f77b4", "pchip": "#17becf", "rigid": "#2ca02c", "pca": "#9467bd",
           "unfilled": "#d62728", "swap_repaired": "#ff7f0e", "spike": "#e377c2"}
LEGEND = {"measured": "measured", "linear": "filled: linear", "pchip": "filled: PCHIP",
          "rigid": "filled: rigid cluster", "pca": "filled: PCA", "swap_repaired": "repaired swap",
          "spike": "removed spike (refilled)", "unfilled": "unfilled (where last seen)"}
MOMENT_COLOURS = {"no_row": "#d62728", "swap": "#ff7f0e", "fill_error": "#9467bd", "rotation": "#2ca02c",
                  "spike": "#e377c2"}
#: categories drawn as points at their cleaned position (unfilled apart: at the last position seen)
_POINT_CATS = [c for c in range(len(CATEGORIES)) if c != UNFILLED]


def _b64(values: np.ndarray) -> dict[str, str] | list:
    """A float32 typed array of plotly.js (base64, little-endian) of values already rounded and cast to
    ``<f4``; NaN stays NaN (plotly leaves such a point out and breaks a line there)."""
    if values.size == 0:
        return []
    return {"dtype": "f4", "bdata": binascii.b2a_base64(values.tobytes(), newline=False).decode("ascii")}


def _f4(points: np.ndarray) -> np.ndarray:
    """(..., 3) positions rounded to 0.1 mm as little-endian float32, axes first: (3, ...)."""
    p = np.asarray(points, dtype=np.float64)
    return np.ascontiguousarray(np.moveaxis(np.round(p, 1).astype("<f4"), -1, 0))


def _per_frame(mask: np.ndarray) -> list[np.ndarray]:
    """Per row of the (F, M) ``mask``, the columns where it holds (``np.flatnonzero`` of each row, from one
    ``nonzero`` of the whole)."""
    rows, cols = np.nonzero(mask)
    ends = np.cumsum(np.bincount(rows, minlength=mask.shape[0])).tolist()
    return [cols[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]   # (np.split: a swapaxes call each)


def _xyz(axes: np.ndarray) -> dict[str, Any]:
    """x, y, z typed arrays of (3, N) positions from :func:`_f4`."""
    return {"x": _b64(axes[0]), "y": _b64(axes[1]), "z": _b64(axes[2])}


@dataclass
class Replay:
    """A built replay: the figure, the frames it shows, the moments and the page's own facts."""

    figure: dict[str, Any]
    frames: np.ndarray
    stride: int
    moments: list[Moment]
    start: int
    window: int


#: the animation of one step (the slider's, a jump button's)
ANIM = {"mode": "immediate", "frame": {"duration": 0, "redraw": True}, "transition": {"duration": 0}}


class _Frames:
    """Each shown frame's trace data, made on demand (a long take is never converted whole)."""

    def __init__(self, inp: ReplayInputs) -> None:
        raw, clean, ms = inp.raw, inp.clean, inp.markerset
        self.inp = inp
        self.rate = float(raw.rate_hz)
        T = raw.n_frames
        self.cat = sample_categories(inp.fill, inp.spike, clean.valid)
        self.held_row = last_seen(clean.valid)
        self.transform = raw_transform(inp)
        self.head, self.target = head_and_target(inp)
        self.cpath = np.array(stick_path(stick_pairs(ms, clean.labels)), dtype=np.int64)
        self.rpath = np.array(stick_path(stick_pairs(ms, raw.labels)), dtype=np.int64)
        ri = {lab: i for i, lab in enumerate(raw.labels)}
        self.swaps = [(ri[a], ri[b], s0, s1) for a, b, s0, s1, _ in inp.swaps if a in ri and b in ri]
        cframes = np.asarray(inp.clean_frames, dtype=np.int64)
        self.row_of = np.full(T, -1, dtype=np.int64)
        ok = (cframes >= 0) & (cframes < T)
        self.row_of[cframes[ok]] = np.flatnonzero(ok)
        self.clabels = np.array(clean.labels, dtype=object)
        self.rlabels = np.array(raw.labels, dtype=object)
        self.columns = np.arange(clean.n_markers)

    def raw_at(self, frames: np.ndarray) -> np.ndarray:
        """(F, M_raw, 3) the raw capture of ``frames`` in the cleaned axes."""
        return raw_in_clean_axes(self.inp, frames, self.transform)

    def _sticks(self, xyz: np.ndarray, labels: list[str], path: np.ndarray) -> np.ndarray:
        """(3, F, V) the sticks of frames ``xyz`` (F, M, 3) (``path`` over the markers, ``-1`` lifting the pen),
        then each segment's normal."""
        pts = xyz[:, np.maximum(path, 0)]
        pts[:, path < 0] = np.nan
        normals = segment_normals(self.inp.markerset, labels, xyz)
        if normals.shape[1]:
            pts = np.concatenate([pts, np.full((len(xyz), 1, 3), np.nan), normals], axis=1)
        return _f4(pts)

    def data(self, frames: np.ndarray) -> list[list[dict[str, Any]]]:
        """The dynamic traces' data at each of the take's ``frames`` (in the order of :func:`_traces`),
        computed for them all at once; each frame's markers of a category picked by one ``nonzero`` over all
        the frames."""
        frames = np.asarray(frames, dtype=np.int64)
        clean, raw = self.inp.clean, self.inp.raw
        rows = self.row_of[frames]
        kept = rows >= 0
        k_rows = np.where(kept, rows, 0)
        rxyz = self.raw_at(frames)
        rsticks = self._sticks(rxyz.copy(), raw.labels, self.rpath)
        rpts = _f4(rxyz)
        r_ok = raw.valid[frames] & np.isfinite(rxyz).all(axis=2)
        cleaned = self._cleaned(k_rows) if clean.n_frames else None
        empty: dict[str, Any] = {"x": [], "y": [], "z": []}
        raw_pts = _per_frame(r_ok)
        swapped = self._swapped(frames, r_ok)
        out: list[list[dict[str, Any]]] = []
        for i, f in enumerate(frames.tolist()):
            if kept[i] and cleaned is not None:
                d = cleaned(i)
            else:
                d = [dict(empty)] + [{**empty, "text": []} for _ in range(len(_POINT_CATS) + 1)] + [dict(empty)]
            d.append(_xyz(rsticks[:, i]))
            sel = raw_pts[i]
            d.append({**_xyz(rpts[:, i, sel]), "text": self.rlabels[sel].tolist()})
            sw = swapped[i]
            d.append({**_xyz(rpts[:, i, sw]), "text": self.rlabels[sw].tolist()})
            t = round(f / self.rate, 3)
            d.append({"x": [t, t], "y": [0, 1]})
            out.append(d)
        return out

    def _cleaned(self, k_rows: np.ndarray) -> Any:
        """The cleaned traces' data of the frame at position ``i`` of cleaned rows ``k_rows``, as a function of
        ``i`` (what is computed for every frame at once is computed here)."""
        clean = self.inp.clean
        cxyz = clean.xyz[k_rows]
        csticks = self._sticks(cxyz, clean.labels, self.cpath)
        cpts = _f4(cxyz)
        cats = self.cat[k_rows]
        held_rows = self.held_row[k_rows]
        gaze = _f4(np.stack([self.head[k_rows], self.target[k_rows]], axis=1))
        gaze_ok = np.isfinite(gaze).all(axis=(0, 2))
        by_cat = [_per_frame(cats == c) for c in _POINT_CATS]
        held = _per_frame((cats == UNFILLED) & (held_rows >= 0))
        held_pts = _f4(clean.xyz[np.maximum(held_rows, 0), self.columns])   # where each marker was last seen

        def frame(i: int) -> list[dict[str, Any]]:
            d = [_xyz(csticks[:, i])]
            for sels in by_cat:
                sel = sels[i]
                d.append({**_xyz(cpts[:, i, sel]), "text": self.clabels[sel].tolist()})
            sel = held[i]
            d.append({**_xyz(held_pts[:, i, sel]), "text": self.clabels[sel].tolist()})
            d.append(_xyz(gaze[:, i]) if gaze_ok[i] else {"x": [], "y": [], "z": []})
            return d

        return frame

    def _swapped(self, frames: np.ndarray, r_ok: np.ndarray) -> list[list[int]]:
        """Per frame, the raw markers (seen) of the label swaps going on, in order."""
        on = np.zeros(r_ok.shape, bool)
        for a, b, s0, s1 in self.swaps:
            during = (frames >= s0) & (frames < s1)
            on[during, a] = True
            on[during, b] = True
        return [sel.tolist() for sel in _per_frame(on & r_ok)]

    def frames(self, frames: np.ndarray, crop: tuple[int, int]) -> list[tuple[dict[str, Any], dict[str, Any]]]:
        """The animation frame and the slider step of each of the take's ``frames``."""
        out = []
        for f, data in zip(np.asarray(frames).tolist(), self.data(frames), strict=True):
            where = "" if crop[0] <= f < crop[1] else " \u00b7 cropped out"
            step = {"method": "animate", "label": f"frame {f} \u00b7 {f / self.rate:.2f} s{where}",
                    "args": [[str(f)], ANIM]}
            out.append(({"name": str(f), "data": data, "traces": list(range(N_DYNAMIC))}, step))
        return out


def _traces() -> list[dict[str, Any]]:
    """The dynamic traces (data from :meth:`_Frames.data`), in drawing order."""
    traces: list[dict[str, Any]] = [
        {"type": "scatter3d", "mode": "lines", "name": "cleaned: sticks", "legendgroup": "sticks",
         "line": {"color": "#7a7a7a", "width": 4}, "hoverinfo": "skip", "connectgaps": False}]
    for c in _POINT_CATS:
        name = CATEGORIES[c]
        traces.append({"type": "scatter3d", "mode": "markers", "name": LEGEND[name], "legendgroup": name,
                       "marker": {"size": 4 if name == "measured" else 6, "color": COLOURS[name],
                                  "line": {"width": 0}},
                       "hovertemplate": "%{text}<extra>" + escape(LEGEND[name]) + "</extra>"})
    traces.append({"type": "scatter3d", "mode": "markers", "name": LEGEND["unfilled"], "legendgroup": "unfilled",
                   "marker": {"size": 5, "color": COLOURS["unfilled"], "symbol": "diamond"},
                   "hovertemplate": "%{text}: unfilled, shown where last seen<extra></extra>"})
    traces.append({"type": "scatter3d", "mode": "lines", "name": "eyes to gaze target", "legendgroup": "gaze",
                   "line": {"color": "#000000", "width": 3, "dash": "dash"}, "hoverinfo": "skip"})
    traces.append({"type": "scatter3d", "mode": "lines", "name": "raw: sticks", "legendgroup": "raw",
                   "line": {"color": "#c4c4c4", "width": 3}, "hoverinfo": "skip", "connectgaps": False})
    traces.append({"type": "scatter3d", "mode": "markers", "name": "raw capture", "legendgroup": "raw",
                   "marker": {"size": 3, "color": "#9e9e9e", "symbol": "circle-open"},
                   "hovertemplate": "%{text}<extra>raw</extra>"})
    traces.append({"type": "scatter3d", "mode": "markers+text", "name": "raw labels of swapped markers",
                   "legendgroup": "raw", "marker": {"size": 7, "color": COLOURS["swap_repaired"],
                                                    "symbol": "circle-open"},
                   "textposition": "top center", "textfont": {"color": "#c45a00", "size": 12},
                   "hovertemplate": "raw label %{text} (a label swap)<extra></extra>"})
    traces.append({"type": "scatter", "mode": "lines", "name": "now", "xaxis": "x", "yaxis": "y",
                   "line": {"color": "#000000", "width": 2}, "showlegend": False, "hoverinfo": "skip"})
    return traces


N_DYNAMIC = len(_traces())
#: the traces of the cleaned markers and of the raw capture (what the layer buttons show and hide)
CLEANED_TRACES = [i for i, t in enumerate(_traces()) if t["type"] == "scatter3d" and t["legendgroup"] != "raw"]
RAW_TRACES = [i for i, t in enumerate(_traces()) if t.get("legendgroup") == "raw"]


def _json_len(obj: Any) -> int:
    return len(_json(obj))


def build_replay(inp: ReplayInputs, budget: int | None = None, max_bytes: int = REPLAY_MAX_BYTES) -> Replay:
    """The Plotly figure of a take's replay. ``budget``: about how many frames it shows; by default as many as
    keep the figure within ``max_bytes`` (measured on a sample of frames), at most :data:`MAX_FRAMES`."""
    raw, clean, ms = inp.raw, inp.clean, inp.markerset
    rate = float(raw.rate_hz)
    T = raw.n_frames
    moments = worst_moments(inp)
    fr = _Frames(inp)
    if budget is None:
        probe = np.unique(np.linspace(0, max(T - 1, 0), num=min(T, 24)).astype(np.int64))
        per = max((_json_len(x) + 2 for x in fr.frames(probe, inp.crop)), default=1)
        budget = int(min(MAX_FRAMES, (0.92 * max_bytes - 60_000) // per))
    budget = max(budget, 20)
    frames, stride, half = choose_frames(T, [m.frame for m in moments], rate, budget)
    start = moments[0].frame if moments else int(min(max(inp.crop[0], 0), max(T - 1, 0)))

    traces = _traces()
    if moments:   # the timeline's marks of the worst moments (static)
        traces.append({"type": "scatter", "mode": "markers", "xaxis": "x", "yaxis": "y", "showlegend": False,
                       "x": [round(m.frame / rate, 3) for m in moments], "y": [0.5] * len(moments),
                       "marker": {"symbol": "triangle-down", "size": 11,
                                  "color": [MOMENT_COLOURS[m.kind] for m in moments],
                                  "line": {"width": 1, "color": "#000000"}},
                       "text": [m.label for m in moments], "hovertemplate": "%{text}<extra></extra>"})
    for tr, d in zip(traces, fr.data(np.array([start]))[0], strict=False):
        tr.update(d)
    built = fr.frames(frames, inp.crop)
    figure_frames = [b[0] for b in built]
    steps = [b[1] for b in built]

    # the view: equal millimetres on every axis, the lab's vertical up; the subject fills it, and a button
    # widens it to everything the take shows (the gaze target can be metres away); from the frames shown
    subject = [clean.labels.index(m) for m in ms.subject_markers if m in clean.labels]
    rsubject = [raw.labels.index(m) for m in ms.subject_markers if m in raw.labels]
    rows = fr.row_of[frames]
    shown = rows[rows >= 0]
    raw_shown = fr.raw_at(frames)
    out_of_crop = raw_shown[rows < 0]
    body = axis_ranges([clean.xyz[shown][:, subject], robust_points(out_of_crop[:, rsubject])], pad=0.35)
    whole = axis_ranges([clean.xyz[shown], robust_points(out_of_crop), robust_points(raw_shown[rows >= 0]),
                         fr.target[shown], fr.head[shown]])
    from gazepipe.stages.geometry import up_vector

    up = up_vector(ms.up_axis)
    eye = np.array([0.9, -0.9, 0.3]) if abs(up[2]) > 0.5 else np.array([0.9, 0.3, 0.9])
    eye = eye * np.where(up < 0, -1, 1)

    def view(r: np.ndarray) -> dict[str, Any]:
        span = r[:, 1] - r[:, 0]
        out: dict[str, Any] = {"aspectratio": {a: round(float(v), 4) for a, v in zip("xyz", span / span.max(),
                                                                                   strict=True)}}
        for i, a in enumerate("xyz"):
            out[f"{a}axis.range"] = [round(float(r[i, 0]), 1), round(float(r[i, 1]), 1)]
        return out

    scene: dict[str, Any] = {"domain": {"x": [0.25, 1.0], "y": [0.25, 1.0]}, "aspectmode": "manual",
                             "aspectratio": view(body)["aspectratio"],
                             "camera": {"up": {a: float(v) for a, v in zip("xyz", up, strict=True)},
                                        "eye": {a: float(v) for a, v in zip("xyz", eye, strict=True)}},
                             "uirevision": "keep"}
    for i, a in enumerate("xyz"):
        scene[f"{a}axis"] = {"range": [round(float(body[i, 0]), 1), round(float(body[i, 1]), 1)],
                             "autorange": False, "title": {"text": f"{a} (mm)"}, "zeroline": False}

    lo, hi = inp.crop
    shapes = []
    for f0, f1 in ((0, lo), (hi, T)):
        if f1 > f0:
            shapes.append({"type": "rect", "xref": "x", "yref": "y", "x0": round(f0 / rate, 3),
                           "x1": round(f1 / rate, 3), "y0": 0, "y1": 1, "fillcolor": "#bdbdbd", "opacity": 0.6,
                           "line": {"width": 0}, "layer": "below"})
    bad, _ = dropped_frames(inp)
    cframes = np.asarray(inp.clean_frames, dtype=np.int64)
    for r0, r1 in runs(bad):
        shapes.append({"type": "rect", "xref": "x", "yref": "y", "x0": round(cframes[r0] / rate, 3),
                       "x1": round((cframes[r1 - 1] + 1) / rate, 3), "y0": 0, "y1": 0.25,
                       "fillcolor": MOMENT_COLOURS["no_row"], "opacity": 0.7, "line": {"width": 0}})
    for _a, _b, s0, s1, _r in inp.swaps:
        shapes.append({"type": "rect", "xref": "x", "yref": "y", "x0": round(s0 / rate, 3),
                       "x1": round(s1 / rate, 3), "y0": 0.75, "y1": 1, "fillcolor": MOMENT_COLOURS["swap"],
                       "opacity": 0.7, "line": {"width": 0}})

    play_ms = int(max(40, round(1000.0 * stride / rate)))
    both = CLEANED_TRACES + RAW_TRACES
    nc, nr = len(CLEANED_TRACES), len(RAW_TRACES)
    menus: list[dict[str, Any]] = [
        {"type": "buttons", "direction": "left", "x": 0.25, "xanchor": "right", "y": 0.11, "yanchor": "top",
         "pad": {"r": 8, "t": 38}, "showactive": False, "buttons": [
             {"method": "animate", "label": "\u25b6 play",
              "args": [None, {"mode": "immediate", "fromcurrent": True, "frame": {"duration": play_ms, "redraw": True},
                              "transition": {"duration": 0}}]},
             {"method": "animate", "label": "\u275a\u275a pause",
              "args": [[None], {"mode": "immediate", "frame": {"duration": 0, "redraw": False},
                                "transition": {"duration": 0}}]}]},
        {"type": "buttons", "direction": "right", "x": 0.31, "xanchor": "left", "y": 1.0, "yanchor": "bottom",
         "showactive": True, "active": 0, "buttons": [
             {"method": "restyle", "label": "cleaned and raw", "args": [{"visible": [True] * (nc + nr)}, both]},
             {"method": "restyle", "label": "cleaned only", "args": [{"visible": [True] * nc + [False] * nr}, both]},
             {"method": "restyle", "label": "raw only", "args": [{"visible": [False] * nc + [True] * nr}, both]}]},
        {"type": "buttons", "direction": "right", "x": 0.63, "xanchor": "left", "y": 1.0, "yanchor": "bottom",
         "showactive": True, "active": 0, "buttons": [
             {"method": "relayout", "label": "view: subject",
              "args": [{f"scene.{k}": v for k, v in view(body).items()}]},
             {"method": "relayout", "label": "view: everything",
              "args": [{f"scene.{k}": v for k, v in view(whole).items()}]}]},
    ]
    annotations = []
    if moments:
        menus.append({"type": "buttons", "direction": "down", "x": 0.0, "xanchor": "left", "y": 0.97,
                      "yanchor": "top", "showactive": False, "font": {"size": 11}, "bgcolor": "#f7f7f7",
                      "buttons": [{"method": "animate", "label": m.label, "args": [[str(m.frame)], ANIM]}
                                  for m in moments]})
        annotations.append({"text": "<b>Jump to the worst moments</b>", "xref": "paper", "yref": "paper", "x": 0.0,
                            "y": 1.0, "xanchor": "left", "yanchor": "top", "showarrow": False})
    layout = {
        "title": {"text": f"{escape(inp.key)}: {escape(inp.kind)}", "x": 0.0, "xanchor": "left",
                  "y": 0.995, "yanchor": "top", "font": {"size": 15}},
        "scene": scene, "showlegend": True,
        "legend": {"x": 1.0, "xanchor": "right", "y": 0.95, "yanchor": "top", "bgcolor": "rgba(255,255,255,0.8)",
                   "groupclick": "togglegroup", "font": {"size": 11}},
        "xaxis": {"domain": [0.25, 1.0], "anchor": "y", "range": [0, round(T / rate, 3)], "fixedrange": True,
                  "title": {"text": "s", "standoff": 2}, "ticks": "outside"},
        "yaxis": {"domain": [0.15, 0.21], "anchor": "x", "range": [0, 1], "fixedrange": True, "visible": False},
        "shapes": shapes, "annotations": annotations,
        "sliders": [{"active": int(np.searchsorted(frames, start)), "steps": steps, "x": 0.25, "len": 0.75,
                     "y": 0.11, "yanchor": "top", "pad": {"t": 36, "b": 6}, "transition": {"duration": 0},
                     "currentvalue": {"visible": True, "prefix": "", "xanchor": "left", "font": {"size": 13}}}],
        "updatemenus": menus, "margin": {"l": 10, "r": 10, "t": 36, "b": 10},
        "paper_bgcolor": "#ffffff", "hovermode": "closest", "font": {"family": "DejaVu Sans, Arial, sans-serif"},
    }
    fig = {"data": traces, "layout": layout, "frames": figure_frames}
    return Replay(fig, frames, stride, moments, start, half)


def _json(obj: Any) -> str:
    """Compact JSON safe inside a <script> element (and an HTML attribute): every ``<``, ``>`` and ``&`` a \\u
    escape (a marker labelled ``<!--<script>`` otherwise leaves the page blank; no entity can form), and every
    character beyond ASCII one too (U+2028 and U+2029 included, line breaks to older JavaScript); the text stays
    the same JSON. (``str.replace`` thrice: a translation table walks the whole text in Python-level steps.)"""
    text = json.dumps(obj, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


_SCRIPT = """(function(){
var gd=document.getElementById('replay');
if(!window.Plotly){gd.textContent='Plotly did not load: this page needs '+SRC+' beside it (gazepipe writes it into the report folder).';return;}
var fig=FIG, info=INFO;
function show(name){gd.setAttribute('data-frame',name);document.title=info.title+' \\u00b7 frame '+name;}
function go(args){return Plotly.animate(gd,args[0],args[1]).then(function(){show(args[0][0]);});}
function fromHash(){
 var m=/^#(frame|jump|step)=(\\d+)$/.exec(location.hash);if(!m)return null;var n=+m[2];
 if(m[1]==='frame')return info.frames.indexOf(String(n))<0?null:[[String(n)],info.anim];
 if(m[1]==='jump'){var b=info.jumpMenu<0?null:gd.layout.updatemenus[info.jumpMenu].buttons[n];return b?b.args:null;}
 var s=gd.layout.sliders[0].steps[n];return s?s.args:null;}
Plotly.newPlot(gd,fig.data,fig.layout,fig.config).then(function(){return Plotly.addFrames(gd,fig.frames);}).then(function(){
 gd.on('plotly_animatingframe',function(e){show(e.name);});
 window.addEventListener('hashchange',function(){var a=fromHash();if(a)go(a);});
 var a=fromHash();if(a)return go(a);show(info.start);
}).then(function(){gd.setAttribute('data-load-ms',String(Math.round(performance.now())));gd.setAttribute('data-ready','1');});
})();"""

CSS = """body{font-family:'DejaVu Sans',Arial,sans-serif;font-size:13px;margin:10px 18px;color:#222}
h1{font-size:17px;margin:4px 0} #replay{width:100%;height:calc(100vh - 40px);min-height:620px}
.muted{color:#666} ul.moments{margin:4px 0;padding-left:20px} p{max-width:1100px;margin:6px 0}"""


def replay_html(inp: ReplayInputs, plotly_src: str) -> tuple[str, Replay]:
    """The replay page of a take, loading Plotly from ``plotly_src`` (a relative path, or ``inline:`` followed by
    the script itself for a page that stands alone), within :data:`REPLAY_MAX_BYTES` (Plotly inline apart)."""
    budget: int | None = None
    while True:
        rep = build_replay(inp, budget)
        page = _page(inp, rep, plotly_src)
        size = len(page.encode()) - (len(plotly_src) if plotly_src.startswith("inline:") else 0)
        if size <= REPLAY_MAX_BYTES or len(rep.frames) <= 20:
            return page, rep
        budget = max(20, int(len(rep.frames) * 0.95 * REPLAY_MAX_BYTES / size))


def _page(inp: ReplayInputs, rep: Replay, plotly_src: str) -> str:
    rate = float(inp.raw.rate_hz)
    T = inp.raw.n_frames
    lo, hi = inp.crop
    up = inp.markerset.up_axis
    jump_menu = len(rep.figure["layout"]["updatemenus"]) - 1 if rep.moments else -1
    info = {"title": f"{inp.key}: 3D replay", "start": str(rep.start), "anim": ANIM, "jumpMenu": jump_menu,
            "frames": [str(int(f)) for f in rep.frames]}
    config = {"responsive": True, "displaylogo": False, "scrollZoom": True,
              "toImageButtonOptions": {"filename": inp.key.replace("/", "_") + "_replay"}}
    fig = dict(rep.figure, config=config)
    if plotly_src.startswith("inline:"):
        loader = f"<script>{plotly_src[len('inline:'):]}</script>"
        src_note = "(Plotly is inside this page)"
    else:
        loader = f'<script src="{escape(plotly_src)}" charset="utf-8"></script>'
        src_note = escape(plotly_src)
    # one pass: a label holding a placeholder's name (a marker called INFO) is never replaced in turn
    values = {"FIG": _json(fig), "INFO": _json(info), "SRC": _json(src_note)}
    script = re.sub(r"\b(FIG|INFO|SRC)\b", lambda m: values[m.group(1)], _SCRIPT)
    moments = "".join(f'<li><a href="#jump={i}">{escape(m.label)}</a>: {escape(m.detail)}</li>'
                      for i, m in enumerate(rep.moments))
    windows = "" if not rep.moments else (f" Around each worst moment every frame is kept (&plusmn;{rep.window} "
                                          "frames), so those stretches play in slow motion.")
    nth = {1: "st", 2: "nd", 3: "rd"}.get(rep.stride % 10 if rep.stride % 100 not in (11, 12, 13) else 0, "th")
    stride = "every frame" if rep.stride == 1 else f"every {rep.stride}{nth} frame"
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{escape(inp.key)}: 3D replay</title>", f"<style>{CSS}</style>", loader, "</head><body>",
        '<div id="replay" data-frame=""></div>',
        f"<h1>{escape(inp.key)} in 3D</h1>",
        f"<p>Cleaned markers coloured by how each sample was made, joined by the sticks of their segments "
        f"(markerset), the raw capture in grey (hollow points, sticks drawn by the raw labels: a label swap shows "
        f"as crossed sticks), and the line from the eyes' centre to the gaze target. Millimetres on equal axes in "
        f"the cleaned markers' frame (lab axes, {escape(up)} up, the root marker {escape(inp.markerset.root)} at "
        f"the origin); the raw capture is moved there frame by frame as the cleaning moved it. "
        f"Click a legend entry to hide it.</p>",
        f"<p>{T} frames at {rate:g} Hz; the replay shows {len(rep.frames)} of them: {stride} and the worst "
        f"moments.{windows} Timeline: grey, the frames cropped out (before frame {lo} and from frame {hi}: in no "
        f"dataset); red, kept frames that give no dataset row; orange, label swaps; triangles, the worst moments."
        f"</p>",
        f'<ul class="moments">{moments}</ul>' if moments else '<p class="muted">No worst moment to jump to: no '
        "fill error, filled rotation, swap, lost row or spike.</p>",
        f'<p class="muted">gazepipe {escape(__version__)}; Plotly {src_note}.</p>',
        f"<script>{script}</script>", "</body></html>"]
    return "\n".join(parts) + "\n"


# ------------------------------------------------------------------------------------------- the files

def plotly_js() -> bytes:
    """Plotly's JavaScript as the installed plotly package ships it (``plotly.offline.get_plotlyjs()``: the
    file is read where the package keeps it, without importing plotly when it is found there)."""
    from importlib.util import find_spec

    spec = find_spec("plotly")
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        path = Path(folder) / "package_data" / PLOTLY_JS
        if path.is_file():
            return path.read_bytes()
    from plotly.offline import get_plotlyjs

    return get_plotlyjs().encode("utf-8")


def write_plotly_js(qc: Path, tmp: Path) -> Path:
    """``qc/plotly.min.js``, written (atomically) unless it already holds these bytes."""
    path = qc / PLOTLY_JS
    write_if_changed(path, plotly_js(), tmp)
    return path


def write_if_changed(path: Path, data: bytes, tmp: Path) -> None:
    """Write ``data`` to ``path`` atomically unless the file already holds these bytes (an unchanged page keeps
    its modification time, and a report rewritten over a copied folder rewrites nothing)."""
    from gazepipe.pipeline.atomic import atomic_write_bytes

    try:
        same = path.stat().st_size == len(data) and path.read_bytes() == data
    except OSError:
        same = False
    if not same:
        atomic_write_bytes(path, data, tmp)


def page_path(qc: Path, folder: str, session: str, take: str) -> Path:
    """Where the page of a take goes: ``qc/<folder>/<session>/<take>.html``; a session or take that is not an id
    (letters, digits, ``_``, ``-``: a path, say) is refused (:class:`ConfigError`), so no page lands outside."""
    from gazepipe.errors import ConfigError, printable
    from gazepipe.io.toml_common import WORD

    for what, name in (("session", session), ("take", take)):
        if not WORD.fullmatch(name):
            raise ConfigError(None, f"{printable(name)!r} is not a {what} id: no page is written for it")
    return qc / folder / session / f"{take}.html"


#: how a page under ``qc/<folder>/<session>/`` reaches ``qc/plotly.min.js``
RELATIVE_PLOTLY = f"../../{PLOTLY_JS}"
#: the report's replay pages, ``qc/replay/<session>/<take>.html`` (the report owns the folder)
REPLAY_DIR = "replay"
#: the pages ``gazepipe view`` writes, ``qc/view/<session>/<take>.html`` (the report leaves them alone)
VIEW_DIR = "view"


def write_report_replays(qc: Path, tmp: Path, pages: dict[tuple[str, str], bytes], prune: bool = True,
                         keep: Sequence[Path] = ()) -> list[Path]:
    """Write the report's replay pages (``(session, take)`` → page) under ``qc/replay/`` (atomically, each
    unless it already holds these bytes), ``qc/plotly.min.js`` when there is a page, and, with ``prune``, delete
    the other files there but ``keep`` (pages of takes gone, or of outputs since changed; ``validate
    --no-plots`` deletes nothing). Returns the pages' paths."""
    if pages:
        write_plotly_js(qc, tmp)
    paths: list[Path] = []
    for (session, take), data in sorted(pages.items()):
        path = page_path(qc, REPLAY_DIR, session, take)
        write_if_changed(path, data, tmp)
        paths.append(path)
    base = qc / REPLAY_DIR
    if prune and base.is_dir():
        kept = set(paths) | set(keep)
        for p in sorted(base.rglob("*"), reverse=True):
            try:
                if p.is_dir():
                    if not any(p.iterdir()):
                        p.rmdir()
                elif p not in kept:
                    p.unlink()
            except OSError:
                pass
        if base.is_dir() and not any(base.iterdir()):
            base.rmdir()
    return paths
