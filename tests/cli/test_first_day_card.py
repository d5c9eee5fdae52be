"""The dataset card a new user reads first: units of every column, the mirrored copies and the frame rate."""

from __future__ import annotations

from gazepipe.io.dataset_card import card_text, column_units

FACE = {"name": "face_clean", "fps": None, "rates_hz": [60.0, 30.0],
        "features": {"tracked": ["tracked.a"], "tracked_d1": ["tracked_d1.a"], "clean": ["clean.a"],
                     "clean_d1": ["clean_d1.a"]},
        "units": {"tracked": "blendshape coefficient", "tracked_dK": "1/s^K", "clean": "blendshape coefficient",
                  "clean_dK": "1/s^K", "time_s": "s"},
        "identifiers": ["subject", "take", "mirrored", "frame", "time_s"], "params": {"mirror": True}}


def test_derivative_columns_have_units():
    text = card_text(FACE, "a: 1\n")
    rows = {ln.split("|")[1].strip(): ln.split("|")[3].strip() for ln in text.splitlines() if ln.startswith("| `")}
    assert rows["`tracked_d1`"].startswith("1/s (per second of the blendshape coefficient")
    assert rows["`clean_d1`"].startswith("1/s (per second")
    assert column_units(FACE["units"], "tracked_d2").startswith("1/s^2")
    assert column_units(FACE["units"], "other") == ""


def test_card_says_rows_are_mirrored_and_gives_the_frame_rate():
    text = card_text(FACE, "a: 1\n")
    assert "mirrored copy: column `mirrored`" in text
    assert "Frame rates: 30, 60 Hz" in text
    one = card_text({**FACE, "fps": 29.97002997002997}, "a: 1\n")
    assert "Frame rate: 29.97 Hz." in one
    plain = card_text({**FACE, "params": {"mirror": False}}, "a: 1\n")
    assert "mirrored copy" not in plain
