"""``gazepipe train``: every ``--option`` typed and range-checked from the trainer's declarations, the options
listed in the help, an --out folder that already holds something refused without --force, and a run id on
every JSON log event."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.trainers.base import Option, TrainOptions, check_options, load_trainer


@pytest.fixture(scope="module")
def datasets(generated_datasets) -> Path:
    return generated_datasets


def train(*args: str):
    return CliRunner().invoke(cli, ["train", *args])


@pytest.mark.parametrize("trainer, pair, allowed", [
    ("gaze_rnn", "residual=False", None),
    ("gaze_rnn", "residual=no", None),
    ("gaze_rnn", "residual=maybe", "residual must be true or false"),
    ("gaze_rnn", "residual=2", "residual must be true or false"),
    ("gaze_rnn", "clip=-1", "clip must be a number >= 0"),
    ("gaze_rnn", "threads=0", "threads must be a whole number >= 1"),
    ("gaze_rnn", "threads=abc", "threads must be a whole number >= 1"),
    ("gaze_rnn", "threads=1.5", "threads must be a whole number >= 1"),
    ("gaze_rnn", "schedule=linear", "schedule must be one of cosine, constant"),
    ("gaze_rnn", "max_seconds=nan", "max_seconds must be a number > 0"),
    ("face_clean", "dropout=1", "dropout must be a number in [0, 1)"),
    ("gaze_map", "k=0", "k must be a whole number >= 1"),
    ("gaze_map", "train_split=all", "train_split must be one of train, val, test"),
])
def test_a_bad_option_value_is_a_usage_error_naming_option_value_and_range(datasets, tmp_path, trainer, pair,
                                                                           allowed):
    data = {"gaze_rnn": "gaze_rnn_lod"}.get(trainer, trainer)
    if allowed is None:   # accepted spellings of a boolean: typed, not truthy text
        opts = TrainOptions(extra={pair.split("=")[0]: pair.split("=")[1]})
        check_options(load_trainer(trainer), opts)
        assert opts.extra == {"residual": False}
        return
    res = train(trainer, "--data", str(datasets / data), "--out", str(tmp_path / "m"), "--option", pair)
    assert res.exit_code == 2, res.output
    assert res.output.count("\n") == 1 and "internal error" not in res.output
    assert f"--option {pair}: {allowed}" in res.output
    assert not (tmp_path / "m").exists()


def test_options_are_typed_from_the_declaration():
    t = load_trainer("gaze_rnn")
    opts = TrainOptions(extra={"residual": "TRUE", "clip": "0", "threads": "2", "l2": "1e-4",
                               "schedule": "constant"})
    check_options(t, opts)
    assert opts.extra == {"residual": True, "clip": 0.0, "threads": 2, "l2": 1e-4, "schedule": "constant"}
    assert isinstance(opts.extra["threads"], int) and isinstance(opts.extra["clip"], float)
    for bad in ({"residual": 1}, {"threads": True}, {"threads": 2.0}):   # through the API: the types too
        with pytest.raises(Exception, match="must be"):
            check_options(t, TrainOptions(extra=dict(bad)))
    with pytest.raises(Exception, match="has no option nope"):
        check_options(t, TrainOptions(extra={"nope": "1"}))


def test_every_builtin_option_is_declared_with_type_default_range_and_help():
    for name in ("gaze_map", "gaze_rnn", "face_clean"):
        for key, decl in load_trainer(name).options.items():
            assert isinstance(decl, Option) and decl.name == key and decl.help
            assert decl.type in (bool, int, float, str)
            if decl.default is not None:
                assert decl.parse(decl.default) == decl.default
            if decl.type in (int, float):
                assert decl.min is not None, key


def test_help_lists_each_trainers_options_with_type_default_and_range():
    text = CliRunner().invoke(cli, ["train", "--help"], terminal_width=200).output
    assert "--option for gaze_rnn:" in text and "--option for face_clean:" in text
    assert "residual (bool, default true; true or false)" in text
    assert "clip (float, default 1; a number >= 0)" in text
    assert "k (int, default 4; a whole number >= 1)" in text
    assert "dropout (float, default 0.3; a number in [0, 1))" in text


def test_train_refuses_a_folder_that_holds_a_model_unless_force(datasets, tmp_path):
    out = tmp_path / "m"
    args = ["gaze_map", "--data", str(datasets / "gaze_map"), "--out", str(out)]
    assert train(*args).exit_code == 0
    before = (out / "model.json").stat().st_mtime_ns
    res = train(*args)
    assert res.exit_code == 2 and res.output.count("\n") == 1
    assert str(out) in res.output and "--force" in res.output
    assert (out / "model.json").stat().st_mtime_ns == before
    res = train(*args, "--force")
    assert res.exit_code == 0, res.output
    (tmp_path / "f").write_text("x")
    res = train("gaze_map", "--data", str(datasets / "gaze_map"), "--out", str(tmp_path / "f"))
    assert res.exit_code == 2 and "is a file" in res.output


def test_train_json_log_events_carry_a_run_id(datasets, tmp_path):
    pytest.importorskip("torch")
    res = train("gaze_rnn", "--data", str(datasets / "gaze_rnn_lod"), "--out", str(tmp_path / "m"), "--epochs",
                "1", "--hidden", "4", "--device", "cpu", "--option", "threads=1", "--option", "max_windows=4",
                "--log-format", "json")
    assert res.exit_code == 0, res.output
    events = [json.loads(ln) for ln in res.stderr.splitlines() if ln.startswith("{")]
    assert events and {e["event"] for e in events} >= {"epoch", "train_end"}
    ids = {e["run_id"] for e in events}
    assert len(ids) == 1 and ids.pop() != ""
