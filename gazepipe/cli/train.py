"""``gazepipe train NAME --data DATASET_DIR --out MODEL_DIR``: run a trainer plugin on a built dataset."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import click

from gazepipe.cli.common import handle_errors
from gazepipe.cli.threads import capped
from gazepipe.errors import ConfigError

EPILOG = """\b
Trainers: gaze_map (numpy/scipy), gaze_rnn and face_clean (need gazepipe[torch]),
plus any installed under the "gazepipe.trainers" entry-point group.
Progress (torch trainers): per epoch the training loss, the validation loss and the
seconds, on stderr: a bar on a terminal, JSON lines otherwise (--log-format).
Exit codes: 0 ok; 1 the data could not be read or training failed; 2 usage error,
unknown trainer, a dataset the trainer cannot use, a bad --option, --device cuda
without a GPU, or an --out folder that is not empty without --force.
"""


#: the largest whole number the knobs take (a C int, as the trainers' ``--option``s:
#: :data:`gazepipe.trainers.base.INT_MAX`, not imported here: `gazepipe --help` stays quick)
INT_MAX = 2**31 - 1
#: the largest seed (numpy and torch take 64-bit seeds)
SEED_MAX = 2**63 - 1


class _TrainCommand(click.Command):
    """``gazepipe train``, whose help ends with every trainer's ``--option``s (read from their declarations
    when the help is shown)."""

    def format_epilog(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        super().format_epilog(ctx, formatter)
        from gazepipe.errors import GazepipeError
        from gazepipe.trainers.base import available, load_trainer, option_lines

        for name in available():
            try:
                lines = option_lines(load_trainer(name)) or ["(none)"]
            except (GazepipeError, ImportError, AttributeError) as exc:
                lines = [f"(cannot be loaded: {exc})"]
            formatter.write_paragraph()
            formatter.write_text(f"--option for {name}:")
            with formatter.indentation():
                for line in lines:
                    formatter.write_text(line)


def parse_options(pairs: tuple[str, ...]) -> dict[str, str]:
    """``key=value`` pairs → dict of texts (the trainer's declarations type them:
    :func:`gazepipe.trainers.base.check_options`)."""
    out: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(None, f"--option {pair!r}: expected KEY=VALUE")
        out[key] = value
    return out


def dataset_header(data_dir: Path) -> tuple[dict[str, Any], list[str]]:
    """_dataset.json and the column names of ``_common_metadata``, read without the rows; a folder that is not a
    dataset is a usage error (exit 2)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from gazepipe.errors import GazepipeError
    from gazepipe.io.dataset_files import COMMON_METADATA, read_info

    if not data_dir.is_dir():
        raise ConfigError(data_dir, "no such dataset folder")
    try:
        info = read_info(data_dir)
    except GazepipeError as exc:
        raise ConfigError(exc.path, exc.problem) from None
    try:
        columns = list(pq.read_schema(str(data_dir / COMMON_METADATA)).names)
    except (OSError, pa.ArrowException) as exc:
        raise ConfigError(data_dir / COMMON_METADATA, f"missing or unreadable ({exc})") from None
    return info, columns


def _facts(metrics: dict[str, Any]) -> list[str]:
    """Where and how long training ran, in one line (the trainer's summary says how well)."""
    if not metrics.get("epochs_run"):
        return []
    seconds = sorted(metrics.get("epoch_seconds") or [0.0])
    step = (metrics.get("execution") or {}).get("training_step", "eager")
    how = {"cuda_graph": "each step replayed as a CUDA graph", "eager": "eager steps"}.get(step, step)
    return [f"{metrics['epochs_run']} epoch(s) on {metrics.get('device', '?')}, {how}, "
            f"{seconds[len(seconds) // 2]:.2f} s per epoch (median)"]


@click.command("train", cls=_TrainCommand, epilog=EPILOG)
@click.argument("name")
@click.option("--data", "data_dir", required=True, type=click.Path(file_okay=False),
              help="A built dataset folder (OUT/datasets/<name>).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Folder for the model: model.json (config, metrics) and its weights.")
@click.option("--epochs", type=click.IntRange(min=1, max=INT_MAX), default=None,
              help="Training epochs (trainer default).")
@click.option("--hidden", type=click.IntRange(min=1, max=INT_MAX), default=None,
              help="Hidden units (trainer default).")
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Learning rate (trainer default).")
@click.option("--seed", type=click.IntRange(min=0, max=SEED_MAX), default=0, show_default=True,
              help="Random seed (same seed, same model: byte for byte on the CPU).")
@click.option("--device", default=None, metavar="auto|cpu|cuda|cuda:N",
              help="Where a torch trainer trains (default auto: the GPU when PyTorch sees one).")
@click.option("--patience", type=click.IntRange(min=0, max=INT_MAX), default=None, metavar="N",
              help="Stop after N epochs without a lower validation loss (default 10; 0: run every epoch). "
              "The best validation epoch's weights are kept either way (--option keep=last for the last).")
@click.option("--option", "opts", multiple=True, metavar="KEY=VALUE",
              help="A trainer-specific option, typed and range-checked (listed below); repeatable.")
@click.option("--force", is_flag=True, help="Train into an --out folder that is not empty, overwriting the model "
              "there (default: refuse).")
@click.option("--json", "as_json", is_flag=True, help="Print the metrics as JSON.")
@click.option("--log-format", type=click.Choice(["auto", "text", "json"]), default="auto", show_default=True,
              help="Progress on stderr: a bar on a terminal, JSON lines otherwise (auto).")
@handle_errors
def train(name: str, data_dir: str, out_dir: str, epochs: int | None, hidden: int | None, lr: float | None,
          seed: int, device: str | None, patience: int | None, opts: tuple[str, ...], force: bool,
          as_json: bool, log_format: str) -> None:
    """Train the model NAME on a built dataset and save it in --out.

    The trainer checks the dataset first (its name, schema version and columns) and refuses one it cannot use.

    \b
      gazepipe train gaze_map --data out/datasets/gaze_map --out models/gaze_map
      gazepipe train gaze_rnn --data out/datasets/gaze_rnn --out models/gaze_rnn --epochs 50
      gazepipe train gaze_rnn --data out/datasets/gaze_rnn_lod --out models/lod --device cpu
      gazepipe train face_clean --data out/datasets/face_clean --out models/face --patience 5
    """
    from gazepipe.datasets import open_dataset
    from gazepipe.pipeline.events import EventLog
    from gazepipe.pipeline.runner import new_run_id
    from gazepipe.trainers.base import TrainOptions, check_compatible, check_options, load_trainer

    trainer = load_trainer(name)
    log = EventLog(log_format, run_id=new_run_id())
    options = TrainOptions(epochs=epochs, hidden=hidden, lr=lr, seed=seed, device=device, patience=patience,
                           extra=parse_options(opts), progress=lambda e: _progress(log, e))
    check_options(trainer, options)
    if capped("OMP_NUM_THREADS") and "threads" in (getattr(trainer, "options", None) or {}):
        options.extra.setdefault("threads", cores())   # training is not a pipeline stage: every core
    data_path = Path(data_dir)
    info, columns = dataset_header(data_path)
    check_compatible(trainer, info, columns, data_path)
    out = Path(out_dir)
    _check_out(out, force)
    data = open_dataset(data_path)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        metrics = trainer.train(data, out, options)
    except BaseException:
        if created:        # a training that failed leaves no --out folder it made (empty, or half a model)
            shutil.rmtree(out, ignore_errors=True)
        raise
    if metrics.get("epochs_run"):
        log.emit("info", "train_end", _end_message(metrics), epochs_run=metrics["epochs_run"],
                 stopped=metrics.get("stopped"), best_epoch=metrics.get("best_epoch"), kept=metrics.get("kept"),
                 device=metrics.get("device"), summary=metrics.get("summary"))
    if as_json:
        click.echo(json.dumps(metrics, indent=1, sort_keys=True))
        return
    click.echo(f"trained {trainer.name} on {data_path} -> {out}")
    for line in [*(metrics.get("summary") or []), *_facts(metrics)]:
        click.echo(f"  {line}")
    click.echo(f"  every figure: {out / 'model.json'} (or --json)")


def _check_out(out: Path, force: bool) -> None:
    """Refuse (exit 2, naming the folder) an ``--out`` that is a file, or a folder with something in it unless
    ``force``: training writes over the model there."""
    if out.exists() and not out.is_dir():
        raise ConfigError(out, "--out is a file, not a folder")
    if not force and out.is_dir() and any(out.iterdir()):
        raise ConfigError(out, "--out is not empty (it may hold a model): give --force to overwrite it, or "
                               "another folder")


def cores() -> int:
    """The cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _end_message(m: dict[str, Any]) -> str:
    seconds = sum(m.get("epoch_seconds") or [])
    text = f"trained {m['epochs_run']} epoch(s) in {seconds:.1f} s on {m.get('device', '?')}"
    if m.get("stopped") == "patience":
        text += f"; stopped early, no lower validation loss since epoch {m['best_epoch']}"
    elif m.get("stopped") == "time":
        text += "; stopped at the time limit"
    if m.get("kept") == "best":
        text += f"; kept epoch {m['best_epoch']}'s weights"
    return text


def _progress(log: Any, e: dict[str, Any]) -> None:
    """A minibatch moves the bar (terminals only); an epoch is a line above the bar on a terminal, a JSON line
    otherwise."""
    if e["event"] == "batch":
        done = (e["epoch"] - 1) * e["batches"] + e["batch"]
        log.progress(min(done, e["epochs"] * e["batches"] - 1), e["epochs"] * e["batches"],
                     f"minibatches (epoch {e['epoch']}/{e['epochs']})")
        return
    val = "" if e["val_loss"] is None else f"  val {e['val_loss']:.4g}{' (best)' if e['best'] else ''}"
    message = (f"epoch {e['epoch']}/{e['epochs']}  train {e['train_loss']:.4g}{val}  {e['seconds']:.1f} s"
               f" (+{e['val_seconds']:.1f} s validation)")
    log.emit("info", "epoch", message, **{k: v for k, v in e.items() if k != "event"})
