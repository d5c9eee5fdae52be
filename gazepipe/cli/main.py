"""``gazepipe``: the command line (a thin layer over :mod:`gazepipe.dag`, :mod:`gazepipe.pipeline`, :mod:`gazepipe.io`)."""

from __future__ import annotations

import gc
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click

from gazepipe import __version__
from gazepipe.cli.common import (
    add_debug_option,
    check_destination,
    debug_enabled,
    handle_errors,
    load_sessions,
    parse_params,
    run_options,
)
from gazepipe.cli.param_help import CleanParamOption, fill_params
from gazepipe.cli.validate import DEFAULT_PLOT_TAKES
from gazepipe.errors import ConfigError

if TYPE_CHECKING:
    import numpy as np

    from gazepipe.model import Markers
    from gazepipe.report.run_report import ReportInBackground

EPILOG = """\b
Exit codes: 0 ok; 1 a take failed (the others finished); 2 usage or configuration
error; 3 the QC gate failed; 75 another run holds the output folder's lock.
"""

#: exit codes of the commands that read or write single files
FILE_EPILOG = """\b
Exit codes: 0 ok; 1 a file could not be read or written; 2 usage error.
"""


@click.group(epilog=EPILOG, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="gazepipe")
def cli() -> None:
    """gazepipe turns capture sessions (mocap, head camera, eye tracking, face tracks) into clean,
    synchronised, validated Parquet training sets.

    \b
    Typical use:
      gazepipe run sample_data/session01 --out out/      # everything
      gazepipe status out/                               # what ran, what failed, what is stale
      gazepipe inspect capture.c3d                       # look inside one capture file
    """


def _run(sessions: tuple[str, ...], until: str | None, out: str, force: bool, dry_run: bool, executor: str,
         jobs: int | None, scheduler: str | None, params: tuple[str, ...], params_file: str | None,
         log_format: str, heartbeat: int) -> None:
    from gazepipe.pipeline.executors import check_executor

    check_executor(executor, scheduler)   # before anything else, --dry-run too: a missing extra is exit 2 at once
    from gazepipe.dag import run_pipeline
    from gazepipe.pipeline.events import EventLog
    from gazepipe.pipeline.runner import new_run_id

    debug = debug_enabled()
    loaded = load_sessions(sessions)
    values = parse_params(params, params_file)
    log = EventLog(log_format, run_id=new_run_id(), debug=debug)
    report = _RunReport(Path(out), log) if until is None and not dry_run else None
    summary = run_pipeline(loaded, out, until=until, params=values, executor=executor, jobs=jobs,
                           scheduler=scheduler, force=force, dry_run=dry_run, log=log, heartbeat_every=heartbeat,
                           report=report, preload=_RunReport.WORKER_MODULES if report is not None else ())
    if debug:
        for o in summary.failed:
            if o.traceback:
                click.echo(o.traceback, err=True)
    if not dry_run:
        msg, counts = summary.end_message()
        failed = summary.exit_code != 0
        gate = qc_gate_line(Path(out)) if report is not None else None
        if gate is not None:
            log.emit("warning", "qc_gate", gate, status="would_fail", path=str(Path(out) / "qc" / "report.html"))
        log.emit("error" if failed else "info", "run_end", msg, status="failed" if failed else "ok",
                 skipped=counts["up_to_date"], **counts)
    sys.exit(summary.exit_code)


def qc_gate_line(out: Path, shown: int = 3) -> str | None:
    """The line saying that the QC gate of ``out/qc/report.json`` (``gazepipe validate``'s exit 3) would fail,
    with the first ``shown`` checks that hit it; ``None`` when it passes or there is no readable report."""
    from gazepipe.pipeline.state import read_json

    rep = read_json(out / "qc" / "report.json") or {}
    gate = rep.get("gate") if isinstance(rep, dict) else None
    if not isinstance(gate, dict) or gate.get("passed", True):
        return None
    hit = [h for h in gate.get("hit") or [] if isinstance(h, dict)]
    names = [f"{h.get('id')} ({h.get('target')})" for h in hit[:shown]]
    more = f", {len(hit) - shown} more" if len(hit) > shown else ""
    checks = f"{len(hit)} check{'' if len(hit) == 1 else 's'} at {gate.get('fail_on', 'fail')}"
    listed = f": {', '.join(names)}{more}" if names else ""
    return f"QC gate: would fail ({checks}{listed}); see {out / 'qc' / 'report.html'}"


#: takes plotted in the report that `gazepipe run` writes (the worst first; `validate`'s default too); report.json
#: covers every take
REPORT_PLOT_TAKES = DEFAULT_PLOT_TAKES


class _RunReport:
    """The QC report of a full run, made on the run's workers as it goes
    (:class:`gazepipe.report.run_report.ReportInBackground`) and finished under the run's lock, unless it
    already describes exactly these outputs."""

    #: what the report's jobs run on the workers (matplotlib is most of it): imported once with the stages
    WORKER_MODULES = ("gazepipe.report.run_report", "gazepipe.report.plots", "gazepipe.report.replay_page")

    def __init__(self, out: Path, log) -> None:
        self.out = out
        self.log = log
        self.background: ReportInBackground | None = None

    def _started(self) -> ReportInBackground:
        # the hooks below run only after takes_started made the report
        assert self.background is not None, "takes_started was not called"
        return self.background

    def take_job(self):
        from gazepipe.report.run_report import take_part

        return take_part   # each take's checks, on its worker, as soon as it ran

    def takes_started(self, pool) -> None:
        from gazepipe.report.run_report import ReportInBackground

        # plots for the worst takes only: `gazepipe validate OUT --plot-takes N` draws more
        self.background = ReportInBackground(self.out, plot_takes=REPORT_PLOT_TAKES, pool=pool)

    def take_finished(self, session, take, waiting: int) -> None:
        self._started().take_finished(session, take, waiting)

    def takes_done(self) -> None:
        self._started().start()

    def dataset_built(self, name: str) -> None:
        self._started().dataset_built(name)

    def datasets_done(self) -> None:
        self._started().wait_for_workers()

    def finish(self) -> None:
        from gazepipe.pipeline.state import OutLayout, outputs_fingerprint, read_json

        layout = OutLayout(self.out)
        stamp = layout.state / "report.json"
        current = outputs_fingerprint(layout)
        background, self.background = self.background, None
        if (self.out / "qc" / "report.html").is_file() and (read_json(stamp) or {}).get("outputs") == current:
            if background is not None:
                background.finish_quietly()
            return
        if background is not None:
            res = background.finish()
        else:
            from gazepipe.report.validate import validate_output

            res = validate_output(self.out, plot_takes=REPORT_PLOT_TAKES, lock=False)  # the run holds it
        layout.write_json(stamp, {"outputs": current})
        counts = res.report["summary"]["checks"]
        self.log.emit("info", "qc_report", f"QC report: {res.paths[2]} ("
                      + ", ".join(f"{n} {k}" for k, n in counts.items() if n) + ")", status="ok",
                      path=str(res.paths[2]))


def _stage_examples(name: str) -> str:
    """Usage examples and the --params file format, appended to a stage command's help."""
    return f"""

    \b
    Examples:
      gazepipe {name} sample_data/session01 --out out/
      gazepipe {name} sessions/s01 sessions/s02 --out out/ --executor dask -j 4
      gazepipe {name} sessions/s01 --out out/ --param clean.max_gap_s=0.5 --dry-run
      gazepipe {name} sessions/s01 --out out/ --params studio.toml

    \b
    A --params file has one table per stage (`gazepipe params` lists every name and default):
      [clean]
      max_gap_s = 0.5
      fill_methods = ["rigid", "pca", "pchip"]
      [build]
      train_frac = 0.8
    """


def _stage_command(name: str, until: str | None, summary: str) -> None:
    @cli.command(name, help=summary + _stage_examples(name), epilog=EPILOG)
    @click.argument("sessions", nargs=-1, required=True, type=click.Path(exists=True))
    @run_options
    @handle_errors
    def command(sessions, **kw):
        _run(sessions, until, **kw)


_stage_command("run", None, "Run every stage on every take of SESSIONS (folders or session.toml files), build "
               "the training datasets and write the QC report. Incremental: units whose inputs, parameters and "
               "code are unchanged are skipped. Writes OUT/takes/<session>/<take>/ (every stage's tables), "
               "OUT/datasets/<name>/ and OUT/qc/ (report.json, takes.parquet, report.html).")
_stage_command("ingest", "ingest", "Only read each take's capture files (C3D, Vicon CSV, QTM TSV, wide CSV) into "
               "one canonical table per take, to check that every file reads before a full run. Writes "
               "OUT/takes/<session>/<take>/markers_raw.parquet; nothing is cleaned, no dataset or QC report is "
               "made.")
_stage_command("clean", "frames", "Ingest, then clean each take's markers (label swaps repaired, spikes removed, "
               "gaps filled, stabilised, rests cropped) and compute the segment orientations. Writes "
               "OUT/takes/<session>/<take>/markers_raw, markers, neutral, rest_speed and joints (.parquet); "
               "no sync, eyes, face, dataset or QC report.")
_stage_command("build", "build", "Run every take stage (ingest, clean, frames, sync, eyes, face and each take's "
               "dataset rows), then build the training datasets. Writes OUT/takes/<session>/<take>/ and "
               "OUT/datasets/<name>/ (gaze_rnn, gaze_rnn_lod, gaze_map, face_clean); no QC report "
               "(`gazepipe validate OUT` or `gazepipe run` writes it).")


@cli.command(epilog=FILE_EPILOG)
@click.argument("src", metavar="IN", type=click.Path())
@click.argument("dest", metavar="OUT", type=click.Path(dir_okay=False))
@click.option("--max-gap-s", cls=CleanParamOption, field="max_gap_s", type=click.FloatRange(min=0),
              show_default=True, more="; 0: fill nothing.")
@click.option("--rate-hz", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Rate for CSV files that do not carry one.")
@click.option("--remove-spikes", is_flag=True, help="Turn spikes (ghosts of a frame or two off a marker's path or "
              "its rigid cluster, and accelerations over 50 g) into gaps first, as `gazepipe clean` does (default: "
              "measured samples are kept; spikes are counted).")
@click.option("--repair-swaps", is_flag=True, help="Put samples back under their own names where two markers "
              "carried each other's names (label swaps), proven frame by frame against the file's own marker "
              "geometry, before anything else; unprovable stretches become gaps (files of 20 s or more).")
@click.option("--fill-unlabeled", is_flag=True, help="Also fill unlabeled trajectories (Vicon *12, 'Unlabeled 3', "
              "...; default: left as they are, since a fill between their scattered samples joins different "
              "markers).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON (with every gap).")
@click.option("--force", is_flag=True, help="Overwrite OUT when it exists (default: refuse).")
@handle_errors
def fill(src: str, dest: str, max_gap_s: float, rate_hz: float | None, remove_spikes: bool, repair_swaps: bool,
         fill_unlabeled: bool, as_json: bool, force: bool) -> None:
    """Fill the gaps of one capture file (C3D, Vicon CSV, QTM TSV, wide CSV) with no session or markerset.

    Rigid clusters are found from the data; each gap gets the best of rigid-cluster, PCA, PCHIP and linear
    fill, chosen by hiding known samples next to it. A gap is filled only where that gives its fill an error
    estimate, and no filled step is faster than the fastest step measured in the file. OUT is a copy of IN, in
    its format and with its extension, in which only the filled samples changed; gaps it could not fill stay
    gaps, and the summary says why. A .c3d keeps its analog data,
    events, model outputs and parameters, and a filled sample gets residual 0 (the C3D mark of a sample not
    reconstructed from cameras). A text export (Vicon Nexus CSV, QTM TSV, wide CSV) keeps its header, other
    blocks, columns and line endings; filled cells are written in the file's units with its number of
    decimals. Gaps at the start or end of the file are filled only from other markers (rigid or PCA), never
    extrapolated in time, and are counted apart in the summary.

    \b
      gazepipe fill walk.c3d walk_filled.c3d
      gazepipe fill trial.csv trial_filled.csv --max-gap-s 0.5 --json
      gazepipe fill noisy.c3d noisy_filled.c3d --remove-spikes
      gazepipe fill trial.c3d trial_fixed.c3d --repair-swaps --remove-spikes
      gazepipe fill walk.c3d walk_filled.c3d --force     # write over an earlier walk_filled.c3d
    """
    from gazepipe.io.c3d import write_filled_c3d
    from gazepipe.io.capture import read_markers, sniff_format
    from gazepipe.io.filled_text import write_filled_text
    from gazepipe.io.marker_csv import read_text_export
    from gazepipe.pipeline.atomic import atomic_path
    from gazepipe.stages.clean.standalone import fill_capture

    src_p, dest_p = Path(src), Path(dest)
    want = src_p.suffix.lower()
    if dest_p.suffix.lower() != want:
        raise ConfigError(dest, f"OUT must be a {want or 'extension-less'} file like IN (the filler writes a copy "
                                "of the input in its own format)")
    check_destination(src_p, dest_p, overwrite=force)
    fmt = sniff_format(src_p)
    # a text export is read once, with the layout its copy is written from
    text = None if fmt == "c3d" else read_text_export(src_p, fmt, rate_hz=rate_hz)
    markers = read_markers(src_p, rate_hz=rate_hz) if text is None else text[0]
    # the clean stage's parameters, built as `gazepipe run` builds them
    p = fill_params(max_gap_s=max_gap_s, remove_spikes=remove_spikes, repair_swaps=repair_swaps,
                    fill_unlabeled=fill_unlabeled)
    filled, summary, removed = fill_capture(markers, max_gap_s=p.max_gap_s, methods=p.fill_methods,
                                            spikes=p.remove_spikes, swaps=p.repair_swaps, unlabeled=p.fill_unlabeled)
    with atomic_path(dest_p, dest_p.parent, suffix=want) as tmp:
        if fmt == "c3d":
            res = write_filled_c3d(src_p, tmp, filled, removed=removed, original=markers)
            if res.wide:
                markers.warnings.append(f"{res.wide} filled samples lie beyond the file's 16-bit integer range "
                                        "and are written as gaps (counted as filled below)")
            summary["samples_written_as_gaps"] = res.wide
            unmarked = (f"{res.unmarked_measured} samples the input holds already have a residual or camera byte "
                        "of 0 (the mark of a filled sample), so readers cannot tell the new fills from them") \
                if res.unmarked_measured else None
        else:
            assert text is not None   # read above for every format but C3D
            write_filled_text(src_p, tmp, filled, fmt, removed=removed, original=text)
            n_lineless = _filled_without_a_line(markers, filled, text[1].rows)
            if n_lineless:
                markers.warnings.append(f"{n_lineless} filled samples lie in dropped frames (frame numbers "
                                        "missing from the file): the copy has no line for them, so they are not "
                                        "written (counted as filled below)")
            summary["samples_not_written"] = n_lineless
            unmarked = "a text export has no residuals to mark filled samples with"
    summary["sidecar"] = _fill_sidecar(src_p, dest_p, markers, filled, removed, summary, unmarked)
    summary = {"input": str(src_p), "output": str(dest_p), **summary, "warnings": list(markers.warnings)}
    if as_json:
        click.echo(json.dumps(summary, indent=1))
        return
    for w in markers.warnings:
        click.echo(f"  warning: {w}")
    s, g = summary["samples"], summary["gaps"]
    click.echo(f"{dest_p}: {g['filled']} of {g['total']} gaps filled "
               f"({', '.join(f'{s[k]} {k}' for k in ('rigid', 'pca', 'pchip', 'linear'))} samples); "
               f"{g['unfilled']} gaps ({s['unfilled']} samples) left as gaps")
    if g["edge_filled"]:
        click.echo(f"  {g['edge_filled']} of the filled gaps are at the file's start or end (filled from other "
                   "markers only: check them)")
    if g["filled"]:
        click.echo(f"  every fill has an estimated error (--json lists them) and no filled step is faster than the "
                   f"file's fastest measured one, {summary['fastest_measured_step_mm']:.1f} mm per frame")
    for reason, n in summary["unfilled_by_reason"].items():
        click.echo(f"  left as gaps: {n['gaps']} gap(s), {n['samples']} samples: {reason}")
    unl = summary["unlabeled"]
    if unl["markers"] and not unl["filled"]:
        click.echo(f"  {len(unl['markers'])} unlabeled trajectories left as they are (--fill-unlabeled fills them)")
    sp = summary["spikes"]
    if sp["samples"]:
        what = ("turned into gaps before filling" if sp["removed"]
                else "kept as measured (--remove-spikes turns them into gaps first)")
        click.echo(f"  {sp['samples']} samples of {len(sp['per_marker'])} markers are spikes (off their path or "
                   f"cluster, or implausibly accelerated): {what}")
    sw = summary["swaps"]
    if repair_swaps and not sw["looked_for"]:
        click.echo("  label swaps not looked for: the file is shorter than 20 s (a swap could be most of it)")
    elif sw["looked_for"]:
        click.echo(f"  label swaps: {len(sw['stretches'])} stretch(es); {sw['samples_repaired']} samples put back "
                   f"under their own names, {sw['samples_removed']} made gaps")
    if summary["clusters"]:
        click.echo(f"  rigid clusters found: {len(summary['clusters'])}")


def _fill_sidecar(src: Path, dest: Path, markers: Markers, filled: Markers, removed: np.ndarray,
                  summary: dict, unmarked: str | None) -> str | None:
    """Where the copy's own residuals cannot mark its filled samples (``unmarked`` says why), list them in
    ``OUT.gazepipe.json`` and add a warning; else remove a sidecar an earlier OUT left. Returns its path."""
    from gazepipe import __version__
    from gazepipe.io.export import fill_listing, sidecar_path, write_sidecar
    from gazepipe.pipeline.atomic import atomic_path

    side = sidecar_path(dest)
    listing = fill_listing(markers, filled, removed, summary["gap_list"])
    if unmarked is None or not (listing["filled"] or listing["removed"]):
        side.unlink(missing_ok=True)
        return None
    markers.warnings.append(f"{unmarked}: the filled samples are listed in {side}")
    facts = {"gazepipe_version": __version__, "input": str(src), "file": dest.name, "why": unmarked,
             "frame_numbers": "the file's own; ranges are first and last frame, inclusive", **listing}
    with atomic_path(side, dest.parent, suffix=".json") as tmp:
        write_sidecar(tmp, facts)
    return str(side)


def _filled_without_a_line(markers: Markers, filled: Markers, rows: np.ndarray | None) -> int:
    """Samples ``filled`` fills in rows the reader added for dropped frames (``rows``: each data line's row of
    ``markers``; None when there are none)."""
    import numpy as np

    if rows is None:
        return 0
    lineless = np.ones(markers.n_frames, dtype=bool)
    lineless[np.asarray(rows, dtype=np.int64)] = False
    return int((filled.valid[lineless] & ~markers.valid[lineless]).sum())


@cli.command(epilog=FILE_EPILOG)
@click.argument("file", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of a summary (floats rounded "
              "to what they mean: rates to 6 significant digits, seconds to 1 µs, shares to 1e-6).")
@click.option("--rate-hz", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Rate for CSV files that do not carry one (marker CSVs, Live Link Face).")
@click.option("--timecode-fps", type=click.FloatRange(min=0, min_open=True), default=60.0, show_default=True,
              help="Frames a second a Live Link Face timecode counts.")
@handle_errors
def inspect(file: str, as_json: bool, rate_hz: float | None, timecode_fps: float) -> None:
    """Summarise a capture file: format, rate, frames, first frame, units, markers and their gap share.

    \b
    Also eye and face tracks:
      OpenFace CSV     rows, rate, duration, valid share (success == 1 and confidence >= eyes.min_confidence),
                       blink share (AU45_c == 1, as the eyes stage masks blinks)
      Live Link Face   rows, rate, duration, dropped frames, valid share (some blendshape not zero), blink share
                       (eyeBlinkLeft or eyeBlinkRight > 0.5), head tracking on or off
    """
    from gazepipe.cli.inspect_view import text_lines
    from gazepipe.cli.jsonout import dumps
    from gazepipe.io.inspect_tracks import inspect_file
    from gazepipe.stages.eyes.params import EyesParams

    info = inspect_file(file, rate_hz=rate_hz, timecode_fps=timecode_fps,
                        min_confidence=EyesParams().min_confidence)
    if as_json:
        click.echo(dumps(info))
        return
    for line in text_lines(info):
        click.echo(line)


@cli.command(epilog=FILE_EPILOG)
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table: an object with the lock's "
              "holder, the take units, the datasets and their counts (seconds rounded to 1 µs).")
@click.option("--param", "params", multiple=True, metavar="STAGE.NAME=VALUE",
              help="The parameters the next run would use (as given to `gazepipe run`): units run with others "
              "show as stale.")
@click.option("--params", "params_file", type=click.Path(dir_okay=False), default=None,
              help="TOML file of parameters: one table per stage.")
@handle_errors
def status(out: str, as_json: bool, params: tuple[str, ...], params_file: str | None) -> None:
    """What ran in OUT, what failed, and what is stale (inputs, parameters or code changed since), compared
    with the default parameters or those given; and whether a run holds OUT now (its pid and start time).

    \b
      gazepipe status out/
      gazepipe status out/ --params studio.toml --json
    """
    from gazepipe.cli.jsonout import dumps
    from gazepipe.cli.status_view import status_json, table_lines
    from gazepipe.dag import collect_status
    from gazepipe.pipeline.lock import lock_state
    from gazepipe.pipeline.state import OutLayout
    from gazepipe.report.collect import open_output

    open_output(out)
    holder = lock_state(OutLayout(Path(out)).lock)
    rows = collect_status(Path(out), parse_params(params, params_file))
    if as_json:
        click.echo(dumps(status_json(out, rows, holder)))
        return
    for line in table_lines(rows, holder):
        click.echo(line)


@cli.command("params")
def params_cmd() -> None:
    """List every stage parameter once: what it does, its default and the values it accepts, as TOML that
    `--params` reads (set them with --param STAGE.NAME=VALUE or --params FILE)."""
    import gazepipe.dag
    from gazepipe.cli.param_help import user_help
    from gazepipe.pipeline.registry import allowed_values, default_params, param_rules, show_value

    gazepipe.dag.declare()   # the stages and their parameters

    rules, meanings = param_rules(), user_help()
    # TOML (dotted keys; a parameter that is off by default is shown commented out): a --params file as is;
    # each parameter under a comment saying what it means
    lines = [(k, f"{k} = {show_value(v)}" if v is not None else f"# {k} = (off by default)",
              allowed_values(v, rules.get(k, {}))[1]) for k, v in default_params().items()]
    width = max(len(a) for _, a, _ in lines)
    group = None
    for key, a, b in lines:
        if key.partition(".")[0] != group:
            if group is not None:
                click.echo("")
            group = key.partition(".")[0]
        click.echo(f"# {meanings.get(key, '(not documented)')}")
        click.echo(f"{a:<{width}}  # {b}")


def _register_commands() -> None:
    from gazepipe.cli.export_cmd import export
    from gazepipe.cli.train import train
    from gazepipe.cli.validate import validate
    from gazepipe.cli.view import view

    cli.add_command(export)
    cli.add_command(validate)
    cli.add_command(view)
    cli.add_command(train)
    add_debug_option(cli)
    for command in cli.commands.values():
        add_debug_option(command)


_register_commands()


def _main_json() -> None:
    """The command line when ``--json`` was given: a usage error (a bad option or value, which click reports
    before the command runs) is a JSON line on stderr too (:func:`gazepipe.cli.jsonout.error_line`), with the
    same exit code."""
    from gazepipe.cli.jsonout import error_line

    try:
        code = cli.main(prog_name="gazepipe", standalone_mode=False)
    except click.ClickException as e:
        click.echo(error_line(" ".join(e.format_message().split()), e.exit_code, kind=type(e).__name__), err=True)
        sys.exit(e.exit_code)
    except click.exceptions.Abort:
        click.echo(error_line("aborted", 1, kind="Interrupted"), err=True)
        sys.exit(1)
    sys.exit(code if isinstance(code, int) else 0)


def main() -> None:
    """The ``gazepipe`` command: the BLAS threads capped, then the command line (:func:`_main_json` under
    ``--json``)."""
    from gazepipe.cli.threads import cap_blas_threads

    cap_blas_threads()
    try:
        if "--json" in sys.argv[1:]:
            _main_json()
        else:
            cli(prog_name="gazepipe")
    finally:
        # the process ends here: what it holds goes back to the system whole, instead of the collector walking
        # every object of the libraries it loaded on the way out (a tenth to half a second after a run)
        gc.freeze()


if __name__ == "__main__":
    main()
