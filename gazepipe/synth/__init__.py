"""Deterministic synthetic capture sessions with ground truth (sample data, tests, benchmarks).

``generate_session(out_dir, seed=..., config=...)`` writes a session folder per SPEC §1 (session.toml,
markerset.toml, mocap/*.c3d) and its truth (truth/*.npz, truth/truth.json); ``load_truth`` reads it back.
"""

from gazepipe.synth.session import ModalityWriter, SynthConfig, TakeRecord, generate_session, klein_config
from gazepipe.synth.skeleton import Placement
from gazepipe.synth.truth import load_truth

__all__ = ["ModalityWriter", "Placement", "SynthConfig", "TakeRecord", "generate_session", "klein_config",
           "load_truth"]
