"""Trainer plugins (entry-point group ``gazepipe.trainers``): the interface in :mod:`gazepipe.trainers.base`,
the reference trainers ``gaze_map`` (numpy/scipy), ``gaze_rnn`` and ``face_clean`` (PyTorch, imported only when
they train)."""

from gazepipe.trainers.base import Trainer, TrainOptions, available, load_trainer

__all__ = ["Trainer", "TrainOptions", "available", "load_trainer"]
