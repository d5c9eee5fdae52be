"""Rates as files and settings state them (issue 46): an NTSC rate written rounded is exact, any other rate is
taken as written, and a rate implausible for its kind of track is noted with what to do."""

from __future__ import annotations

import numpy as np
import pytest

from gazepipe.io.c3d import read_c3d, write_c3d
from gazepipe.io.capture import inspect_capture, read_markers
from gazepipe.io.livelinkface import read_livelinkface
from gazepipe.io.openface import read_openface
from gazepipe.io.session_toml import load_session
from gazepipe.model import Markers
from gazepipe.timebase import implausible_rate, snap_rate, stated_rate
from tests.helpers import REPO, TESTS

CORPUS = TESTS / "data" / "corpus"


@pytest.mark.parametrize(("written", "rate"), [
    ("29.97", 30000 / 1001), ("29.970", 30000 / 1001), ("59.94", 60000 / 1001), ("59.9", 60000 / 1001),
    ("119.88", 120000 / 1001), ("23.976", 24000 / 1001), ("23.98", 24000 / 1001), ("47.952", 48000 / 1001),
    ("239.76", 240000 / 1001), ("29.97002997002997", 30000 / 1001),
    # written as the file means them: no NTSC rate near (N = 70, 25), or the whole rate itself within rounding
    ("69.9", 69.9), ("69.93", 69.93), ("24.975", 24.975), ("60", 60.0), ("30.0", 30.0), ("29.9", 29.9),
    ("100", 100.0), ("120", 120.0), ("250", 250.0),
])
def test_stated_rates_are_taken_as_written_unless_an_ntsc_rate_written_rounded(written, rate):
    assert stated_rate(written) == rate
    assert stated_rate(float(written)) == rate            # a TOML or command-line number: its shortest decimal


def test_c3d_rates_are_read_as_their_four_byte_real_states_them(tmp_path):
    """A C3D stores its rate as a 4-byte real: 69.9 Hz is 69.9 Hz (not 70·1000/1001 = 69.9301 Hz, which would
    move a 10-minute take by 0.26 s), 29.97 and the 4-byte 30000/1001 are 30000/1001 Hz; times follow."""
    xyz = np.random.default_rng(0).normal(size=(600, 2, 3)) * 100.0 + 500.0
    for rate, want in ((69.9, 69.9), (29.97, 30000 / 1001), (30000 / 1001, 30000 / 1001), (100.0, 100.0)):
        p = tmp_path / f"r{rate}.c3d"
        write_c3d(p, Markers(labels=["A", "B"], xyz=xyz, valid=np.ones((600, 2), bool), rate_hz=rate))
        m = read_c3d(p)
        assert m.rate_hz == want
        assert inspect_capture(p)["rate_hz"] == want
        np.testing.assert_allclose(m.time_s[-1], 599 / want, rtol=0, atol=1e-12)
        assert not any("Hz" in w for w in m.warnings)


@pytest.mark.parametrize(("cell", "rate"), [("69.9", 69.9), ("29.97", 30000 / 1001), ("100", 100.0)])
def test_text_exports_state_their_rate(tmp_path, cell, rate):
    vicon = (f"Trajectories\n{cell}\n,,S:A,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n"
             + "".join(f"{i + 1},0,{i}.5,2,3\n" for i in range(5)))
    (tmp_path / "v.csv").write_text(vicon)
    assert read_markers(tmp_path / "v.csv").rate_hz == rate
    qtm = (f"NO_OF_FRAMES\t2\nNO_OF_MARKERS\t1\nFREQUENCY\t{cell}\nMARKER_NAMES\tA\n"
           "Frame\tTime\tA X\tA Y\tA Z\n1\t0\t1\t2\t3\n2\t0.01\t1\t2\t3\n")
    (tmp_path / "q.tsv").write_text(qtm)
    assert read_markers(tmp_path / "q.tsv").rate_hz == rate


def test_given_rates_are_taken_as_written(tmp_path):
    wide = "frame,A_x,A_y,A_z\n" + "".join(f"{i},{i}.5,2,3\n" for i in range(5))
    (tmp_path / "w.csv").write_text(wide)
    assert read_markers(tmp_path / "w.csv", rate_hz=69.9).rate_hz == 69.9
    assert read_markers(tmp_path / "w.csv", rate_hz=29.97).rate_hz == 30000 / 1001
    ft = read_livelinkface(CORPUS / "livelinkface" / "alex_rom_3_first300.csv", rate_hz=29.97)
    assert ft.rate_hz == 30000 / 1001


def test_session_rates_are_taken_as_written(tmp_path):
    (tmp_path / "f.csv").write_text((CORPUS / "livelinkface" / "alex_rom_3_first300.csv").read_text())
    (tmp_path / "session.toml").write_text(
        'schema = 1\n[session]\nsubject = "p"\n'
        '[[takes]]\nid = "a"\nkind = "face"\ntracked = "f.csv"\nclean = "f.csv"\nrate_hz = 29.97\n'
        '[[takes]]\nid = "b"\nkind = "face"\ntracked = "f.csv"\nclean = "f.csv"\nrate_hz = 25\n'
        'timecode_fps = 59.94\n')
    s = load_session(tmp_path)
    assert s.take("a").rate_hz == 30000 / 1001 and s.take("a").timecode_fps == 60.0
    assert s.take("b").rate_hz == 25.0 and s.take("b").timecode_fps == 60000 / 1001


def test_measured_rates_snap_only_to_rates_that_exist():
    """A rate measured from timestamps snaps to N·1000/1001 only for an N that has an NTSC variant."""
    assert snap_rate(59.9405) == 60000 / 1001
    assert snap_rate(119.879) == 120000 / 1001
    assert snap_rate(69.93) == 69.93                     # 70 Hz has no NTSC variant
    assert snap_rate(60.0) == 60.0 and snap_rate(59.5) == 59.5


def test_openface_with_millisecond_frame_numbers_for_timestamps_is_flagged():
    """The real py-feat file steps 1 ms a frame: 1000 Hz is no face camera's rate; the warning says what to do."""
    eye = read_openface(CORPUS / "openface" / "pyfeat_OpenFace_Test.csv")
    odd = [w for w in eye.warnings if "1000 Hz" in w]
    assert len(odd) == 1 and "1 ms" in odd[0] and "FeatureExtraction" in odd[0] and "frame rate" in odd[0]
    # a 60 Hz file with millisecond timestamps (the bundled sample) is not flagged
    sample = REPO / "sample_data" / "session01" / "eyes" / "follow_sitting_01.csv"
    assert not any("implausible" in w for w in read_openface(sample).warnings)


def test_implausible_rates_by_kind(tmp_path):
    assert implausible_rate(1000.0, "video") and implausible_rate(2.0, "video")
    assert implausible_rate(60.0, "video") is None and implausible_rate(240.0, "video") is None
    assert implausible_rate(120.0, "face") and implausible_rate(60000 / 1001, "face") is None
    assert implausible_rate(5.0, "mocap") and implausible_rate(2000.0, "mocap") is None
    # a Live Link Face take said to run at 120 Hz: ARKit tracks faces at 60 Hz at most
    ft = read_livelinkface(CORPUS / "livelinkface" / "alex_rom_3_first300.csv", rate_hz=120)
    assert any("implausible for ARKit face tracking" in w and "rate_hz" in w for w in ft.warnings)
    # a marker capture at 5 Hz is read, with a note
    p = tmp_path / "slow.c3d"
    write_c3d(p, Markers(labels=["A"], xyz=np.ones((20, 1, 3)), valid=np.ones((20, 1), bool), rate_hz=5.0))
    assert any("implausible for a marker capture" in w for w in read_c3d(p).warnings)
