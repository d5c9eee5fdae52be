"""What the session generator hands each modality writer: a generated take's record, and the writers' protocol."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.synth.markers import Kinematics
from gazepipe.synth.motion import TakeMotion


@dataclass
class TakeRecord:
    """Everything known about one generated take; handed to every modality writer.

    ``face`` takes have no motion capture: their ``motion`` and ``kinematics`` are ``None`` and ``rate_hz`` is
    the face capture rate.
    """

    id: str
    kind: str
    pose: str
    index: int
    rate_hz: float
    motion: TakeMotion | None
    kinematics: Kinematics | None
    truth_arrays: dict[str, np.ndarray]
    truth_scalars: dict[str, Any]
    rng: np.random.Generator          # a stream of its own, for the writer's noise
    camera_to_head: Rotation          # true head-camera rotation, v_head = R · v_cam
    entries: dict[str, Any] = field(default_factory=dict)   # the take's session.toml keys


class ModalityWriter(Protocol):
    """Writes one more file of a take (video, eyes CSV, face CSVs …).

    Called once per take after the mocap file and truth exist; returns session.toml keys to add to the take
    (paths relative to the session folder), e.g. ``{"video": "video/<take>.mp4"}``, and may add entries to
    ``take.truth_scalars``.
    """

    def __call__(self, session_dir: Path, take: TakeRecord) -> dict[str, Any]: ...
