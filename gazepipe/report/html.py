"""``qc/report.html``: one page (inline CSS and SVG, no script, no external URL) rendered from the ``report.json``
object and the plots; each take drawn links to its 3D replay, a page of its own beside it under ``qc/replay/``
(:mod:`gazepipe.report.replay_page`).

Layout: the gate's verdict and a table of contents; which takes have plots and how to plot the others; a
summary table of takes and datasets, worst first (:func:`~gazepipe.report.checks.rank_key`, the rank the plots
are chosen by), naming their failing checks; a table of every check at warning or worse; one section per take,
worst first (checks worst first, plots, or why there are none); one section per dataset; the checks of the
whole output; how checks are graded and the thresholds.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from html import escape
from typing import Any
from urllib.parse import quote

from gazepipe.report.checks import RANK, rank_key


@dataclass(frozen=True)
class Figure:
    """A plot: title, caption and the inline SVG element."""

    title: str
    caption: str
    svg: str


@dataclass(frozen=True)
class PlotSelection:
    """Which takes the page has plots of, and why the others have none.

    ``enabled`` false: no plot drawn (``--no-plots``; ``plotted`` then names the takes whose plots drawn before
    are kept). ``limit``: the number of worst takes asked for
    (``None``: every take). ``ranked``: every take key (``session/take``), worst first. ``plotted``: the takes
    drawn, worst first. ``named``: the takes asked for by name. ``nothing_to_draw``: the takes without a table to
    draw from (face takes, takes whose ingest failed). ``failed``: takes asked for of which nothing could be drawn.
    """

    enabled: bool
    limit: int | None
    ranked: tuple[str, ...]
    plotted: tuple[str, ...] = ()
    named: tuple[str, ...] = ()
    nothing_to_draw: tuple[str, ...] = ()
    failed: tuple[str, ...] = ()

    @functools.cached_property
    def _sets(self) -> tuple[frozenset[str], frozenset[str], frozenset[str]]:
        return frozenset(self.plotted), frozenset(self.nothing_to_draw), frozenset(self.failed)

    def status(self, key: str) -> str:
        """``drawn``, ``nothing to draw``, ``left out`` (no plots at all), ``failed`` or ``not drawn`` (not among
        the takes asked for)."""
        plotted, nothing, failed = self._sets
        if key in plotted:
            return "drawn"
        if key in nothing:
            return "nothing to draw"
        if not self.enabled:
            return "left out"
        return "failed" if key in failed else "not drawn"


#: how to ask for the plots of other takes (the page names no folder: it is the same wherever the output is)
HOW_TO_PLOT = ("<code>gazepipe validate OUT --plot-takes all</code> (every take), <code>--plot-takes N</code> (the "
               "N worst) or <code>--plot-take SESSION/TAKE</code> (one take by name, or a pattern such as "
               "<code>'shift_*'</code>; repeatable)")


CSS = """
body{font-family:'DejaVu Sans',Arial,sans-serif;font-size:13px;margin:20px 28px;color:#222;max-width:1150px}
h1{font-size:20px;margin:0 0 6px} h2{font-size:16px;margin:28px 0 6px;border-bottom:1px solid #ccc}
h3{font-size:13px;margin:14px 0 4px}
table{border-collapse:collapse;margin:6px 0 12px} th,td{border:1px solid #ddd;padding:3px 7px;text-align:left;
vertical-align:top} th{background:#f4f4f4}
.sev{display:inline-block;min-width:58px;text-align:center;border-radius:3px;padding:1px 5px;font-weight:bold;
font-size:11px;color:#fff}
.sev-error{background:#7b1fa2}.sev-fail{background:#c62828}.sev-warning{background:#ef8f00}
.sev-pass{background:#2e7d32}.sev-skipped{background:#9e9e9e}
.gate{padding:8px 12px;border-radius:4px;font-size:15px;font-weight:bold;margin:8px 0 14px;color:#fff}
.gate-pass{background:#2e7d32}.gate-fail{background:#c62828}
figure.plot{margin:10px 0 18px} figure.plot figcaption{color:#555;margin:2px 0 4px}
figure.plot svg{max-width:100%;height:auto}
.muted{color:#777} td.num{text-align:right;font-variant-numeric:tabular-nums}
nav#toc{margin:4px 0 10px} nav#toc ol{margin:2px 0;padding-left:22px}
p.replay{margin:8px 0 12px}
"""


def anchor(kind: str, name: str) -> str:
    return f"{kind}-" + re.sub(r"[^A-Za-z0-9_-]", "-", name)


def _sev(s: str) -> str:
    return f'<span class="sev sev-{escape(s)}">{escape(s)}</span>'


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.4g}"
    return escape(str(v))


def _checks_table(checks: list[dict[str, Any]]) -> str:
    rows = ["<table class=\"checks\"><tr><th>severity</th><th>check</th><th>value</th><th>message</th></tr>"]
    for c in checks:
        rows.append(f"<tr><td>{_sev(c['severity'])}</td><td>{escape(c['id'])}</td>"
                    f"<td class=\"num\">{_fmt(c['value'])}</td><td>{escape(c['message'])}</td></tr>")
    rows.append("</table>")
    return "\n".join(rows)


def _figures(figs: list[Figure]) -> str:
    out = []
    for f in figs:
        out.append(f'<figure class="plot"><h3>{escape(f.title)}</h3><figcaption>{escape(f.caption)}</figcaption>\n'
                   f"{f.svg}\n</figure>")
    return "\n".join(out)


def _n(count: int, noun: str) -> str:
    return f"{count} {noun}" + ("" if count == 1 else "s")


def _plots_paragraph(sel: PlotSelection) -> str:
    """Which takes have plots (links, worst first), how the takes were ranked, and how to plot the others."""
    items: list[str] = []
    if not sel.enabled:
        head = ("<b>Plots</b>: none drawn (--no-plots); every check is in the page. <code>gazepipe validate OUT"
                "</code> draws the datasets&rsquo; plots and those of the worst takes.")
        if sel.plotted:
            links = ", ".join(f'<a href="#{anchor("take", k)}">{escape(k)}</a>' for k in sel.plotted)
            items.append(f"Kept from the report drawn before, their outputs unchanged: the plots and 3D replays of "
                         f"{_n(len(sel.plotted), 'take')} ({links}).")
        items.append(f"To plot takes: {HOW_TO_PLOT}.")
    else:
        links = ", ".join(f'<a href="#{anchor("take", k)}">{escape(k)}</a>' for k in sel.plotted) or "none"
        which = "every take with something to draw" if sel.limit is None else \
            f"the {sel.limit} worst with something to draw"
        if sel.named:
            which += f", and {_n(len(sel.named), 'take')} asked for by name"
        head = f"<b>Plots</b> drawn for {len(sel.plotted)} of {_n(len(sel.ranked), 'take')} ({escape(which)}), " \
               f"worst first: {links}."
        items.append("Worst: the highest severity, then the most checks at fail or error, then the most warnings, "
                     "then the check nearest to (or furthest past) its threshold.")
        rest = [k for k in sel.ranked if sel.status(k) == "not drawn"]
        if rest:
            items.append(f"Not drawn for {_n(len(rest), 'other take')} (&lsquo;not drawn&rsquo; in the summary; every "
                         f"check of theirs is in the page). To plot them: {HOW_TO_PLOT}.")
        if sel.plotted:
            items.append("Each take drawn also has a 3D replay (its own page under <code>qc/replay/</code>, "
                         "linked from its section); <code>gazepipe view OUT SESSION/TAKE --open</code> makes one "
                         "for any take.")
        if sel.failed:
            items.append(f"Nothing could be drawn for {_n(len(sel.failed), 'take')} asked for: see the notes below.")
    if sel.nothing_to_draw:
        items.append(f"Nothing to draw for {_n(len(sel.nothing_to_draw), 'take')} (no raw markers or eye-tracking "
                     "table: face takes, takes whose ingest failed).")
    return f'<div id="plots"><p>{head}</p><ul>' + "".join(f"<li>{i}</li>" for i in items) + "</ul></div>"


def _take_plots_note(sel: PlotSelection | None, key: str) -> str:
    """The line a take section without plots has instead: why, and how to draw them."""
    if sel is None:
        return ""
    status = sel.status(key)
    if status == "nothing to draw":
        return ('<p class="muted plots-note">No plots: nothing to draw for this take (no raw markers or '
                "eye-tracking table).</p>")
    if status == "left out":
        return '<p class="muted plots-note">Plots left out (--no-plots).</p>'
    if status == "failed":
        return '<p class="muted plots-note">No plot could be drawn for this take (see the notes above).</p>'
    worst = "" if sel.limit is None else f" (not among the {sel.limit} worst takes)"
    return (f'<p class="muted plots-note">Plots not drawn{worst}: <code>gazepipe validate OUT --plot-take '
            f"{escape(key)}</code> draws them.</p>")


#: how the severities are decided, for the page's last section
GRADING = (
    "<p>Every check is <b>pass</b>, <b>warning</b>, <b>fail</b>, <b>error</b> (it could not be evaluated) or "
    "<b>skipped</b> (not applicable: no video, no eye tracking, a dataset whose inputs no take has). The gate "
    "(<code>--fail-on fail</code>) fails on fail and error; <code>--fail-on warning</code> on warnings too.</p>"
    "<p>A gap is graded by what it costs the datasets, not by the raw share of one marker: <b>unfilled</b> is at "
    "most a warning for a marker left unfilled on more than <code>unfilled_warn</code> of the kept frames when "
    "the frames still give their dataset rows (the segment rotations were computed, e.g. from the segment's "
    "other markers); the rows lost (kept frames with a marker unfilled whose joints row has no character frame, "
    "a segment rotation missing or, for gaze_follow, no target direction) are graded as a share of the take's "
    "kept frames: warning above <code>unfilled_warn</code>, fail above <code>unfilled_fail</code>. A take that "
    "feeds no dataset (neutral) loses no row; without a joints table every frame with an unfilled marker counts "
    "as lost. <b>gap_share</b> (gaps at ingest, before filling) is a warning only.</p>")


def _toc(takes: list[dict[str, Any]], datasets: list[dict[str, Any]]) -> str:
    """The table of contents: each part of the page, the takes worst first."""
    def link(target: str, text: str) -> str:
        return f'<a href="#{target}">{escape(text)}</a>'
    worst = [t for t in takes if RANK[t["severity"]] >= RANK["warning"]][:6]
    first = ", ".join(link(anchor("take", f"{t['session']}/{t['take']}"), f"{t['session']}/{t['take']}")
                      for t in worst)
    items = [link("summary-heading", "Summary") + " (takes and datasets, worst first)",
             link("problems", "Checks at warning or worse"),
             link("takes", f"Takes, worst first ({len(takes)})") + (f": {first}" if first else ""),
             link("datasets", f"Datasets ({len(datasets)})") + ": " + ", ".join(
                 link(anchor("dataset", d["name"]), d["name"]) for d in datasets),
             link("output", "Whole output"), link("grading", "How checks are graded, thresholds")]
    return '<nav id="toc"><b>Contents</b><ol>' + "".join(f"<li>{i}</li>" for i in items) + "</ol></nav>"


def _replay(href: str, key: str) -> str:
    """A take's link to its 3D replay page (a link, not a frame: the report opens without loading any)."""
    url = escape(quote(href), quote=True)
    return (f'<p class="replay"><b><a href="{url}">3D replay of {escape(key)}</a></b> (its own page: the markers '
            "and sticks in 3D, cleaned over raw, coloured by how each sample was made, with a time slider and "
            "buttons that jump to the worst moments)</p>")


def render_html(report: dict[str, Any], take_figs: dict[str, list[Figure]],
                dataset_figs: dict[str, list[Figure]], plot_notes: list[str] | None = None,
                plots: PlotSelection | None = None, replays: dict[str, str] | None = None) -> str:
    """The page for ``report`` (the report.json object) with the plots of each take (key ``session/take``) and
    dataset (key: its name), notes on plots that could not be drawn, (``plots``) which takes were plotted and
    why the others were not, and (``replays``) the 3D replay page of each take that has one (its path relative
    to the report)."""
    replays = replays or {}
    gate = report["gate"]
    summ = report["summary"]
    p: list[str] = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
                    "<title>gazepipe QC report</title>", f"<style>{CSS}</style></head><body>"]
    p.append(f"<h1>gazepipe QC report</h1><p class=\"muted\">gazepipe {escape(report['gazepipe_version'])}, "
             f"report schema {report['schema_version']}; {summ['takes']} take(s), {summ['datasets']} dataset(s)</p>")
    verdict = "passed" if gate["passed"] else f"failed: {len(gate['hit'])} check(s) at or above {gate['fail_on']}"
    p.append(f'<div id="gate" class="gate gate-{"pass" if gate["passed"] else "fail"}">QC gate '
             f"(--fail-on {escape(gate['fail_on'])}) {escape(verdict)}</div>")
    counts = ", ".join(f"{n} {s}" for s, n in sorted(summ["checks"].items(), key=lambda kv: -RANK[kv[0]]) if n)
    p.append(f"<p>Checks: {escape(counts)}.</p>")
    takes = sorted(report["takes"], key=lambda t: rank_key(t["severity"], t["checks"],
                                                             f"{t['session']}/{t['take']}"))
    p.append(_toc(takes, report["datasets"]))
    if plots is not None:
        p.append(_plots_paragraph(plots))

    # summary: one row per take and dataset, worst first by the rank the plots are chosen by
    entries = [("dataset", d["name"], "dataset", "", d["severity"], d["checks"]) for d in report["datasets"]]
    entries += [("take", f"{t['session']}/{t['take']}", t["kind"], t["pose"], t["severity"], t["checks"])
                for t in report["takes"]]
    entries.sort(key=lambda e: rank_key(e[4], e[5], e[1]))
    p.append('<h2 id="summary-heading">Summary</h2>')
    p.append('<p class="muted">Worst first: the highest severity, then the most checks at fail or error, then the '
             "most warnings, then the check nearest to (or furthest past) its threshold.</p>")
    p.append('<table id="summary"><tr><th>severity</th><th>take / dataset</th><th>kind</th><th>pose</th>'
             "<th>fail</th><th>warning</th><th>checks at warning or worse</th><th>plots</th></tr>")
    for scope, key, kind, pose, sev, checks in entries:
        bad = [c for c in checks if RANK[c["severity"]] >= RANK["warning"]]
        nf = sum(c["severity"] in ("fail", "error") for c in checks)
        nw = sum(c["severity"] == "warning" for c in checks)
        if scope == "dataset":
            drawn = "drawn" if dataset_figs.get(key) else ""
        else:
            drawn = plots.status(key) if plots is not None else ("drawn" if take_figs.get(key) else "")
        p.append(f"<tr><td>{_sev(sev)}</td><td><a href=\"#{anchor(scope, key)}\">{escape(key)}</a></td>"
                 f"<td>{escape(kind)}</td><td>{escape(pose)}</td><td class=\"num\">{nf}</td>"
                 f"<td class=\"num\">{nw}</td><td>{escape(', '.join(c['id'] for c in bad))}</td>"
                 f"<td>{escape(drawn)}</td></tr>")
    p.append("</table>")

    failing = summ["failing"]
    p.append('<h2 id="problems">Checks at warning or worse</h2>')
    if failing:
        p.append('<table id="failing"><tr><th>severity</th><th>take / dataset</th><th>check</th><th>message</th></tr>')
        for r in failing:
            link = anchor(r["scope"], r["target"]) if r["scope"] != "output" else "output"
            p.append(f"<tr><td>{_sev(r['severity'])}</td><td><a href=\"#{link}\">{escape(r['target'])}</a></td>"
                     f"<td>{escape(r['id'])}</td><td>{escape(r['message'])}</td></tr>")
        p.append("</table>")
    else:
        p.append("<p>None.</p>")

    p.append('<h2 id="takes">Takes, worst first</h2>')
    p.append(f"<p>{_n(len(takes), 'take')}; the plotted ones first among them as the worst.</p>")
    for t in takes:
        key = f"{t['session']}/{t['take']}"
        p.append(f"<h2 id=\"{anchor('take', key)}\">{_sev(t['severity'])} {escape(key)} "
                 f"<span class=\"muted\">{escape(t['kind'])}, {escape(t['pose'])}</span></h2>")
        stages = ", ".join(f"{k} {v}" for k, v in t["stages"].items()) or "none ran"
        p.append(f"<p>Stages: {escape(stages)}</p>")
        p.append(_checks_table(t["checks"]))
        figs = take_figs.get(key, [])
        if key in replays:
            p.append(_replay(replays[key], key))
        p.append(_figures(figs) if figs else _take_plots_note(plots, key))

    p.append('<h2 id="datasets">Datasets</h2>')
    p.append(f"<p>{_n(len(report['datasets']), 'dataset')}.</p>")
    for d in report["datasets"]:
        p.append(f"<h2 id=\"{anchor('dataset', d['name'])}\">{_sev(d['severity'])} dataset {escape(d['name'])}</h2>")
        c = d["counts"] or {}
        if d["severity"] == "skipped":
            p.append(f"<p>{escape(d['checks'][0]['message'] if d['checks'] else 'skipped')}</p>")
        else:
            p.append(f"<p>{_fmt(c.get('takes'))} take(s), {_fmt(c.get('rows'))} rows; schema hash "
                     f"<code>{_fmt(d['schema_hash'])}</code></p>")
        p.append(_checks_table(d["checks"]))
        p.append(_figures(dataset_figs.get(d["name"], [])))

    p.append('<h2 id="output">Whole output</h2>')
    p.append(_checks_table(report["output_checks"]))
    notes = list(report["notes"]) + list(plot_notes or [])
    if notes:
        p.append('<ul id="notes">' + "".join(f"<li>{escape(n)}</li>" for n in notes) + "</ul>")

    p.append('<h2 id="grading">How checks are graded</h2>')
    p.append(GRADING)
    p.append("<p class=\"muted\">Thresholds: " + escape(", ".join(f"{k} = {v}" for k, v in
                                                                  sorted(report["thresholds"].items()))) + "</p>")
    p.append("</body></html>")
    return "\n".join(p) + "\n"
