"""Shared command-line plumbing: error handling, session loading, parameters, logging options."""

from __future__ import annotations

import functools
import sys
import tomllib
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from gazepipe.errors import ConfigError, GazepipeError


def fail(message: str, code: int) -> None:
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


def handle_errors(fn: Callable) -> Callable:
    """Turn every failure into one line on stderr and an exit code; the traceback only with ``--debug``."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        debug = bool(click.get_current_context().find_root().params.get("debug"))
        try:
            return fn(*args, **kwargs)
        except GazepipeError as exc:
            if debug:
                traceback.print_exc()
            fail(exc.one_line(), exc.exit_code)
        except KeyboardInterrupt:
            fail("interrupted", 130)
        except BrokenPipeError:  # output piped into `head` and the like
            sys.stderr.close()
            sys.exit(0)
        except (click.exceptions.Exit, click.ClickException, SystemExit):
            raise
        except Exception as exc:
            if debug:
                traceback.print_exc()
            fail(f"internal error: {type(exc).__name__}: {' '.join(str(exc).split())} "
                 "(run with --debug for the traceback)", 1)

    return wrapper


def load_sessions(paths: tuple[str, ...]):
    """Load and validate every session; print every configuration problem, then exit 2 if there was one."""
    from gazepipe.io.session_toml import load_session, validate_session

    problems: list[ConfigError] = []
    sessions = []
    for p in paths:
        errs = validate_session(p)
        if errs:
            problems.extend(errs)
            continue
        sessions.append(load_session(p))
    if problems:
        for e in problems[:-1]:
            click.echo(f"error: {e.one_line()}", err=True)
        raise problems[-1]
    ids = [s.id for s in sessions]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise ConfigError(None, f"two sessions share the id {dup[0]}: give one a different [session] id")
    return sessions


def parse_params(pairs: tuple[str, ...], params_file: str | None) -> dict[str, Any]:
    """``--param stage.name=value`` (TOML values: 0.5, true, "text") and ``--params FILE.toml`` merged,
    checked against the parameters the stages declare."""
    from gazepipe.pipeline.registry import default_params

    known = default_params()
    values: dict[str, Any] = {}
    if params_file:
        try:
            data = tomllib.loads(Path(params_file).read_text())
        except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(params_file, f"cannot read parameters ({' '.join(str(exc).split())})") from None
        for stage, table in data.items():
            if not isinstance(table, dict):
                raise ConfigError(params_file, "expected one table per stage, e.g. [clean] max_gap_s = 0.5",
                                  key=stage)
            for k, v in table.items():
                values[f"{stage}.{k}"] = v
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        if not sep:
            raise ConfigError(None, f"--param {pair}: expected STAGE.NAME=VALUE")
        try:
            values[key.strip()] = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            values[key.strip()] = raw.strip()
    for key, v in values.items():
        if key not in known:
            close = [k for k in known if k.split(".")[-1] == key.split(".")[-1]]
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise ConfigError(params_file, f"unknown parameter {key}{hint}; `gazepipe params` lists them")
        default = known[key]
        if isinstance(default, bool) != isinstance(v, bool) or (
                isinstance(default, int | float) and not isinstance(v, int | float)):
            if default is not None:
                raise ConfigError(params_file, f"parameter {key} must be like {default!r}, got {v!r}")
        if isinstance(default, float) and isinstance(v, int) and not isinstance(v, bool):
            values[key] = float(v)
    return values


def run_options(fn: Callable) -> Callable:
    """Options shared by every command that runs stages."""
    opts = [
        click.option("--out", "-o", required=True, type=click.Path(file_okay=False),
                     help="Output folder (created if absent)."),
        click.option("--force", is_flag=True, help="Re-run every unit even when it is up to date."),
        click.option("--dry-run", is_flag=True, help="Say which units would run and why; change nothing."),
        click.option("--executor", type=click.Choice(["serial", "process", "dask"]), default="process",
                     show_default=True, help="Where takes run: this process, local worker processes, or Dask."),
        click.option("--jobs", "-j", type=click.IntRange(1, 512), default=None,
                     help="Worker processes (default: the number of cores)."),
        click.option("--scheduler", default=None, metavar="ADDRESS",
                     help="Join an existing Dask scheduler (implies --executor dask)."),
        click.option("--param", "params", multiple=True, metavar="STAGE.NAME=VALUE",
                     help="Override a stage parameter, e.g. --param clean.max_gap_s=0.5 (repeatable)."),
        click.option("--params", "params_file", type=click.Path(dir_okay=False), default=None,
                     help="TOML file of parameters: one table per stage."),
        click.option("--log-format", type=click.Choice(["auto", "text", "json"]), default="auto",
                     show_default=True, help="Text on a terminal, JSON lines otherwise (auto)."),
        click.option("--heartbeat", type=click.IntRange(0), default=10, show_default=True,
                     help="Log a progress line every N takes (0: never)."),
    ]
    for opt in reversed(opts):
        fn = opt(fn)
    return fn
