"""What each stage parameter means, for ``gazepipe params``: the first sentence of its entry in the numpy-style
docstring of the code that declares it (``name : meaning``, or ``a, b : meaning`` for several)."""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from typing import Any

_ENTRY = re.compile(r"^([A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)*)\s+:\s*(.*)$")
_ROLE = re.compile(r":(?:func|meth):`~?(?:[\w.]*\.)?(\w+)`")
_OTHER_ROLE = re.compile(r":\w+:`~?(?:[\w.]*\.)?([^`]+)`")


def documented_by() -> dict[str, Callable[..., Any] | type]:
    """Each parameter group (a stage, or ``build``) → the class or function whose docstring documents its
    parameters. A group missing here has no meanings (the tests require every parameter to have one)."""
    from gazepipe.stages.build.stage import BuildParams
    from gazepipe.stages.clean.stage import CleanParams
    from gazepipe.stages.eyes.params import EyesParams
    from gazepipe.stages.face.stage import align_face
    from gazepipe.stages.frames.stage import FramesParams
    from gazepipe.stages.sync.stage import SyncParams

    return {"clean": CleanParams, "frames": FramesParams, "sync": SyncParams, "eyes": EyesParams,
            "face": align_face, "build": BuildParams}


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
