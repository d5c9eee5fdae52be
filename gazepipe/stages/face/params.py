"""The face stage's parameters (:class:`FaceParams`)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class FaceParams:
    """Parameters of the face stage (see :func:`gazepipe.stages.face.stage.align_face`).

    k : highest derivative order of the blendshapes (Berson's forward derivatives over the aligned rows); the
        last ``k`` aligned rows lack it and are left out.

    Each field's metadata gives its allowed values (:func:`gazepipe.pipeline.registry.value_problem`) and its one
    line of help (``help``).
    """

    k: int = field(default=1, metadata={"min": 1, "help": "highest time derivative of the blendshapes to compute"})
