"""Trainer plugins (entry-point group ``gazepipe.trainers``): the interface in :mod:`gazepipe.trainers.base`,
the reference trainers ``gaze_map`` (numpy/scipy), ``gaze_rnn`` and ``face_clean`` (PyTorch, imported only when
they train or run), and their inference API:

- :class:`gazepipe.trainers.gaze_rnn.GazeRNNPredictor`: ``GazeRNNPredictor.load(model_dir).rollout(start_pose,
  target_dirs)``, a closed-loop rollout in the dataset's units (segment rotations as 6D and quaternions, eye
  directions);
- :class:`gazepipe.trainers.face_clean.FaceCleaner`: ``FaceCleaner.load(model_dir).clean(blendshapes,
  timestamps)``;
- :class:`gazepipe.trainers.gaze_map.GazeMap`: ``GazeMap.load(model_dir).motion(yaw_deg, pitch_deg)``.

The three are importable from here too (loaded on first use).
"""

from __future__ import annotations

import importlib
from typing import Any

from gazepipe.trainers.base import Trainer, TrainOptions, available, load_trainer

_LAZY = {"GazeRNNPredictor": "gazepipe.trainers.gaze_rnn", "FaceCleaner": "gazepipe.trainers.face_clean",
         "GazeMap": "gazepipe.trainers.gaze_map"}

__all__ = ["Trainer", "TrainOptions", "available", "load_trainer", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'gazepipe.trainers' has no attribute {name!r}")
