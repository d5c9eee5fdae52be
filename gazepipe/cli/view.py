"""``gazepipe view OUT SESSION/TAKE``: a take's 3D replay page, for any take of an output folder."""

from __future__ import annotations

from pathlib import Path

import click

from gazepipe.cli.common import handle_errors

EPILOG = """\b
Exit codes: 0 the page was written; 1 it could not be written (a file system
error); 2 OUT is not a gazepipe output folder, no take is called that, or the
take has nothing to replay (a face take, its ingest or clean failed).
"""


def _find_take(layout, name: str):
    """The take entry ``name`` (SESSION/TAKE, or TAKE when one session has it) names, and its session; a
    :class:`ConfigError` naming the nearest takes otherwise."""
    import difflib

    from gazepipe.errors import ConfigError
    from gazepipe.report.collect import load_sessions, take_entries

    sessions, _ = load_sessions(layout)
    entries = take_entries(layout, sessions)
    if not entries:
        raise ConfigError(layout.root, "holds no take yet (`gazepipe run SESSION --out OUT` makes them)")
    by_key = {e.key: e for e in entries}
    if name in by_key:
        return by_key[name], sessions.get(by_key[name].session)
    same = [e for e in entries if e.take == name]
    if len(same) == 1:
        return same[0], sessions.get(same[0].session)
    if same:
        raise ConfigError(None, f"take {name!r} is in several sessions ({', '.join(e.session for e in same)}): "
                          f"name it as SESSION/TAKE, e.g. {same[0].key}")
    near = difflib.get_close_matches(name, list(by_key), n=3, cutoff=0.5)
    ids = difflib.get_close_matches(name.rpartition("/")[2], sorted({e.take for e in entries}), n=3, cutoff=0.5)
    near += [e.key for t in ids for e in entries if e.take == t and e.key not in near]
    near = near[:3]
    hint = f"; nearest: {', '.join(near)}" if near else f" (it has {len(entries)}, e.g. {entries[0].key})"
    raise ConfigError(layout.root, f"no take {name!r} here{hint} (`gazepipe status {layout.root}` lists them)")


@click.command("view", epilog=EPILOG)
@click.argument("out", type=click.Path(file_okay=False))
@click.argument("take", metavar="SESSION/TAKE")
@click.option("--open", "open_page", is_flag=True, help="Open the page in your web browser once written.")
@click.option("--to", "dest", type=click.Path(dir_okay=False), default=None, metavar="FILE.html",
              help="Write the page here instead, as one file that stands alone (Plotly inside it, about 5 MB "
              "more), to keep or send.")
@handle_errors
def view(out: str, take: str, open_page: bool, dest: str | None) -> None:
    """Write the 3D replay of one take of OUT and print the page's path.

    The page shows the take's markers in 3D, joined by the sticks of their segments (markerset), the cleaned
    markers over the raw capture, each sample coloured by how it was made (measured, each fill method,
    unfilled, removed spike, repaired label swap), and the line from the eyes to the gaze target; a time slider
    with the crop marked, play and pause, and buttons that jump to the take's worst moments (the largest
    estimated fill errors, filled segment rotations, label swaps, frames that give no dataset row and why).
    It is the page the QC report links for the takes it draws, made here for any take.

    By default it goes to OUT/qc/view/SESSION/TAKE.html and loads Plotly from OUT/qc/plotly.min.js (written
    beside the report if missing): no network needed, and the qc/ folder still works when copied. The report
    never deletes these pages; running the command again rewrites one.

    \b
      gazepipe view out/ session01/follow_standing_01 --open
      gazepipe view out/ shift_y036_p12                 # a take id alone, when one session has it
      gazepipe view out/ session01/neutral --to neutral_replay.html
    """
    from gazepipe.errors import ConfigError
    from gazepipe.pipeline.atomic import atomic_path
    from gazepipe.report.collect import open_output
    from gazepipe.report.replay import ReplayUnavailable, load_replay_inputs
    from gazepipe.report.replay_page import (
        RELATIVE_PLOTLY,
        VIEW_DIR,
        page_path,
        plotly_js,
        replay_html,
        write_plotly_js,
    )

    layout = open_output(out)
    if dest is not None and Path(dest).suffix.lower() not in (".html", ".htm"):
        raise ConfigError(dest, "--to names the page to write: a .html file")
    entry, session = _find_take(layout, take)
    try:
        inputs = load_replay_inputs(layout, entry, session.markerset if session is not None else None)
    except ReplayUnavailable as exc:
        raise ConfigError(None, f"nothing to replay: {exc}") from None
    qc = layout.root / "qc"
    if dest is None:
        page, rep = replay_html(inputs, RELATIVE_PLOTLY)
        path = page_path(qc, VIEW_DIR, entry.session, entry.take)
        write_plotly_js(qc, layout.tmp)
        layout.write_bytes(path, page.encode("utf-8"))
    else:
        page, rep = replay_html(inputs, "inline:" + plotly_js().decode("utf-8"))
        path = Path(dest)
        with atomic_path(path, path.resolve().parent, suffix=".html") as tmp:
            tmp.write_bytes(page.encode("utf-8"))
    moments = f"; worst moments at frames {', '.join(str(m.frame) for m in rep.moments)}" if rep.moments else ""
    click.echo(f"{entry.key}: {len(rep.frames)} of {inputs.raw.n_frames} frames{moments}", err=True)
    click.echo(str(path))
    if open_page:
        click.launch(str(path))
