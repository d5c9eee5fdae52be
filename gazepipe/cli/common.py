"""Shared command-line plumbing: error handling, session loading, parameters, logging options."""

from __future__ import annotations

import difflib
import functools
import sys
import tomllib
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import click

from gazepipe.errors import ConfigError, GazepipeError, printable

#: where ``--debug`` is kept: the context's ``meta``, shared by a command and the group above it
_DEBUG_KEY = "gazepipe.debug"
DEBUG_HELP = "Show tracebacks for errors (accepted before or after the command)."


def _remember_debug(ctx: click.Context, param: click.Parameter, value: bool) -> bool:
    if value:
        ctx.meta[_DEBUG_KEY] = True
    return value


def debug_option() -> click.Option:
    """The one ``--debug`` option: the group has it and so does every command (:func:`add_debug_option`), so it
    may come before or after the command's name; either sets :func:`debug_enabled`."""
    return click.Option(["--debug"], is_flag=True, expose_value=False, is_eager=True, callback=_remember_debug,
                        help=DEBUG_HELP)


def add_debug_option(command: click.Command) -> None:
    """Give ``command`` the shared ``--debug`` option (once)."""
    if not any(p.name == "debug" for p in command.params):
        command.params.append(debug_option())


def debug_enabled() -> bool:
    """Whether ``--debug`` was given, before or after the command."""
    ctx = click.get_current_context(silent=True)
    return bool(ctx is not None and ctx.meta.get(_DEBUG_KEY))


def json_errors() -> bool:
    """Whether the running command was given ``--json``: its errors are then a JSON line
    (:func:`gazepipe.cli.jsonout.error_line`)."""
    ctx = click.get_current_context(silent=True)
    return bool(ctx is not None and ctx.params.get("as_json"))


def fail(message: str, code: int, *, kind: str = "Error", error: GazepipeError | None = None) -> None:
    """Print ``message`` as the one error line (a JSON object under ``--json``) and exit with ``code``."""
    if json_errors():
        from gazepipe.cli.jsonout import error_line

        others = tuple(e.one_line() for e in getattr(error, "earlier", ()))
        click.echo(error_line(message, code, kind=kind, file=getattr(error, "path", None),
                              key=getattr(error, "key", None), take=getattr(error, "take", None),
                              others=others), err=True)
    else:
        click.echo(f"error: {printable(message)}", err=True)
    sys.exit(code)


def handle_errors(fn: Callable) -> Callable:
    """Turn every failure into one line on stderr (a JSON object under ``--json``) and an exit code; the
    traceback only with ``--debug``."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        debug = debug_enabled()
        try:
            return fn(*args, **kwargs)
        except GazepipeError as exc:
            if debug:
                traceback.print_exc()
            fail(exc.one_line(), exc.exit_code, kind=type(exc).__name__, error=exc)
        except KeyboardInterrupt:
            fail("interrupted (what finished is kept; the same command resumes)", 130, kind="Interrupted")
        except BrokenPipeError:  # output piped into `head` and the like
            sys.stderr.close()
            sys.exit(0)
        except (click.exceptions.Exit, click.ClickException, SystemExit):
            raise
        except OSError as exc:  # the file system refused (permissions, a full disk, a file where a folder goes)
            if debug:
                traceback.print_exc()
            where = f"{exc.filename}: " if exc.filename else ""
            fail(f"{where}{exc.strerror or type(exc).__name__}", 1, kind="OSError")
        except Exception as exc:
            if debug:
                traceback.print_exc()
            hint = "" if debug else " (run with --debug for the traceback)"
            fail(f"internal error: {type(exc).__name__}: {' '.join(str(exc).split())}{hint}", 1,
                 kind="InternalError")

    return wrapper


def raise_all(problems: Sequence[GazepipeError]) -> None:
    """Print every problem but the last as an ``error:`` line, then raise the last (nothing when none); under
    ``--json`` the last carries the others (``earlier``), for the one JSON line to list them all."""
    if problems:
        if json_errors():
            problems[-1].earlier = tuple(problems[:-1])  # type: ignore[attr-defined]
            raise problems[-1]
        for e in problems[:-1]:
            click.echo(f"error: {printable(e.one_line())}", err=True)
        raise problems[-1]


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
    raise_all(problems)
    by_id: dict[str, list[str]] = {}
    for s in sessions:
        by_id.setdefault(s.id, []).append(s.path)
    for sid, tomls in sorted(by_id.items()):
        if len(tomls) > 1 and tomls[0] == tomls[1]:
            raise ConfigError(tomls[0], "this session is given twice")
        if len(tomls) > 1:
            raise ConfigError(tomls[1], f"session id {sid!r} is also the id of {tomls[0]}: a take is (session, take), "
                                        "so give each capture day its own [session] id", key="session.id")
    return sessions


def _unknown_name(key: str, known: dict[str, Any]) -> str:
    """The problem of an unknown parameter name, with the closest known name when there is one."""
    stage, _, name = key.partition(".")
    same_stage = [k.partition(".")[2] for k in known if k.partition(".")[0] == stage]
    # of a known stage: the very name under another stage first (frames.max_gap_s is clean's), then a near name
    # in the same stage; of an unknown stage (eye.min_confidence), the nearest whole name
    elsewhere = [k for k in known if k.partition(".")[2] == name] if same_stage else []
    close = elsewhere or [f"{stage}.{n}" for n in difflib.get_close_matches(name, same_stage, n=1, cutoff=0.6)]
    close = close or difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
    close = close or [k for k in known if k.partition(".")[2] == name]
    hint = f" (did you mean {close[0]}?)" if close else ""
    return f"unknown parameter {key}{hint}; `gazepipe params` lists them"


def parse_params(pairs: tuple[str, ...], params_file: str | None) -> dict[str, Any]:
    """``--param stage.name=value`` (TOML values: 0.5, true, "text") and ``--params FILE.toml`` merged,
    checked against the parameters the stages declare: their names, kinds and allowed values.

    Every problem is printed, one line each, before the last is raised (:class:`ConfigError`, exit 2).
    """
    import gazepipe.dag
    from gazepipe.pipeline.registry import allowed_values, default_params, param_problems, param_rules

    gazepipe.dag.declare()   # the stages and their parameters

    known = default_params()
    stage_names = list(dict.fromkeys(k.partition(".")[0] for k in known))
    problems: list[ConfigError] = []
    values: dict[str, Any] = {}
    source: dict[str, str | None] = {}      # the file a value came from (None: the command line)
    if params_file:
        from gazepipe.io.toml_common import Collector, read_toml

        col = Collector(Path(params_file))
        data = read_toml(Path(params_file), col)   # bounded in size and depth, as session.toml is
        if data is None:
            raise col.errors[0]
        for stage, table in data.items():
            if not isinstance(table, dict):
                problems.append(ConfigError(params_file, "expected one table per stage, e.g. [clean] "
                                                         "max_gap_s = 0.5", key=stage))
                continue
            if stage not in stage_names:
                close = difflib.get_close_matches(stage, stage_names, n=1, cutoff=0.6)
                hint = f" (did you mean [{close[0]}]?)" if close else ""
                problems.append(ConfigError(params_file, f"unknown table [{stage}]{hint}; the stages with "
                                                         f"parameters are {', '.join(stage_names)}"))
                continue
            for k, v in table.items():
                values[f"{stage}.{k}"] = v
                source[f"{stage}.{k}"] = params_file
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        if not sep:
            problems.append(ConfigError(None, f"--param {pair}: expected STAGE.NAME=VALUE"))
            continue
        key = key.strip()
        try:
            values[key] = tomllib.loads(f"v = {raw.strip()}")["v"]
        except (tomllib.TOMLDecodeError, RecursionError):  # not a TOML value: the text itself
            values[key] = raw.strip()
        source[key] = None
    for key in values:
        if key not in known:
            problems.append(ConfigError(source[key], _unknown_name(key, known)))
    checked = {k: v for k, v in values.items() if k in known}
    problems.extend(ConfigError(source[key], problem) for key, problem in param_problems(checked))
    raise_all(problems)
    rules = param_rules()
    for key, v in values.items():   # 1 and 1.0 are the same number: the same fingerprint
        number = allowed_values(known[key], rules[key])[0] == "float"
        if number and isinstance(v, int) and not isinstance(v, bool):
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
                     show_default=True, help="Where takes run: this process, local worker processes, or Dask (the gazepipe[dask] "
                     "extra)."),
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


def check_destination(src: Path | None, dest: Path, overwrite: bool = True) -> None:
    """Refuse to write over the input, over an existing file unless ``overwrite``, or into a folder that does
    not exist (ConfigError, exit 2)."""
    if src is not None and dest.exists() and src.exists() and dest.resolve() == src.resolve():
        raise ConfigError(dest, "OUT is the input file: write the filled capture to another file")
    if dest.is_dir():
        raise ConfigError(dest, "OUT is a folder: give a file name")
    if not overwrite and (dest.exists() or dest.is_symlink()):
        raise ConfigError(dest, "OUT exists: give --force to overwrite it, or another file name")
    parent = dest.parent
    if not parent.is_dir():
        what = "is not a folder" if parent.exists() else "does not exist: create it first"
        raise ConfigError(dest, f"{parent} {what}")
