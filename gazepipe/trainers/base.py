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
import math
import re
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
    patience : stop after this many epochs without a lower validation loss (``None``: the trainer's default,
        10 epochs; 0: run every epoch). The best validation epoch's weights are kept unless ``--option
        keep=last``.
    extra : every ``--option key=value``, typed by :func:`check_options` from the trainer's declarations.
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
    options : known ``--option`` keys → :class:`Option` (type, default, range, help; a plain text instead is
        an untyped option's help); unknown keys are refused.
    knobs : optional; which of ``epochs``, ``hidden``, ``lr``, ``device``, ``patience`` it uses (default the first
        three; others are refused).
    """

    name: str
    dataset: str | tuple[str, ...]
    schema_version: int
    required_columns: tuple[str, ...]
    options: dict[str, Option] | dict[str, str]

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


def check_options(trainer: Any, options: TrainOptions) -> None:
    """Check and type ``options.extra`` against the trainer's declared ``--option``s (:func:`typed_options`,
    in place) and refuse (exit 2) an ``--option`` the trainer does not declare and a knob (``--epochs``, ``--hidden``,
    ``--lr``, ``--device``, ``--patience``) it does not use (its optional ``knobs`` attribute; the first three
    when absent)."""
    uses = tuple(getattr(trainer, "knobs", DEFAULT_KNOBS))
    unused = [f"--{k}" for k in KNOBS if getattr(options, k) is not None and k not in uses]
    if unused:
        raise ConfigError(None, f"trainer {trainer.name!r} does not use {', '.join(unused)}")
    options.extra = typed_options(trainer, options.extra)


# ------------------------------------------------------------------------------------------- --option values

#: what a boolean ``--option`` accepts (any case)
TRUE_WORDS = ("true", "1", "yes")
FALSE_WORDS = ("false", "0", "no")
_INT_RE = re.compile(r"^[+-]?\d+$")
#: the largest whole number an ``--option`` takes (a C int: what numpy and torch take for counts, threads and
#: sizes); past it a value would pass the check and fail inside the trainer
INT_MAX = 2**31 - 1


@dataclass(frozen=True)
class Option:
    """One ``--option NAME=VALUE`` a trainer declares: its type, default, allowed range and help.

    Attributes
    ----------
    name : the key.
    type : ``bool``, ``int``, ``float`` or ``str``.
    default : the value when the option is not given; ``None`` when the trainer derives it (``help`` says how).
    help : one line for ``gazepipe train --help``.
    min, max : inclusive bounds of a number (``None``: unbounded).
    min_open, max_open : the bound itself is not allowed.
    choices : the values a ``str`` option accepts.
    default_text : what a ``None`` default means, for people (``all``, ``the dataset's``).
    """

    name: str
    type: type
    default: Any
    help: str
    min: float | None = None
    max: float | None = None
    min_open: bool = False
    max_open: bool = False
    choices: tuple[str, ...] = ()
    default_text: str = ""

    def allowed(self, cap: bool = False) -> str:
        """What the option accepts, for people (``a whole number >= 1``, ``true or false``); with ``cap``, a whole
        number's bound of :data:`INT_MAX` is said too where the trainer declares no maximum."""
        if self.type is bool:
            return "true or false"
        if self.type is str:
            return f"one of {', '.join(self.choices)}" if self.choices else "a text"
        kind = "a whole number" if self.type is int else "a number"
        # a whole number is bounded by INT_MAX even when the trainer declares no maximum
        top = f" (at most {INT_MAX})" if cap and self.type is int and self.max is None else ""
        lo = None if self.min is None else ("(" if self.min_open else "[", self._shown(self.min))
        hi = None if self.max is None else (self._shown(self.max), ")" if self.max_open else "]")
        if lo and hi:
            return f"{kind} in {lo[0]}{lo[1]}, {hi[0]}{hi[1]}"
        if lo:
            return f"{kind} {'>' if self.min_open else '>='} {lo[1]}{top}"
        if hi:
            return f"{kind} {'<' if self.max_open else '<='} {hi[0]}"
        return kind + top

    def _shown(self, v: float) -> str:
        return str(int(v)) if self.type is int else f"{v:g}"

    def shown_default(self) -> str:
        if self.default is None:
            return self.default_text or "none"
        if self.type is bool:
            return "true" if self.default else "false"
        return f"{self.default:g}" if self.type is float else str(self.default)

    def parse(self, value: Any) -> Any:
        """``value`` (the text after ``=``, or a Python value through the API) as the option's type; a
        :class:`ConfigError` (exit 2) naming the option, the value and what is allowed when it is not."""
        got = self._typed(value)
        if got is None or not self._in_range(got):
            raise ConfigError(None, f"--option {self.name}={value}: {self.name} must be {self.allowed(cap=True)}")
        return got

    def _typed(self, value: Any) -> Any:
        if isinstance(value, str):
            text = value.strip()
            if self.type is bool:
                word = text.lower()
                return True if word in TRUE_WORDS else False if word in FALSE_WORDS else None
            if self.type is int:
                return int(text) if _INT_RE.match(text) else None
            if self.type is float:
                try:
                    x = float(text)
                except ValueError:
                    return None
                return x if math.isfinite(x) else None
            return text
        if self.type is bool:
            return value if isinstance(value, bool) else None
        if isinstance(value, bool):
            return None
        if self.type is int:
            return value if isinstance(value, int) else None
        if self.type is float:
            ok = isinstance(value, int | float) and math.isfinite(value)
            return float(value) if ok else None
        return None

    def _in_range(self, x: Any) -> bool:
        if self.type is str:
            return not self.choices or x in self.choices
        if self.type is bool:
            return True
        if self.min is not None and (x < self.min or (self.min_open and x == self.min)):
            return False
        if self.type is int and abs(x) > INT_MAX:
            return False
        return not (self.max is not None and (x > self.max or (self.max_open and x == self.max)))


def declared_options(trainer: Any) -> dict[str, Option | str]:
    """A trainer's ``options``: name → :class:`Option` (a plain text is the help of an untyped option of a
    third-party trainer, whose value is parsed as JSON where it parses, else kept as text)."""
    return dict(getattr(trainer, "options", None) or {})


def options_table(*options: Option) -> dict[str, Option]:
    """The ``options`` attribute of a trainer: name → declaration."""
    return {o.name: o for o in options}


def _untyped(value: Any) -> Any:
    if not isinstance(value, str):
        return value
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value


def typed_options(trainer: Any, values: dict[str, Any]) -> dict[str, Any]:
    """``values`` (``--option`` texts, or Python values) checked against the trainer's declarations and
    converted to their types; an unknown name or a bad value is a :class:`ConfigError` (exit 2)."""
    known = declared_options(trainer)
    unknown = sorted(k for k in values if k not in known)
    if unknown:
        listed = ", ".join(sorted(known)) or "none"
        raise ConfigError(None, f"trainer {trainer.name!r} has no option {', '.join(unknown)} (options: {listed})")
    out: dict[str, Any] = {}
    for k, v in values.items():
        decl = known[k]
        out[k] = decl.parse(v) if isinstance(decl, Option) else _untyped(v)
    return out


def option_lines(trainer: Any) -> list[str]:
    """One line per ``--option`` of a trainer: name, type, default, what it accepts and its help."""
    lines = []
    for name, decl in sorted(declared_options(trainer).items()):
        if isinstance(decl, Option):
            lines.append(f"{name} ({decl.type.__name__}, default {decl.shown_default()}; {decl.allowed()}): "
                         f"{decl.help}")
        else:
            lines.append(f"{name}: {decl}")
    return lines


def loop_options(unit: str, window_default: str, stride_default: str) -> tuple[Option, ...]:
    """The ``--option`` declarations of the torch trainers' common training loop
    (:func:`gazepipe.trainers.loop.fit_config`); ``unit`` names what a minibatch holds (``windows``)."""
    return (
        Option("batch", int, 64, f"{unit} per minibatch", min=1),
        Option("window", int, None, f"frames per {unit[:-1]}", min=1, default_text=window_default),
        Option("stride", int, None, f"step between {unit}, in frames", min=1, default_text=stride_default),
        Option("max_windows", int, None, f"use at most this many training {unit} (a seeded subset)", min=1,
               default_text="all"),
        Option("threads", int, None, "torch CPU threads", min=1,
               default_text="every core the process may use, under gazepipe train"),
        Option("schedule", str, "cosine", "learning rate: cosine (decayed to 0 over the epochs) or constant",
               choices=("cosine", "constant")),
        Option("clip", float, 1.0, "largest gradient norm (0: no clipping)", min=0),
        Option("keep", str, "best", "which epoch's weights to save: best (lowest validation loss) or last",
               choices=("best", "last"), default_text="best; last when there is no validation split"),
        Option("cuda_graph", bool, True, "on a CUDA GPU, replay each training step as one captured CUDA graph "
               "(false: run it operation by operation)"),
        Option("max_seconds", float, None, "stop after the epoch that passes this much training time, in s",
               min=0, min_open=True, default_text="no limit"),
    )


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
