"""Rows of the ``face_clean`` dataset (SPEC §3.6, Berson 3.1, 4.1) from a take's ``face`` table."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from gazepipe.arkit import mirror_face
from gazepipe.schemas.joints import list_to_numpy
from gazepipe.schemas.tracks import N_BLENDSHAPES
from gazepipe.stages.build.gaze import TakeRows


def face_columns(k: int) -> list[str]:
    """Feature columns of face_clean for derivatives up to order ``k``."""
    return ["tracked", "clean", *[f"{w}_d{o}" for o in range(1, k + 1) for w in ("tracked", "clean")]]


def face_rows(face: pa.Table, k: int) -> TakeRows:
    """One row per frame of the ``face`` table (already aligned, with its forward ``dt_s`` and derivatives;
    the face stage left out the last frame and the rows without a clean counterpart). ``segment`` is 0: the
    rows of a take are one sequence, dropped frames show up as longer ``dt_s``."""
    n = face.num_rows
    feats = {c: list_to_numpy(face.column(c), N_BLENDSHAPES).astype(np.float32) for c in face_columns(k)}
    feats["dt_s"] = face.column("dt_s").to_numpy().astype(np.float64)
    return TakeRows(segment=np.zeros(n, np.int32), frame=face.column("frame").to_numpy().astype(np.int32),
                    time_s=face.column("time_s").to_numpy().astype(np.float64), features=feats,
                    qc={})


def mirror_face_rows(features: dict[str, np.ndarray], names: list[str]) -> dict[str, np.ndarray]:
    """Mirror every blendshape column (``…Left``/``…Right`` swap); ``dt_s`` stays."""
    return {c: (v if c == "dt_s" else mirror_face(v, names)) for c, v in features.items()}
