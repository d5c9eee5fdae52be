"""Deterministic synthetic capture sessions with ground truth (sample data, tests, benchmarks).

``generate_session(out_dir, seed=..., config=...)`` writes a session folder per SPEC §1 (session.toml,
markerset.toml, mocap/*.c3d; per gaze_follow take a head-camera video/*.mp4 on its own clock and the OpenFace
eyes/*.csv of it; Live Link Face face/*_clean.csv and face/*_tracked.csv per face take) and its truth
(truth/*.npz, truth/truth.json, truth/README.md); ``load_truth`` reads it back.
"""

from gazepipe.synth.headcam import head_camera_writer
from gazepipe.synth.livelinkface import face_writer
from gazepipe.synth.record import ModalityWriter, TakeRecord
from gazepipe.synth.session import SynthConfig, generate_session, klein_config
from gazepipe.synth.skeleton import Placement
from gazepipe.synth.truth import load_truth
from gazepipe.synth.video import CameraClock

__all__ = ["CameraClock", "ModalityWriter", "Placement", "SynthConfig", "TakeRecord", "face_writer",
           "generate_session", "head_camera_writer", "klein_config", "load_truth"]
