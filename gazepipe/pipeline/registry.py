"""The engine's registry: the stages a DAG registers, the datasets built from them, their parameters, and how
tables are read and written.

The engine knows nothing of what a stage does. A DAG module (gazepipe's is :mod:`gazepipe.dag`) registers, when
its ``declare()`` is called (never on import; :func:`declared_by` records it, so a worker started afresh calls it
again, :func:`ensure`):

- take stages (:func:`register`): a stage runs once per take (a *unit of work*); it declares the tables it
  reads (``inputs``) and writes (``outputs``), and the engine derives the stages it follows from them (kedro's
  nodes, by table name); its ``run`` receives a :class:`UnitContext` (the take, its parameters, and a loader for
  its declared tables, which refuses any other) and returns a :class:`UnitResult` (Arrow tables to write and a
  QC record); the engine does all reading and writing, so the stage functions stay pure;
- session stages (:func:`register_session_stage`): work done once per session that take stages read (their
  ``session_inputs``), such as a pose every take is calibrated against; they run before the session's take
  units, with a :class:`SessionContext`;
- datasets built from many takes' tables (:func:`register_dataset`, :mod:`gazepipe.pipeline.builds`);
- parameter groups that belong to no take stage (:func:`register_params`: the datasets' parameters);
- the table store (:func:`set_table_store`): how a table is written and read back schema-checked.

Sessions and takes are the DAG's own objects; the engine reads only the attributes of :class:`SessionLike`
and :class:`TakeLike`.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar

import pyarrow as pa

from gazepipe.errors import printable


class TakeLike(Protocol):
    """A take as the engine sees it: an id unique in its session, and its settings as dataclass fields (part of
    every unit's fingerprint; absolute paths among them are made relative to the session folder)."""

    @property
    def id(self) -> str: ...


class SessionLike(Protocol):
    """A session as the engine sees it: an id, the folder its relative paths start from (``root``), the path it
    was loaded from (remembered for ``gazepipe status``), and its takes."""

    @property
    def id(self) -> str: ...

    @property
    def root(self) -> str: ...

    @property
    def path(self) -> str: ...

    @property
    def takes(self) -> Sequence[TakeLike]: ...


SessionT = TypeVar("SessionT", bound=SessionLike)
TakeT = TypeVar("TakeT", bound=TakeLike)


@dataclass(frozen=True)
class TableBatches:
    """A table given as its record batches, for one too long to hold whole beside the arrays it is made from
    or read into: ``schema`` (with its metadata), ``num_rows`` in all, and ``batches`` (an iterator of the rows
    in order, each batch of ``schema``'s fields; read once). A stage returns one in place of a ``pa.Table``; the
    store writes it a batch (a row group) at a time; :meth:`UnitContext.load_batches` reads one."""

    schema: pa.Schema
    num_rows: int
    batches: Iterator[pa.RecordBatch]


@dataclass(frozen=True)
class TableStore:
    """How the engine writes a stage's tables and reads them back.

    write(table, path, schema) : write ``table`` (whole, or :class:`TableBatches`) to ``path``, checked against
        ``schema``.
    read(path) : the table at ``path``.
    check(table, path, name) : raise when table ``name`` (read from, or just written to, ``path``) is not what
        a table of that name must be.
    read_batches(path, name) : the table at ``path`` as :class:`TableBatches`, a row group at a time, each
        batch checked as it is read (its schema before any); ``None``: the whole table is read and checked,
        then handed out in batches.
    """

    write: Callable[[pa.Table | TableBatches, Path, pa.Schema], None]
    read: Callable[[Path], pa.Table]
    check: Callable[[pa.Table, Path, str], None]
    read_batches: Callable[[Path, str], TableBatches] | None = None


@dataclass
class UnitResult:
    """What a unit produced: tables by name (each with the schema it must match) and a JSON-able QC record.

    ``read`` lists input files the unit chose to read beyond its stage's declared ``sources`` (known only
    while it ran, such as a fallback it needed); their content hashes join the unit's record, and a later run
    re-runs the unit when one of them changed.
    """

    tables: dict[str, tuple[pa.Table | TableBatches, pa.Schema]] = field(default_factory=dict)
    qc: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    read: list[str] = field(default_factory=list)


@dataclass
class UnitContext(Generic[SessionT, TakeT]):
    """Everything a stage may use while running on one take: the DAG's own session and take types
    (``UnitContext[Session, Take]``), the stage's parameter values, and loaders for upstream tables."""

    session: SessionT
    take: TakeT
    params: dict[str, Any]
    out_dir: Path
    loader: Callable[[str, str, str], pa.Table]
    all_params: dict[str, Any] = field(default_factory=dict)
    #: reads a session stage's table: ``(session id, table name)``
    session_loader: Callable[[str, str], pa.Table] | None = None
    #: reads a take's table as batches, like ``loader``; None: from ``loader``'s whole table
    batch_loader: Callable[[str, str, str], TableBatches] | None = None

    def params_of(self, stage: str) -> dict[str, Any]:
        """Another stage's parameter values (defaults overridden), for a stage that repeats its work."""
        return group_values(stage, self.all_params)

    #: the take tables and the session tables the stage declares it reads (:attr:`Stage.inputs`,
    #: :attr:`Stage.session_inputs`); None: any
    inputs: frozenset[str] | None = None
    session_inputs: frozenset[str] | None = None

    def load(self, table: str, take_id: str | None = None) -> pa.Table:
        """Read an upstream table of this take (or of ``take_id`` in the same session), schema-checked; one the
        stage does not declare among its inputs is refused (:class:`UndeclaredLoad`)."""
        _check_declared(table, self.inputs, "inputs")
        return self.loader(self.session.id, take_id or self.take.id, table)

    def load_batches(self, table: str) -> TableBatches:
        """:meth:`load` of this take's table a row group at a time (:class:`TableBatches`), for a table too long
        to hold whole beside the arrays read from it; each batch is checked as it is read."""
        _check_declared(table, self.inputs, "inputs")
        if self.batch_loader is None:
            whole = self.loader(self.session.id, self.take.id, table)
            return TableBatches(whole.schema, whole.num_rows, iter(whole.to_batches()))
        return self.batch_loader(self.session.id, self.take.id, table)

    def load_session(self, table: str) -> pa.Table:
        """Read a table of one of the stage's ``session_inputs`` (this take's session), schema-checked."""
        _check_declared(table, self.session_inputs, "session_inputs")
        if self.session_loader is None:
            raise RuntimeError(f"no session tables in this context (asked for {table})")
        return self.session_loader(self.session.id, table)


class UndeclaredLoad(RuntimeError):
    """A stage asked for a table it does not declare among its inputs: its unit fails (a wiring error, not
    the data's)."""


def _check_declared(table: str, declared: frozenset[str] | None, what: str) -> None:
    if declared is not None and table not in declared:
        raise UndeclaredLoad(f"the stage loads table {table!r}, which it does not declare among its {what} "
                             f"({', '.join(sorted(declared)) or 'none'})")


@dataclass
class SessionContext(Generic[SessionT]):
    """Everything a session stage may use while running once for a session."""

    session: SessionT
    params: dict[str, Any]
    out_dir: Path
    loader: Callable[[str, str], pa.Table]
    all_params: dict[str, Any] = field(default_factory=dict)
    #: the session tables the stage declares it reads (:attr:`SessionStage.inputs`); None: any
    inputs: frozenset[str] | None = None

    def params_of(self, stage: str) -> dict[str, Any]:
        """The parameter values (defaults overridden) of stage or group ``stage``."""
        return group_values(stage, self.all_params)

    def load(self, table: str) -> pa.Table:
        """Read a table of an upstream session stage of this session, schema-checked; one the stage does not
        declare among its inputs is refused (:class:`UndeclaredLoad`)."""
        _check_declared(table, self.inputs, "inputs")
        return self.loader(self.session.id, table)


@dataclass(frozen=True)
class Stage:
    """A registered stage.

    Attributes
    ----------
    name, version : bump ``version`` only for a change of its outputs that its code identity cannot see (a data
        file it reads beside its code, a library it reaches only through another): the code its ``run`` reaches
        is in every unit's code identity (:mod:`gazepipe.pipeline.codehash`).
    params_class : its parameters dataclass (None: it has none), the one source of their names, defaults, value
        rules (field metadata) and help (metadata ``help``, else the class docstring's entry); its run gets the
        values as a dict (``ctx.params``) and builds the dataclass whole with :func:`params_from`.
    params : derived by :func:`register` from ``params_class``: the defaults (:func:`defaults_of`); part of
        its fingerprint.
    outputs : table names it writes under ``takes/<session>/<take>/``; no other stage writes a table of
        that name.
    inputs : the tables of the same take it reads (:meth:`UnitContext.load` refuses any other), each written
        by a stage registered before it.
    session_inputs : the tables of session stages (:class:`SessionStage`) it reads
        (:meth:`UnitContext.load_session`); they run first, and a change of theirs re-runs it.
    applies : which takes it runs on.
    sources : the raw input files it reads (content-hashed into its fingerprint).
    run : the work itself.
    rules : derived by :func:`register` from ``params_class``: the allowed values of its parameters, by name
        (see :func:`value_problem`); none = any value of the default's type.
    groups : parameter groups (:func:`register_params`) whose values it reads too (``ctx.all_params``); they
        are part of its fingerprint as its own parameters are.
    requires, session_requires : derived by :func:`register` from ``inputs`` and ``session_inputs``: the
        stages and session stages that write them, in the order of the tables.
    """

    name: str
    version: str
    outputs: tuple[str, ...]
    applies: Callable[[Any, Any], bool]
    sources: Callable[[Any, Any], Sequence[str]]
    run: Callable[[Any], UnitResult]
    params_class: type | None = None
    help: str = ""
    params: Mapping[str, Any] = field(default_factory=dict)
    rules: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    inputs: tuple[str, ...] = ()
    session_inputs: tuple[str, ...] = ()
    groups: tuple[str, ...] = ()
    requires: tuple[str, ...] = ()
    session_requires: tuple[str, ...] = ()


@dataclass(frozen=True)
class SessionStage:
    """A registered session stage: work done once per session, before its take units, that take stages read.

    Attributes
    ----------
    name, version : as :attr:`Stage.version`: only for what its code identity cannot see.
    inputs : the tables of upstream session stages it reads (:meth:`SessionContext.load` refuses any other).
    uses : parameter groups (take stages or :class:`ParamGroup`) whose values it uses; part of its
        fingerprint (a session stage repeats a take stage's work, with that stage's parameters).
    outputs : table names it writes under ``sessions/<session>/``.
    applies : whether the session needs it.
    sources : the raw input files it reads (content-hashed into its fingerprint).
    run : the work itself: a :class:`SessionContext` in, a :class:`UnitResult` out.
    requires : derived by :func:`register_session_stage` from ``inputs``: the session stages that write them.
    """

    name: str
    version: str
    uses: tuple[str, ...]
    outputs: tuple[str, ...]
    applies: Callable[[Any], bool]
    sources: Callable[[Any], Sequence[str]]
    run: Callable[[Any], UnitResult]
    help: str = ""
    inputs: tuple[str, ...] = ()
    requires: tuple[str, ...] = ()


@dataclass(frozen=True)
class Dataset:
    """A registered dataset: built from every take that feeds it, after the takes ran
    (:mod:`gazepipe.pipeline.builds`).

    Attributes
    ----------
    name, version : as :attr:`Stage.version`: only for what its code identity cannot see.
    needs : stages whose tables it reads from each contributing take. A take contributes when each of them has
        an up-to-date ``ok`` unit, except an ``optional`` one that does not apply to the take.
    applies : which takes may feed it.
    run : the build: a :class:`~gazepipe.pipeline.builds.DatasetContext` in, a
        :class:`~gazepipe.pipeline.builds.DatasetResult` out.
    params : the parameter group (:func:`register_params`) whose values it uses; part of its fingerprint.
    needs_any : ``(stage, why)`` pairs: an ``optional`` stage that at least one contributing take must have;
        when none has it the dataset is skipped (not built, not failed), the run saying ``why`` (e.g. ``no take
        has eye tracking``).
    """

    name: str
    version: str
    needs: tuple[str, ...]
    applies: Callable[[SessionLike, TakeLike], bool]
    run: Callable[[Any], Any]
    params: str = ""
    optional: tuple[str, ...] = ()
    help: str = ""
    needs_any: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class ParamGroup:
    """Parameters that belong to no take stage (``"<name>.<param>"``), declared by their dataclass
    (``params_class``: defaults, value rules and help, as :attr:`Stage.params_class`), and the rules between
    them: ``problems(values)`` gives one line per broken rule (values: every parameter of the group, defaults
    overridden)."""

    name: str
    params_class: type
    problems: Callable[[dict[str, Any]], list[str]] | None = None
    #: derived by :func:`register_params` from ``params_class``, as :attr:`Stage.params` and :attr:`Stage.rules`
    params: Mapping[str, Any] = field(default_factory=dict)
    rules: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)


_STAGES: dict[str, Stage] = {}
_SESSION_STAGES: dict[str, SessionStage] = {}
_DATASETS: dict[str, Dataset] = {}
_GROUPS: dict[str, ParamGroup] = {}
_TABLES: list[TableStore] = []


def _writers(stage: str, tables: Sequence[str], stages: Sequence[Stage | SessionStage],
             what: str) -> tuple[str, ...]:
    """The registered stages (of ``stages``) that write ``tables``, in the order of the tables."""
    by_table = {t: st.name for st in stages for t in st.outputs}
    unknown = [t for t in tables if t not in by_table]
    if unknown:
        raise ValueError(f"stage {stage} reads {what} {unknown} that no stage registered before it writes")
    return tuple(dict.fromkeys(by_table[t] for t in tables))


def _check_outputs(name: str, outputs: Sequence[str]) -> None:
    registered: list[Stage | SessionStage] = [*_STAGES.values(), *_SESSION_STAGES.values()]
    taken = {t: st.name for st in registered for t in st.outputs}
    twice = [t for t in outputs if t in taken]
    if twice:
        raise ValueError(f"stage {name} writes tables {twice} that stage {taken[twice[0]]} writes")


def register(stage: Stage) -> Stage:
    """Add a take stage, its upstream stages and session stages derived from the tables it declares it reads
    (their writers must be registered before it)."""
    if stage.name in _STAGES or stage.name in _GROUPS or stage.name in _SESSION_STAGES:
        raise ValueError(f"stage {stage.name} registered twice")
    if stage.requires or stage.session_requires:
        raise ValueError(f"stage {stage.name}: declare the tables it reads (inputs), not the stages")
    _check_outputs(stage.name, stage.outputs)
    for group in stage.groups:
        if group not in _GROUPS:
            raise ValueError(f"stage {stage.name} reads unknown parameter group {group}")
    if stage.params_class is None and (stage.params or stage.rules):
        raise ValueError(f"stage {stage.name}: declare its parameters dataclass (params_class), not a dict")
    if stage.params_class is not None:
        stage = dataclasses.replace(stage, params=defaults_of(stage.params_class), rules=rules_of(stage.params_class))
    stage = dataclasses.replace(stage, requires=_writers(stage.name, stage.inputs, list(_STAGES.values()), "tables"),
                                session_requires=_writers(stage.name, stage.session_inputs,
                                                          list(_SESSION_STAGES.values()), "session tables"))
    _STAGES[stage.name] = stage
    return stage


def register_session_stage(stage: SessionStage) -> SessionStage:
    """Add a session stage, its upstream session stages derived from the tables it declares it reads (their
    writers must be registered before it)."""
    if stage.name in _SESSION_STAGES or stage.name in _STAGES or stage.name in _GROUPS:
        raise ValueError(f"stage {stage.name} registered twice")
    if stage.requires:
        raise ValueError(f"session stage {stage.name}: declare the tables it reads (inputs), not the stages")
    _check_outputs(stage.name, stage.outputs)
    # the groups it uses may come later: take stages that read it are registered after it
    stage = dataclasses.replace(stage, requires=_writers(stage.name, stage.inputs, list(_SESSION_STAGES.values()),
                                                         "session tables"))
    _SESSION_STAGES[stage.name] = stage
    return stage


def register_params(group: ParamGroup) -> ParamGroup:
    """Add a parameter group that belongs to no take stage."""
    if group.name in _GROUPS or group.name in _STAGES:
        raise ValueError(f"parameter group {group.name} registered twice")
    group = dataclasses.replace(group, params=defaults_of(group.params_class), rules=rules_of(group.params_class))
    _GROUPS[group.name] = group
    return group


def register_dataset(dataset: Dataset) -> Dataset:
    """Add a dataset; the stages it needs and its parameter group must be registered before it."""
    if dataset.name in _DATASETS:
        raise ValueError(f"dataset {dataset.name} registered twice")
    unknown = [s for s in dataset.needs if s not in _STAGES]
    if unknown or (dataset.params and dataset.params not in _GROUPS):
        raise ValueError(f"dataset {dataset.name} needs unknown stages or parameters: {unknown or dataset.params}")
    _DATASETS[dataset.name] = dataset
    return dataset


_SOURCE_CHECK: list[Callable[[Path], None]] = []


def set_table_store(store: TableStore) -> None:
    """How the engine writes and reads tables (once per process; the last call wins)."""
    _TABLES[:] = [store]


def set_source_check(check: Callable[[Path], None] | None) -> None:
    """How the engine looks at an input file before it hashes it (once per process; the last call wins):
    ``check(path)`` raises :class:`~gazepipe.errors.GazepipeError` for a file that cannot be what it claims
    (a capture whose header declares more than the file holds…), in bounded time and memory, so such a file
    fails its take at once instead of being read whole first."""
    _SOURCE_CHECK[:] = [check] if check is not None else []


def source_check() -> Callable[[Path], None] | None:
    return _SOURCE_CHECK[0] if _SOURCE_CHECK else None


def _loaded() -> None:
    if not _STAGES or not _TABLES:
        raise RuntimeError("no stages registered: declare them first (gazepipe.dag.declare())")


_DECLARED_BY: list[str] = []


def declared_by(module: str) -> None:
    """Record that the DAG module ``module`` registered what is registered, through its function ``declare()``
    (:func:`ensure` calls it again in a worker started afresh)."""
    if module not in _DECLARED_BY:
        _DECLARED_BY.append(module)


def declared(module: str) -> bool:
    """Whether DAG module ``module`` has declared its stages in this process (:func:`declared_by`)."""
    return module in _DECLARED_BY


def modules() -> tuple[str, ...]:
    """The DAG modules that declared what is registered (:func:`declared_by`), then the modules whose functions
    the registered stages and datasets run, in registration order: importing them (and calling a DAG module's
    ``declare()``) registers the same stages and datasets in another process (:func:`ensure`)."""
    runs = ([st.run for st in _SESSION_STAGES.values()] + [st.run for st in _STAGES.values()]
            + [ds.run for ds in _DATASETS.values()])
    return tuple(dict.fromkeys([*_DECLARED_BY, *(f.__module__ for f in runs)]))


def ensure(names: Sequence[str]) -> None:
    """In a process where nothing is registered yet (a worker started afresh), import the modules
    :func:`modules` named in the process that planned the run, and call the ``declare()`` of each that has
    one."""
    if not _STAGES:
        for name in names:
            declare = getattr(importlib.import_module(name), "declare", None)
            if callable(declare):
                declare()


def stages() -> list[Stage]:
    """Registered stages in dependency order (registration order)."""
    _loaded()
    return list(_STAGES.values())


def get(name: str) -> Stage:
    _loaded()
    return _STAGES[name]


def get_session_stage(name: str) -> SessionStage:
    _loaded()
    return _SESSION_STAGES[name]


def session_stages_for(take_stages: Sequence[Stage]) -> list[SessionStage]:
    """The session stages that ``take_stages`` read, with those they require, in registration order."""
    need = {name for st in take_stages for name in st.session_requires}
    for st in reversed(list(_SESSION_STAGES.values())):
        if st.name in need:
            need.update(st.requires)
    return [st for st in _SESSION_STAGES.values() if st.name in need]


def upto(name: str) -> list[Stage]:
    """``name`` and every stage it depends on, in order."""
    _loaded()
    need = {name}
    for st in reversed(list(_STAGES.values())):
        if st.name in need:
            need.update(st.requires)
    return [st for st in _STAGES.values() if st.name in need]


def datasets() -> list[Dataset]:
    """Registered datasets in registration order."""
    _loaded()
    return list(_DATASETS.values())


def table_store() -> TableStore:
    _loaded()
    return _TABLES[0]


def group_values(name: str, params: Mapping[str, Any]) -> dict[str, Any]:
    """The values of parameter group ``name`` (a stage or a :class:`ParamGroup`), defaults overridden by
    ``params`` (``"group.param": value``)."""
    _loaded()
    defaults = _STAGES[name].params if name in _STAGES else _GROUPS[name].params
    return {k: params.get(f"{name}.{k}", v) for k, v in defaults.items()}


def default_params() -> dict[str, Any]:
    """Every parameter as ``"group.param": default`` (the take stages', then the other groups')."""
    out = {f"{st.name}.{k}": v for st in stages() for k, v in st.params.items()}
    out.update({f"{g.name}.{k}": v for g in _GROUPS.values() for k, v in g.params.items()})
    return out


# ------------------------------------------------------------------------------------- parameter values
#
# A parameter's rule is a mapping (a parameters dataclass declares it as its field's ``metadata``):
#   min, max : inclusive bounds of a number (always finite);  gt, lt : exclusive bounds;
#   choices : the allowed texts of a text parameter, or of every item of a list parameter (at least one item).
# The kind of value comes from the default: true/false, a whole number, a number, a text, a list. A parameter
# whose default is None (off) takes a number when its rule has bounds, else a text.

#: the metadata key of a parameter's one line of help (the rest of its metadata is its value rule)
HELP = "help"

P = TypeVar("P")


def rules_of(cls: type) -> dict[str, Mapping[str, Any]]:
    """The value rules a parameters dataclass declares in its fields' metadata (but their ``help``), by field
    name."""
    out = {f.name: {k: v for k, v in f.metadata.items() if k != HELP} for f in dataclasses.fields(cls)}
    return {k: v for k, v in out.items() if v}


def helps_of(cls: type) -> dict[str, str]:
    """The one line of help a parameters dataclass declares for each field (metadata ``help``), by field
    name."""
    return {f.name: f.metadata[HELP] for f in dataclasses.fields(cls) if HELP in f.metadata}


def defaults_of(cls: type) -> dict[str, Any]:
    """The defaults of a parameters dataclass, by field name, as JSON writes them (tuples as lists): a stage's
    parameters as its units' fingerprints record them."""
    out = {}
    for f in dataclasses.fields(cls):
        v = getattr(cls(), f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def params_from(cls: type[P], values: Mapping[str, Any]) -> P:
    """The parameters dataclass ``cls`` from a unit's values (its fields' names; lists as tuples; a field not
    given keeps its default): how every stage's run, and the commands, build a stage's parameters."""
    kw = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name in values:
            v = values[f.name]
            kw[f.name] = tuple(v) if isinstance(v, list) else v
    return cls(**kw)


def param_classes() -> dict[str, type]:
    """Each parameter group (a take stage with parameters, or a :class:`ParamGroup`) → its parameters
    dataclass."""
    out: dict[str, type] = {st.name: st.params_class for st in stages() if st.params_class is not None}
    out.update({g.name: g.params_class for g in _GROUPS.values()})
    return out


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
    """The value rule of every parameter as ``"group.param": rule`` (empty: any value of the default's
    kind)."""
    out: dict[str, Mapping[str, Any]] = {f"{st.name}.{k}": st.rules.get(k, {})
                                         for st in stages() for k in st.params}
    out.update({f"{g.name}.{k}": g.rules.get(k, {}) for g in _GROUPS.values() for k in g.params})
    return out


def param_problems(values: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Every value among ``values`` (``"group.param": value``, known parameters only) that is not allowed, as
    ``(parameter, one-line problem)`` naming the parameter, the value and what is allowed; then, for each group
    whose given values are each fine, the rules between its parameters (:attr:`ParamGroup.problems`)."""
    defaults, rules = default_params(), param_rules()
    out = []
    for key, value in values.items():
        allowed = value_problem(value, defaults[key], rules.get(key, {}))
        if allowed:
            shown = show_value(value)
            shown = shown if len(shown) <= 80 else f"{shown[:60]}… ({len(shown)} characters)"
            out.append((key, f"parameter {key} must be {allowed}, got {printable(shown)}"))
    for g in _GROUPS.values():
        given = [k for k in values if k.startswith(f"{g.name}.")]
        if g.problems and given and not any(k.startswith(f"{g.name}.") for k, _ in out):
            out.extend((given[0], p) for p in g.problems(group_values(g.name, values)))
    return out
