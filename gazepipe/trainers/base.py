"""The trainer plugin interface and its discovery (entry-point group ``gazepipe.trainers``).

A trainer is an object with the attributes of :class:`Trainer`; the entry point names a class (instantiated
with no argument) or an instance. The reference trainers ship with the package and are found even when the
package's entry points are not installed (a source checkout); an installed entry point of the same name wins.

Third-party trainers register themselves in their own ``pyproject.toml``::

    [project.entry-points."gazepipe.trainers"]
    my_trainer = "my_package.trainer:MyTrainer"
"""

from __future__ import annotations

import importlib
import io
import json
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from gazepipe import __version__
from gazepipe.durable import write_bytes_atomic
from gazepipe.errors import ConfigError

GROUP = "gazepipe.trainers"
#: the reference trainers (name → "module:attribute"), also declared as entry points in pyproject.toml
BUILTIN: dict[str, str] = {
    "gaze_map": "gazepipe.trainers.gaze_map:GazeMapTrainer",
    "gaze_rnn": "gazepipe.trainers.gaze_rnn:GazeRnnTrainer",
    "face_clean": "gazepipe.trainers.face_clean:FaceCleanTrainer",
}
MODEL_JSON = "model.json"
#: the options every trainer may use (its ``knobs`` say which; others are refused)
KNOBS = ("epochs", "hidden", "lr", "device", "patience")
#: what a trainer without a ``knobs`` attribute uses
DEFAULT_KNOBS = ("epochs", "hidden", "lr")


@dataclass
class TrainOptions:
    """What ``gazepipe train`` passes to a trainer; ``None`` = the trainer's default.

    Attributes
    ----------
    epochs, hidden, lr, seed : the common knobs.
    device : ``auto`` (``None``), ``cpu``, ``cuda`` or ``cuda:N``: where a torch trainer trains.
    patience : stop after this many epochs without a lower validation loss, keeping the best weights
        (``None``: every epoch, the last weights).
    extra : every ``--option key=value`` (values parsed as JSON where they parse: 3, 0.5, true, "text").
    progress : called with a dict after every minibatch and every epoch (see :mod:`gazepipe.trainers.loop`);
        ``None``: silent.
    """

    epochs: int | None = None
    hidden: int | None = None
    lr: float | None = None
    seed: int = 0
    device: str | None = None
    patience: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    progress: Callable[[dict[str, Any]], None] | None = None

    def get(self, key: str, default: Any) -> Any:
        """A knob or ``--option`` value, else ``default``."""
        if key in KNOBS and getattr(self, key) is not None:
            return getattr(self, key)
        return self.extra.get(key, default)


@runtime_checkable
class Trainer(Protocol):
    """A model trainer.

    Attributes
    ----------
    name : the name ``gazepipe train NAME`` uses.
    dataset : the dataset name(s) it trains on (_dataset.json ``name``); a string or a tuple of accepted names.
    schema_version : the dataset schema version it reads (_dataset.json ``schema_version``).
    required_columns : columns the dataset's files must have.
    options : known ``--option`` keys → one-line help (unknown keys are refused).
    knobs : optional; which of ``epochs``, ``hidden``, ``lr``, ``device``, ``patience`` it uses (default the first
        three; others are refused).
    """

    name: str
    dataset: str | tuple[str, ...]
    schema_version: int
    required_columns: tuple[str, ...]
    options: dict[str, str]

    def train(self, data: Any, out_dir: Path, options: TrainOptions) -> dict[str, Any]:
        """Train on ``data`` (a :class:`gazepipe.datasets.Dataset`), save the model in ``out_dir``, return the
        metrics."""
        ...


def available() -> dict[str, str]:
    """Every trainer name → where it comes from ("module:attribute"), built-ins and installed entry points."""
    found = dict(BUILTIN)
    for ep in entry_points(group=GROUP):
        found[ep.name] = ep.value
    return dict(sorted(found.items()))


def load_trainer(name: str) -> Trainer:
    """The trainer called ``name``; :class:`ConfigError` (exit 2) listing the available ones if unknown."""
    eps = {ep.name: ep for ep in entry_points(group=GROUP)}
    if name in eps:
        obj = eps[name].load()
    elif name in BUILTIN:
        module, attr = BUILTIN[name].split(":")
        obj = getattr(importlib.import_module(module), attr)
    else:
        raise ConfigError(None, f"unknown trainer {name!r} (available: {', '.join(available())})")
    trainer = obj() if isinstance(obj, type) else obj
    missing = [a for a in ("name", "dataset", "schema_version", "required_columns", "train")
               if not hasattr(trainer, a)]
    if missing:
        raise ConfigError(None, f"trainer {name!r} ({available().get(name)}) lacks {', '.join(missing)}")
    return trainer


def accepted_datasets(trainer: Trainer) -> tuple[str, ...]:
    d = trainer.dataset
    return (d,) if isinstance(d, str) else tuple(d)


def check_compatible(trainer: Trainer, info: dict[str, Any], columns: list[str], dataset_dir: str | Path) -> None:
    """Refuse a dataset the trainer cannot use: :class:`ConfigError` (exit 2), one line naming the folder."""
    want = accepted_datasets(trainer)
    got = info.get("name")
    if got not in want:
        raise ConfigError(dataset_dir, f"trainer {trainer.name!r} needs a {' or '.join(want)} dataset, this is "
                                       f"{got!r}")
    version = info.get("schema_version")
    if version != trainer.schema_version:
        raise ConfigError(dataset_dir, f"trainer {trainer.name!r} reads schema version {trainer.schema_version}, "
                                       f"the dataset has {version!r} (rebuild it with this gazepipe)")
    missing = [c for c in trainer.required_columns if c not in columns]
    if missing:
        raise ConfigError(dataset_dir, f"trainer {trainer.name!r} needs columns {', '.join(missing)}, missing "
                                       "from the dataset")


def check_options(trainer: Trainer, options: TrainOptions) -> None:
    """Refuse (exit 2) an ``--option`` the trainer does not declare and a knob (``--epochs``, ``--hidden``,
    ``--lr``, ``--device``, ``--patience``) it does not use (its optional ``knobs`` attribute; the first three
    when absent)."""
    uses = tuple(getattr(trainer, "knobs", DEFAULT_KNOBS))
    unused = [f"--{k}" for k in KNOBS if getattr(options, k) is not None and k not in uses]
    if unused:
        raise ConfigError(None, f"trainer {trainer.name!r} does not use {', '.join(unused)}")
    known = dict(getattr(trainer, "options", {}) or {})
    unknown = sorted(k for k in options.extra if k not in known)
    if unknown:
        listed = ", ".join(sorted(known)) or "none"
        raise ConfigError(None, f"trainer {trainer.name!r} has no option {', '.join(unknown)} (options: {listed})")


# ------------------------------------------------------------------------------------------- saving models

def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, mode 0666 less the umask, as the pipeline writes its outputs
    (:func:`gazepipe.durable.write_bytes_atomic`)."""
    write_bytes_atomic(path, data)


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An ``.npz`` archive (readable by ``numpy.load``) with fixed member times: same arrays, same bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as z:
        for name in sorted(arrays):
            member = io.BytesIO()
            a = np.asarray(arrays[name])
            np.lib.format.write_array(member, a if a.flags.c_contiguous else a.copy(), allow_pickle=False)
            z.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), member.getvalue())
    return buf.getvalue()


def json_bytes(obj: dict[str, Any]) -> bytes:
    return (json.dumps(obj, indent=1, sort_keys=True, allow_nan=False) + "\n").encode()


def dataset_summary(data: Any) -> dict[str, Any]:
    """What a saved model records about its training data (enough to normalise inputs at inference)."""
    info = data.info
    return {"name": info.get("name"), "path": str(data.path), "schema_version": info.get("schema_version"),
            "version": info.get("version"), "features": info.get("features"), "fps": info.get("fps"),
            "inputs": sorted(info.get("inputs", {})), "stats": info.get("stats", {}).get("overall")}


def save_model_json(out_dir: Path, trainer: str, config: dict[str, Any], metrics: dict[str, Any], data: Any,
                    weights: str) -> Path:
    """``out_dir/model.json``: trainer, config, metrics, dataset summary, weights file name, gazepipe version."""
    path = Path(out_dir) / MODEL_JSON
    write_atomic(path, json_bytes({"trainer": trainer, "config": config, "metrics": metrics, "weights": weights,
                                   "dataset": dataset_summary(data), "gazepipe_version": __version__}))
    return path


def read_model_json(model_dir: str | Path) -> dict[str, Any]:
    path = Path(model_dir) / MODEL_JSON
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(path, "file not found (not a gazepipe model folder)") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(path, f"not valid JSON ({exc.msg} at line {exc.lineno})") from None
