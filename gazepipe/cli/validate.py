"""``gazepipe validate OUT``: QC checks on an output folder, the report files, and the QC gate (exit 3)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from gazepipe.cli.common import handle_errors

#: `gazepipe validate`'s default --plot-takes (gazepipe.report.validate.DEFAULT_PLOT_TAKES, not imported here:
#: `gazepipe --help` stays quick)
DEFAULT_PLOT_TAKES = 6

EPILOG = """\b
Exit codes: 0 the gate passed; 2 OUT is not a gazepipe output folder or an option is
wrong; 3 the QC gate failed (a check at or above --fail-on); 75 a run holds OUT's lock.
"""


#: failing checks printed one per line before the rest are only counted
_MAX_LISTED = 25


class _TakeCount(click.ParamType):
    """A number of takes (0 or more) or ``all`` (→ ``None``)."""

    name = "N|all"

    def convert(self, value, param, ctx):
        if value is None or isinstance(value, int):
            return value
        text = str(value).strip().lower()
        if text == "all":
            return None
        try:
            n = int(text)
        except ValueError:
            self.fail(f"{value!r} is not a number of takes or 'all'", param, ctx)
        if n < 0:
            self.fail(f"{value!r}: a number of takes is 0 or more", param, ctx)
        return n


def _thresholds(pairs: tuple[str, ...]):
    import dataclasses
    import tomllib

    from gazepipe.errors import ConfigError
    from gazepipe.report.checks import Thresholds

    fields = {f.name: f for f in dataclasses.fields(Thresholds)}
    values: dict[str, Any] = {}   # each threshold's own type (a number, or None for off)
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        key = key.strip()
        if not sep or key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(None, f"--threshold {pair}: expected NAME=VALUE with NAME one of {known}")
        if raw.strip().lower() in ("none", "off"):
            values[key] = None
            continue
        try:
            v = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            raise ConfigError(None, f"--threshold {pair}: {raw!r} is not a number") from None
        if not isinstance(v, int | float) or isinstance(v, bool):
            raise ConfigError(None, f"--threshold {pair}: {raw!r} is not a number")
        values[key] = v
    return Thresholds(**values)


@click.command("validate", epilog=EPILOG)
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--fail-on", type=click.Choice(["warning", "fail"]), default="fail", show_default=True,
              help="Exit 3 when a check is at this severity or worse (error counts as fail).")
@click.option("--threshold", "thresholds", multiple=True, metavar="NAME=VALUE",
              help="Override a check threshold, e.g. --threshold unfilled_warn=0.1 (repeatable; 'none' disables).")
@click.option("--plot-takes", type=_TakeCount(), metavar="N|all", default=DEFAULT_PLOT_TAKES, show_default=True,
              help="Draw the plots of the N worst takes (failed first, then most failing checks, most warnings, "
              "check nearest its threshold; face takes and others with nothing to draw are passed over), or of "
              "every take with 'all' (a tenth of a second or more a take). Every take is checked whatever N.")
@click.option("--plot-take", "plot_named", multiple=True, metavar="SESSION/TAKE",
              help="Also draw this take's plots: SESSION/TAKE, a take id (in any session) or a pattern such as "
              "'shift_*' (repeatable; --plot-takes 0 --plot-take X draws only X).")
@click.option("--no-plots", is_flag=True, help="Draw no plot or replay, datasets' included (the fastest page), and "
              "delete none: the plots and replays drawn before of unchanged outputs stay in the page (report.json "
              "and takes.parquet are the same with or without plots).")
@click.option("--json", "as_json", is_flag=True, help="Print the gate and the failing checks as JSON.")
@handle_errors
def validate(out: str, fail_on: str, thresholds: tuple[str, ...], plot_takes: int | None,
             plot_named: tuple[str, ...], no_plots: bool, as_json: bool) -> None:
    """Check every take and dataset in OUT and write OUT/qc/report.json, OUT/qc/takes.parquet and
    OUT/qc/report.html (no network needed), with a 3D replay page per take drawn (OUT/qc/replay/).

    \b
    Checks per take: failed or out-of-date stages, gap and fill shares, longest gap, fill
    validation error, unfilled samples, spikes, crop bounds, invalid frames, clap
    offset/drift/confidence, frames without video, eye gating, camera-rotation residual,
    face-track matching. Per dataset: build, schema hash, split disjointness, counts per
    pose and split, statistics sanity. Severities: pass, warning, fail, error (the check
    could not be evaluated), skipped (not applicable). Thresholds: see report.json.

    \b
    Plots: every dataset's, and those of the 6 worst takes with their 3D replays
    (--plot-takes N|all and --plot-take SESSION/TAKE ask for others; the page says which
    takes it plotted; `gazepipe view OUT SESSION/TAKE` makes the replay of any take).

    \b
      gazepipe validate out/
      gazepipe validate out/ --fail-on warning --threshold unfilled_warn=0.1
      gazepipe validate out/ --plot-takes all
      gazepipe validate out/ --plot-take session01/follow_sitting_01 --plot-take 'shift_*'
    """
    import json

    from gazepipe.report.validate import validate_output

    if no_plots and plot_named:
        raise click.UsageError("--no-plots leaves every plot out: it cannot go with --plot-take")
    res = validate_output(Path(out), _thresholds(thresholds), fail_on, plots_on=not no_plots, plot_takes=plot_takes,
                          plot_named=plot_named)
    rep = res.report
    if as_json:
        click.echo(json.dumps({"gate": rep["gate"], "summary": rep["summary"],
                               "files": [str(p) for p in res.paths]}, indent=1))
    else:
        s = rep["summary"]
        counts = ", ".join(f"{n} {k}" for k, n in s["checks"].items() if n)
        click.echo(f"{s['takes']} take(s), {s['datasets']} dataset(s): {counts}")
        # the checks that fail the gate are listed (warnings too with --fail-on warning), the rest counted
        shown = ("fail", "error", "warning") if fail_on == "warning" else ("fail", "error")
        listed = [r for r in s["failing"] if r["severity"] in shown]
        for r in listed[:_MAX_LISTED]:
            click.echo(f"  {r['severity']:<7} {r['target']}: {r['id']}: {r['message']}")
        if len(listed) > _MAX_LISTED:
            click.echo(f"  … and {len(listed) - _MAX_LISTED} more (all in {res.paths[0]}, or --json)")
        warn = sum(r["severity"] == "warning" for r in s["failing"])
        if warn and "warning" not in shown:
            click.echo(f"  {warn} warning(s): see {res.paths[2]}")
        click.echo(f"wrote {res.paths[0]}, {res.paths[1].name}, {res.paths[2].name}")
        if not no_plots and plot_takes is not None and len(res.plotted) < s["takes"]:
            click.echo(f"  plots of the {len(res.plotted)} worst of {s['takes']} take(s) (--plot-takes all, or "
                       "--plot-take SESSION/TAKE, for the others)")
        click.echo(f"QC gate (--fail-on {fail_on}): " + ("passed" if res.passed else
                                                         f"FAILED ({len(rep['gate']['hit'])} check(s))"))
    if not res.passed:
        sys.exit(3)
