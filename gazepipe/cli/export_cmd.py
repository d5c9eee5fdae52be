"""``gazepipe export OUT SESSION/TAKE --to FILE``: a take back to the capture programs (C3D, Vicon Nexus CSV,
QTM TSV, wide CSV), with a sidecar listing what gazepipe filled."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from gazepipe import __version__
from gazepipe.cli.common import check_destination, handle_errors
from gazepipe.errors import ConfigError, GazepipeError, printable

EPILOG = """\b
Exit codes: 0 ok; 1 a file could not be read or written; 2 usage error (no such
take, a face take, a destination that cannot be written).
"""

#: the formats (:data:`gazepipe.io.export.FORMATS`, not imported here: `gazepipe --help` stays quick)
FORMAT_NAMES = ("c3d", "nexus", "qtm", "wide")


def resolve_take(out: Path, take: str, session: str | None) -> tuple[str, str, Path]:
    """``(session, take, its folder)`` for TAKE (``SESSION/TAKE``, or a take id with ``session`` or alone in one
    session); ids are checked (letters, digits, ``_``, ``-``) before any path is made from them."""
    from gazepipe.io.toml_common import WORD

    if "/" in take:
        given, _, take = take.partition("/")
        if session is not None and session != given:
            raise ConfigError(None, f"--session {session!r} and {given}/{take}: name the session once")
        session = given
    for what, value in (("take", take), ("session", session)):
        if value is not None and not WORD.fullmatch(value):
            raise ConfigError(None, f"{printable(value)!r} is not a {what} id (letters, digits, '_' and '-')")
    base = out / "takes"
    if session is None:
        found = sorted(p.parent.name for p in base.glob(f"*/{take}") if WORD.fullmatch(p.parent.name))
        if not found:
            raise ConfigError(out, f"no take {take!r} in this output folder (`gazepipe status {out}` lists them)")
        if len(found) > 1:
            raise ConfigError(out, f"take {take!r} is in several sessions ({', '.join(found)}): name it as "
                                   f"SESSION/TAKE, e.g. {found[0]}/{take}")
        session = found[0]
    folder = base / session / take
    if not folder.is_dir():
        raise ConfigError(out, f"no take {session}/{take} in this output folder (`gazepipe status {out}` lists "
                               "them)")
    if not (folder / "markers_raw.parquet").is_file() and (folder / "face.parquet").is_file():
        raise ConfigError(out, f"take {take!r} is a face take: it has blendshape tracks (face.parquet), no markers")
    return session, take, folder


def _clean_params(out: Path, session: str, take: str) -> dict[str, Any]:
    """The parameters the take's clean unit ran with (its record's), or none."""
    from gazepipe.pipeline.state import OutLayout, read_json

    rec = read_json(OutLayout(out).record(session, take, "clean")) or {}
    params = ((rec.get("components") or {}).get("params") if isinstance(rec, dict) else None) or {}
    return params if isinstance(params, dict) else {}


def _source(out: Path, session: str, take: str, renamed: dict[str, str]):
    """The take's capture file read again (:func:`gazepipe.io.export.read_source`), or ``(None, why not)``."""
    from gazepipe.io.export import read_source
    from gazepipe.io.session_toml import load_session
    from gazepipe.pipeline.state import OutLayout, read_json

    paths = read_json(OutLayout(out).sessions) or {}
    toml = paths.get(session) if isinstance(paths, dict) else None
    if not isinstance(toml, str):
        return None, "the session's session.toml is not known to this output folder"
    try:
        s = load_session(toml)
        entry = next((t for t in s.takes if t.id == take), None)
        if entry is None or entry.mocap is None:
            return None, f"{toml} no longer lists the take's capture"
        ms = s.markerset
        return read_source(entry.mocap, rate_hz=entry.rate_hz, default_units=ms.units if ms else "mm",
                           renamed=renamed), None
    except GazepipeError as exc:
        return None, exc.one_line()


@click.command("export", epilog=EPILOG)
@click.argument("out", type=click.Path(exists=True, file_okay=False))
@click.argument("take", metavar="SESSION/TAKE")
@click.option("--session", default=None, help="Session id, for a TAKE given without one that several sessions "
              "have.")
@click.option("--to", "dest", required=True, type=click.Path(dir_okay=False),
              help="File to write: .c3d, .csv or .tsv (the format from the extension, or --format).")
@click.option("--format", "fmt", type=click.Choice(FORMAT_NAMES), default=None,
              help="c3d; nexus (a Vicon Nexus 'Trajectories' CSV, .csv); qtm (a Qualisys QTM 3D TSV, .tsv); wide "
              "(frame, time, <marker>_x/_y/_z, .csv). Default: from the extension (.csv: wide).")
@click.option("--frame", type=click.Choice(["lab", "stabilised"]), default="lab", show_default=True,
              help="lab: the capture's own axes and origin, as the capture programs show it; stabilised: the "
              "cleaned markers' frame, the root marker at the origin in every frame.")
@click.option("--table", type=click.Choice(["markers", "markers_raw"]), default="markers", show_default=True,
              help="markers: the cleaned take (filled samples marked); markers_raw: the capture as ingested.")
@handle_errors
def export(out: str, take: str, session: str | None, dest: str, fmt: str | None, frame: str, table: str) -> None:
    """Write a take of OUT back to the capture programs (Vicon Nexus, Shogun, QTM, MotionBuilder, Mokka) or a
    spreadsheet: the whole take, every frame of its capture, in the lab frame.

    Measured samples are the capture's own values (read again from the capture file when it is unchanged) and
    in a C3D keep their residuals and camera masks (a stand-in of one residual step where the capture wrote 0);
    filled samples are the cleaned take's, put back in the lab frame, at residual 0 in a C3D (C3D's mark of a
    sample not reconstructed from cameras). The crop (the frames gazepipe keeps) is in the C3D's EVENT group
    and GAZEPIPE:CROP, and in a QTM TSV's EVENT lines. Beside FILE, FILE.gazepipe.json lists the crop, every
    filled sample (marker, frames, method) and every sample the cleaning took out.

    \b
      gazepipe export out/ session01/follow_standing_01 --to take.c3d
      gazepipe export out/ follow_standing_01 --to take.csv --format nexus
      gazepipe export out/ session01/follow_standing_01 --to take.tsv
      gazepipe export out/ session01/neutral --to neutral.c3d --frame stabilised
    """
    from gazepipe.io.export import TakeTables, export_format, export_take, load_take_tables, sidecar_path
    from gazepipe.pipeline.atomic import atomic_path

    out_p, dest_p = Path(out), Path(dest)
    chosen = export_format(dest_p, fmt)
    if table == "markers_raw" and frame != "lab":
        raise ConfigError(None, "--table markers_raw is the capture as ingested: it has no stabilised frame")
    check_destination(None, dest_p)
    sid, tid, folder = resolve_take(out_p, take, session)
    tables = load_take_tables(folder, cleaned=table == "markers")
    if table == "markers_raw":
        tables = TakeTables(tables.raw, crop=tables.crop, renamed=tables.renamed)
    source, why = _source(out_p, sid, tid, tables.renamed)
    heading = bool(_clean_params(out_p, sid, tid).get("remove_heading", False))
    side = sidecar_path(dest_p)
    with atomic_path(dest_p, dest_p.parent, suffix=dest_p.suffix) as tmp, \
            atomic_path(side, dest_p.parent, suffix=".json") as tmp_side:
        res = export_take(tables, tmp, take=f"{sid}/{tid}", fmt=chosen, frame=frame, source=source,
                          heading=heading, sidecar=tmp_side, name=dest_p.name,
                          version=__version__)
    c = res.counts
    crop = f"; crop frames {res.crop[0]}-{res.crop[1]} in its events" if res.crop and chosen in ("c3d", "qtm") \
        else (f"; crop frames {res.crop[0]}-{res.crop[1]}" if res.crop else "")
    click.echo(f"wrote {dest_p} ({chosen}, {c['frames']} frames, {frame} frame: {c['measured']:,} measured, "
               f"{c['filled']:,} filled, {c['gaps']:,} gaps{crop}) and {side}")
    if why is not None:
        click.echo(f"  note: capture file not read again ({why}): measured samples are the markers_raw table's "
                   "(float32), residuals stand-ins")
    for note in res.notes:
        click.echo(f"  note: {note}")
