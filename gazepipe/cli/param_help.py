"""What each stage parameter means, for ``gazepipe params`` and the options that expose one: its one line of help
from its field's metadata (``help``), and the long form, the first sentence of its entry in the numpy-style
docstring of its parameters dataclass (``name : meaning``, or ``a, b : meaning`` for several)."""

from __future__ import annotations

import inspect
import re
from typing import Any

import click

_ENTRY = re.compile(r"^([A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)*)\s+:\s*(.*)$")
_ROLE = re.compile(r":(?:func|meth):`~?(?:[\w.]*\.)?(\w+)`")
_OTHER_ROLE = re.compile(r":\w+:`~?(?:[\w.]*\.)?([^`]+)`")


def documented_by() -> dict[str, type]:
    """Each parameter group (a stage, or ``build``) → its parameters dataclass, as the stages declare it
    (:attr:`gazepipe.pipeline.registry.Stage.params_class`): the one source of each parameter's default, value
    rule, one line of help (field metadata ``help``) and long meaning (the class docstring's entry)."""
    import gazepipe.dag
    from gazepipe.pipeline.registry import param_classes

    gazepipe.dag.declare()   # the stages and their parameters

    return param_classes()


def docstring_entries(doc: str) -> dict[str, str]:
    """Every ``name : text`` entry of a numpy-style docstring (continuation lines indented under it), by name,
    the text on one line; the first entry of a name wins."""
    out: dict[str, str] = {}
    names: list[str] = []
    text: list[str] = []

    def close() -> None:
        for n in names:
            out.setdefault(n, " ".join(text))

    for line in inspect.cleandoc(doc).splitlines():
        m = _ENTRY.match(line)
        if m:
            close()
            names = [n.strip() for n in m.group(1).split(",")]
            text = [m.group(2).strip()]
        elif line.startswith((" ", "\t")) and line.strip() and names:
            text.append(line.strip())
        else:
            close()
            names, text = [], []
    close()
    return out


def first_sentence(text: str) -> str:
    """The first sentence of ``text`` (a full stop followed by a capital, outside brackets), reST markup
    turned into plain text."""
    text = _ROLE.sub(r"\1()", text)
    text = _OTHER_ROLE.sub(r"\1", text).replace("``", "").replace("*", "")
    depth = 0
    for i, ch in enumerate(text):
        depth += (ch in "([{") - (ch in ")]}")
        if ch == "." and depth <= 0 and text[i + 1:i + 2] == " " and text[i + 2:i + 3].isupper():
            return text[:i + 1]
    return text


def param_meanings() -> dict[str, str]:
    """``"group.param"`` → one line saying what it means, for every parameter that is documented."""
    out: dict[str, str] = {}
    for group, obj in documented_by().items():
        for name, text in docstring_entries(inspect.getdoc(obj) or "").items():
            sentence = first_sentence(text).strip()
            if sentence:
                out[f"{group}.{name}"] = sentence
    return out


def user_help() -> dict[str, str]:
    """``"group.param"`` → the short line ``gazepipe params`` prints: its field's ``help``
    (:func:`gazepipe.pipeline.registry.helps_of`), else the docstring meaning."""
    from gazepipe.pipeline.registry import helps_of

    out = param_meanings()
    out.update({f"{group}.{name}": text for group, cls in documented_by().items()
                for name, text in helps_of(cls).items()})
    return out


def param_help(group: str, name: str) -> str:
    """The one line of help of parameter ``name`` of parameters dataclass ``group`` (``clean``…), read from the
    dataclass itself: for a command that exposes a stage's parameter as an option (``gazepipe fill``)."""
    return user_help()[f"{group}.{name}"]


# ------------------------------------------------------------------------------- gazepipe fill's parameters

#: the clean parameters ``gazepipe fill`` sets otherwise than ``gazepipe run``: a file filler keeps every measured
#: sample unless asked (spikes are counted, not taken out; label swaps are left as they are)
FILL_OVERRIDES: dict[str, Any] = {"remove_spikes": False, "repair_swaps": False}


def fill_params(**given: Any) -> Any:
    """The clean stage's parameters (:class:`~gazepipe.stages.clean.stage.CleanParams`) ``gazepipe fill`` fills
    with, built as ``gazepipe run`` builds them (:func:`gazepipe.pipeline.registry.params_from`): the
    dataclass's defaults, then :data:`FILL_OVERRIDES`, then the options ``given`` (by field name; None: not
    given)."""
    from gazepipe.pipeline.registry import defaults_of, params_from
    from gazepipe.stages.clean.stage import CleanParams

    values = {**defaults_of(CleanParams), **FILL_OVERRIDES, **{k: v for k, v in given.items() if v is not None}}
    return params_from(CleanParams, values)


class CleanParamOption(click.Option):
    """An option of ``gazepipe fill`` that is a clean stage parameter (``field``): its default and its help's
    first words come from :class:`~gazepipe.stages.clean.stage.CleanParams` (:func:`fill_params`,
    :func:`param_help`), read when the option is parsed or shown (importing the stage with the command line
    would load numpy before the command caps its BLAS threads); ``more``: what the option adds to the help."""

    def __init__(self, *args: Any, field: str, more: str = "", **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.field, self.more = field, more

    def get_default(self, ctx: click.Context, call: bool = True) -> Any:
        return getattr(fill_params(), self.field)

    def get_help_record(self, ctx: click.Context) -> tuple[str, str] | None:
        text = param_help("clean", self.field)
        self.help = f"{text[:1].upper()}{text[1:]} (as `gazepipe run`'s clean.{self.field}){self.more}"
        return super().get_help_record(ctx)
