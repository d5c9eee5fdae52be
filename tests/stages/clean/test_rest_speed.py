"""The clean stage records the rest-speed trace its rests and crop were found on (``rest_speed``), so the report
plots what the stage used instead of recomputing it (SPEC §7)."""

from __future__ import annotations

import io

import numpy as np
import pyarrow.parquet as pq

from gazepipe.dag import run_pipeline
from gazepipe.io.session_toml import load_session
from gazepipe.pipeline.events import EventLog


def test_the_rest_speed_trace_is_the_subjects_speed_on_every_frame_of_the_take(tiny_session, tmp_path):
    out = tmp_path / "out"
    summary = run_pipeline([load_session(tiny_session / "session.toml")], out, executor="serial", until="clean",
                           log=EventLog(fmt="json", stream=io.StringIO()))
    assert summary.exit_code == 0, [o.error for o in summary.failed]
    table = pq.read_table(out / "takes" / "tiny" / "t0" / "rest_speed.parquet")
    assert table.column("frame").to_pylist() == list(range(90))          # the uncropped take: 90 frames
    speed = table.column("speed_mm_s").to_numpy(zero_copy_only=False)
    # the tiny subject sways 20 mm along (1, 0.5, 0) at 0.3 Hz (tests/conftest.py tiny_motion): its markers'
    # mean speed is 20·2π·0.3·√1.25·|cos(2π·0.3·t + φ)| mm/s; the phase comes from the seed, so compare the
    # trace's shape through its peak (the stage smooths at rest_filter_hz = 1.75 Hz, far above 0.3 Hz)
    inner = speed[10:-10]
    assert np.isfinite(inner).all()
    peak = 20 * 2 * np.pi * 0.3 * np.sqrt(1.25)
    assert abs(np.max(inner) - peak) < 0.1 * peak, (np.max(inner), peak)
    assert np.min(inner) < 0.3 * peak     # it slows down at each end of the sway
