"""The clean stage cleaning the caller's positions in place (the clean unit's way: a long take's positions held
once) gives what it gives on its own copy, to the bit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gazepipe.io.capture import read_markers
from gazepipe.io.session_toml import load_session
from gazepipe.stages.clean.stage import clean_markers
from tests.helpers import SAMPLE


def test_cleaning_in_place_gives_the_same_result_as_on_a_copy():
    ses = load_session(SAMPLE / "session.toml")
    take = next(t for t in ses.takes if t.id == "follow_standing_01")
    raw = read_markers(take.mocap)
    raw.xyz[5:9, 2] = np.inf                     # not finite though marked valid: made a gap either way
    given = replace(raw, xyz=raw.xyz.copy(), valid=raw.valid.copy())
    ref = clean_markers(raw, ses.markerset, take.kind)
    np.testing.assert_array_equal(raw.xyz, given.xyz, "without in_place the caller's positions are not touched")
    np.testing.assert_array_equal(raw.valid, given.valid)
    work = replace(raw, xyz=raw.xyz.copy(), valid=raw.valid.copy())
    res = clean_markers(work, ses.markerset, take.kind, in_place=True)
    assert np.shares_memory(res.markers.xyz, work.xyz), "the result's rows are the caller's array"
    for name in ("frames", "fill_code", "spike", "fill_error_mm", "speed_mm_s", "neutral_fill_code"):
        np.testing.assert_array_equal(getattr(res, name), getattr(ref, name), name)
    np.testing.assert_array_equal(res.markers.xyz, ref.markers.xyz)
    np.testing.assert_array_equal(res.markers.valid, ref.markers.valid)
    assert ref.neutral is not None and res.neutral is not None
    np.testing.assert_array_equal(res.neutral.xyz, ref.neutral.xyz)
    assert (res.crop, res.rests, res.qc) == (ref.crop, ref.rests, ref.qc)
