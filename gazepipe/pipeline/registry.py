"""The stage registry: what each stage is, what it reads, which parameters it uses.

A stage runs once per take (a *unit of work*). Its ``run`` receives a :class:`UnitContext` (the take, its
parameters, and a loader for upstream tables) and returns a :class:`UnitResult` (Arrow tables to write and a QC
record); the engine does all reading and writing, so the functions in :mod:`gazepipe.stages` stay pure.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa

from gazepipe.model import Session, Take


@dataclass
class UnitResult:
    """What a unit produced: tables by name (each with the schema it must match) and a JSON-able QC record."""

    tables: dict[str, tuple[pa.Table, pa.Schema]] = field(default_factory=dict)
    qc: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


@dataclass
class UnitContext:
    """Everything a stage may use while running on one take."""

    session: Session
    take: Take
    params: dict[str, Any]
    out_dir: Path
    loader: Callable[[str, str, str], pa.Table]
    all_params: dict[str, Any] = field(default_factory=dict)

    def params_of(self, stage: str) -> dict[str, Any]:
        """Another stage's parameter values (defaults overridden), for a stage that repeats its work."""
        st = get(stage)
        return {k: self.all_params.get(f"{stage}.{k}", v) for k, v in st.params.items()}

    def load(self, table: str, take_id: str | None = None) -> pa.Table:
        """Read an upstream table of this take (or of ``take_id`` in the same session), schema-checked."""
        return self.loader(self.session.id, take_id or self.take.id, table)


@dataclass(frozen=True)
class Stage:
    """A registered stage.

    Attributes
    ----------
    name, version : bump ``version`` whenever the stage's output for the same inputs changes.
    requires : upstream stages (same take) whose outputs it loads.
    params : the parameters it uses with their defaults; part of its fingerprint.
    outputs : table names it writes under ``takes/<session>/<take>/``.
    applies : which takes it runs on.
    sources : the raw input files it reads (content-hashed into its fingerprint).
    run : the work itself.
    rules : the allowed values of its parameters, by name (see :func:`value_problem`); none = any value of
        the default's type.
    """

    name: str
    version: str
    requires: tuple[str, ...]
    params: Mapping[str, Any]
    outputs: tuple[str, ...]
    applies: Callable[[Session, Take], bool]
    sources: Callable[[Session, Take], Sequence[str]]
    run: Callable[[UnitContext], UnitResult]
    help: str = ""
    rules: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)


_STAGES: dict[str, Stage] = {}


def register(stage: Stage) -> Stage:
    if stage.name in _STAGES:
        raise ValueError(f"stage {stage.name} registered twice")
    for up in stage.requires:
        if up not in _STAGES:
            raise ValueError(f"stage {stage.name} requires unknown stage {up}")
    _STAGES[stage.name] = stage
    return stage


def stages() -> list[Stage]:
    """Registered stages in dependency order (registration order)."""
    _ensure_loaded()
    return list(_STAGES.values())


def get(name: str) -> Stage:
    _ensure_loaded()
    return _STAGES[name]


def upto(name: str) -> list[Stage]:
    """``name`` and every stage it depends on, in order."""
    _ensure_loaded()
    need = {name}
    for st in reversed(list(_STAGES.values())):
        if st.name in need:
            need.update(st.requires)
    return [st for st in _STAGES.values() if st.name in need]


def default_params() -> dict[str, Any]:
    """Every parameter as ``"stage.param": default`` (the take stages', then the dataset build's)."""
    from gazepipe.pipeline.datasets import default_build_params

    out = {f"{st.name}.{k}": v for st in stages() for k, v in st.params.items()}
    out.update(default_build_params())
    return out


# ------------------------------------------------------------------------------------- parameter values
#
# A parameter's rule is a mapping (a parameters dataclass declares it as its field's ``metadata``):
#   min, max : inclusive bounds of a number (always finite);  gt, lt : exclusive bounds;
#   choices : the allowed texts of a text parameter, or of every item of a list parameter (at least one item).
# The kind of value comes from the default: true/false, a whole number, a number, a text, a list. A parameter
# whose default is None (off) takes a number when its rule has bounds, else a text.

def rules_of(cls) -> dict[str, Mapping[str, Any]]:
    """The value rules a parameters dataclass declares in its fields' metadata, by field name."""
    return {f.name: dict(f.metadata) for f in dataclasses.fields(cls) if f.metadata}


def show_value(value: Any) -> str:
    """A parameter value as TOML writes it (``-1``, ``1.5``, ``inf``, ``"text"``, ``["a"]``, ``true``)."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return json.dumps(value, default=str)


def _bounds(rule: Mapping[str, Any]) -> str:
    lo = ("[", rule["min"]) if "min" in rule else ("(", rule["gt"]) if "gt" in rule else None
    hi = (rule["max"], "]") if "max" in rule else (rule["lt"], ")") if "lt" in rule else None
    if lo and hi:
        return f" in {lo[0]}{lo[1]:g}, {hi[0]:g}{hi[1]}"
    if lo:
        return f" {'>=' if lo[0] == '[' else '>'} {lo[1]:g}"
    if hi:
        return f" {'<=' if hi[1] == ']' else '<'} {hi[0]:g}"
    return ""


def allowed_values(default: Any, rule: Mapping[str, Any]) -> tuple[str, str]:
    """The kind of value a parameter takes (``bool``, ``int``, ``float``, ``str``, ``list``) and its
    description for users."""
    choices = ", ".join(json.dumps(c) for c in rule.get("choices", ()))
    if isinstance(default, bool):
        return "bool", "true or false"
    if isinstance(default, int):
        return "int", "a whole number" + _bounds(rule)
    if isinstance(default, float) or (default is None and _bounds(rule)):
        return "float", "a number" + _bounds(rule)
    if isinstance(default, list | tuple):
        return "list", f"a list of one or more of {choices}" if choices else "a list"
    return "str", f"one of {choices}" if choices else "a text in quotes"


def _finite(x: float) -> bool:
    try:
        return math.isfinite(x)
    except OverflowError:   # an integer beyond any float
        return False


def value_problem(value: Any, default: Any, rule: Mapping[str, Any]) -> str | None:
    """What is allowed, as a phrase (``a number >= 0``), when ``value`` is not allowed for a parameter with
    this default and rule; ``None`` when it is."""
    kind, allowed = allowed_values(default, rule)
    if value is None and default is None:
        return None
    if kind == "bool":
        ok = isinstance(value, bool)
    elif kind in ("int", "float"):
        number = int if kind == "int" else int | float
        ok = (isinstance(value, number) and not isinstance(value, bool) and _finite(value)
              and value >= rule.get("min", -math.inf) and value <= rule.get("max", math.inf)
              and ("gt" not in rule or value > rule["gt"]) and ("lt" not in rule or value < rule["lt"]))
    elif kind == "list":
        ok = isinstance(value, list | tuple) and len(value) > 0 and all(isinstance(v, str) for v in value)
        ok = ok and ("choices" not in rule or all(v in rule["choices"] for v in value))
    else:
        ok = isinstance(value, str) and ("choices" not in rule or value in rule["choices"])
    return None if ok else allowed


def param_rules() -> dict[str, Mapping[str, Any]]:
    """The value rule of every parameter as ``"stage.param": rule`` (empty: any value of the default's
    kind)."""
    from gazepipe.stages.build import BuildParams

    out: dict[str, Mapping[str, Any]] = {f"{st.name}.{k}": st.rules.get(k, {})
                                         for st in stages() for k in st.params}
    out.update({f"build.{f.name}": dict(f.metadata) for f in dataclasses.fields(BuildParams)})
    return out


def param_problems(values: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Every value among ``values`` (``"stage.param": value``, known parameters only) that is not allowed, as
    ``(parameter, one-line problem)`` naming the parameter, the value and what is allowed; then the rules
    between parameters (:meth:`~gazepipe.stages.build.BuildParams.problems`) when each value is fine."""
    from gazepipe.stages.build import BuildParams

    defaults, rules = default_params(), param_rules()
    out = []
    for key, value in values.items():
        allowed = value_problem(value, defaults[key], rules.get(key, {}))
        if allowed:
            out.append((key, f"parameter {key} must be {allowed}, got {show_value(value)}"))
    given = [k for k in values if k.startswith("build.")]
    if given and not any(k.startswith("build.") for k, _ in out):
        build = BuildParams(**{k: values.get(f"build.{k}", v) for k, v in BuildParams().to_dict().items()})
        out.extend((given[0], p) for p in build.problems())
    return out


def _ensure_loaded() -> None:
    if not _STAGES:
        import gazepipe.pipeline.steps  # noqa: F401  (registers the built-in stages)
