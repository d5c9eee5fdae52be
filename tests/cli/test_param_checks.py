"""Parameter values are checked before a run starts: every bad value, unknown name and unknown table is
named on its own line (parameter, value, what is allowed), and the command exits 2 before planning anything."""

from __future__ import annotations

import dataclasses

import pytest
from click.testing import CliRunner

import gazepipe.dag
from gazepipe.cli.common import parse_params
from gazepipe.cli.main import cli
from gazepipe.errors import ConfigError
from gazepipe.pipeline.registry import default_params, param_problems, param_rules, value_problem
from gazepipe.stages.build.stage import BuildParams
from gazepipe.stages.clean.stage import CleanParams
from gazepipe.stages.eyes.params import EyesParams
from gazepipe.stages.frames.stage import FramesParams
from gazepipe.stages.sync.stage import SyncParams
from tests.helpers import SAMPLE

gazepipe.dag.declare()   # the stages and their parameters


def run(tmp_path, *args: str):
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["run", str(SAMPLE), "--out", str(out), "--executor", "serial", *args])
    return res, out


def error_lines(res) -> list[str]:
    return [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]


def test_defaults_are_allowed():
    assert param_problems(default_params()) == []
    for cls in (CleanParams, FramesParams, SyncParams, EyesParams, BuildParams):
        for f in dataclasses.fields(cls):
            default = getattr(cls(), f.name)
            if default is not None:
                assert value_problem(default, default, f.metadata) is None, (cls.__name__, f.name)
    assert BuildParams().problems() == []


def test_every_number_parameter_has_a_range():
    rules = param_rules()
    numbers = [k for k, v in default_params().items() if isinstance(v, int | float) and not isinstance(v, bool)]
    numbers += ["clean.lowpass_hz", "build.start_filter_hz"]   # default None (off), a number when set
    assert len(numbers) > 30
    missing = [k for k in numbers if not {"min", "max", "gt", "lt"} & set(rules[k])]
    assert missing == []
    assert set(rules["clean.fill_methods"]["choices"]) == {"rigid", "pca", "pchip", "linear"}
    assert set(rules["frames.triangle"]["choices"]) == {"rigid_fit", "gram_schmidt"}


@pytest.mark.parametrize("param, line", [
    ("clean.max_gap_s=-1", "error: parameter clean.max_gap_s must be a number >= 0, got -1"),
    ('clean.fill_methods=["foo"]', 'error: parameter clean.fill_methods must be a list of one or more of '
                                   '"rigid", "pca", "pchip", "linear", got ["foo"]'),
    ("clean.fill_methods=[]", "error: parameter clean.fill_methods must be a list of one or more of"),
    ("clean.lowpass_hz=-3", "error: parameter clean.lowpass_hz must be a number > 0, got -3"),
    ("build.train_frac=1.5", "error: parameter build.train_frac must be a number in [0, 1], got 1.5"),
    ("build.val_frac=0.5", "error: parameters build.train_frac + build.val_frac must add up to at most 1, "
                           "got 0.8 + 0.5"),
    ("eyes.refit_iterations=2.5", "error: parameter eyes.refit_iterations must be a whole number >= 0, got 2.5"),
    ("eyes.min_confidence=nan", "error: parameter eyes.min_confidence must be a number in [0, 1], got nan"),
    ("frames.triangle=foo", 'error: parameter frames.triangle must be one of "rigid_fit", "gram_schmidt", '
                            'got "foo"'),
    ("face.k=0", "error: parameter face.k must be a whole number >= 1, got 0"),
    ("sync.video_scale=0", "error: parameter sync.video_scale must be a number in (0, 1], got 0"),
    ("clean.lowpass_hz=\"x\"", 'error: parameter clean.lowpass_hz must be a number > 0, got "x"'),
])
@pytest.mark.parametrize("dry", [True, False])
def test_a_bad_value_stops_the_run_before_any_work(tmp_path, param, line, dry):
    res, out = run(tmp_path, "--param", param, *(["--dry-run"] if dry else []))
    assert res.exit_code == 2, res.output
    assert [ln for ln in error_lines(res) if ln.startswith(line)], res.stderr
    assert len(error_lines(res)) == 1 and "Traceback" not in res.output
    assert not out.exists()                     # nothing planned, nothing ran
    assert '"event"' not in res.output and "would" not in res.output


def test_several_bad_values_are_all_named(tmp_path):
    res, out = run(tmp_path, "--dry-run", "--param", "clean.max_gap_s=-1", "--param", "clean.lowpass_hz=-3",
                   "--param", "build.train_frac=1.5")
    assert res.exit_code == 2
    assert [ln.split(" must ")[0] for ln in error_lines(res)] == [
        "error: parameter clean.max_gap_s", "error: parameter clean.lowpass_hz",
        "error: parameter build.train_frac"]


def test_a_params_file_with_several_mistakes_names_them_all(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text('[clean]\nmax_gap = 0.5\nlowpass_hz = -1\nfill_methods = ["rigid", "spline"]\n'
                    '[eye]\nmin_confidence = 0.5\n[build]\ntrain_frac = 0.95\n')
    res, out = run(tmp_path, "--dry-run", "--params", str(path), "--param", "frames.min_plane_ratio=2")
    assert res.exit_code == 2 and not out.exists()
    lines = error_lines(res)
    assert len(lines) == 6, lines
    f = f"error: {path}: "
    assert f"{f}unknown table [eye] (did you mean [eyes]?)" in lines[0]
    assert f"{f}unknown parameter clean.max_gap (did you mean clean.max_gap_s?)" in lines[1]
    assert lines[2] == f"{f}parameter clean.lowpass_hz must be a number > 0, got -1"
    assert lines[3].startswith(f'{f}parameter clean.fill_methods must be a list of one or more of "rigid"')
    assert lines[3].endswith('got ["rigid", "spline"]')
    # from the command line, not the file
    assert lines[4] == "error: parameter frames.min_plane_ratio must be a number in [0, 1], got 2"
    assert lines[5] == f"{f}parameters build.train_frac + build.val_frac must add up to at most 1, got 0.95 + 0.1"


def test_a_value_pair_breaking_a_rule_between_parameters_is_named_once(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text("[build]\ntrain_frac = 0.7\nval_frac = 0.4\n")
    with pytest.raises(ConfigError, match=r"p.toml: parameters build.train_frac \+ build.val_frac must add up to "
                                          r"at most 1, got 0.7 \+ 0.4"):
        parse_params((), str(path))


@pytest.mark.parametrize("key, hint", [
    ("clean.max_gap", "clean.max_gap_s"),
    ("clean.lowpass", "clean.lowpass_hz"),
    ("eyes.max_lag", "eyes.max_lag_s"),
    ("eye.min_confidence", "eyes.min_confidence"),
    ("frames.max_gap_s", "clean.max_gap_s"),
])
def test_a_near_miss_name_gets_a_did_you_mean(key, hint):
    with pytest.raises(ConfigError, match=rf"unknown parameter {key} \(did you mean {hint}\?\)"):
        parse_params((f"{key}=1",), None)


def test_allowed_values_pass_and_numbers_are_normalised():
    values = parse_params(("clean.lowpass_hz=6", "clean.max_gap_s=0", "build.train_frac=1", "build.val_frac=0",
                           'clean.fill_methods=["pchip"]', "frames.triangle=gram_schmidt",
                           "eyes.refit_iterations=0", "sync.max_drift=0.01", "frames.head_segment=neck"), None)
    assert values["clean.lowpass_hz"] == 6.0 and isinstance(values["clean.lowpass_hz"], float)
    assert isinstance(values["clean.max_gap_s"], float) and isinstance(values["eyes.refit_iterations"], int)
    assert values["clean.fill_methods"] == ["pchip"] and values["frames.triangle"] == "gram_schmidt"


def test_run_pipeline_refuses_bad_parameters_before_anything_runs(tmp_path):
    from gazepipe.dag import run_pipeline
    from gazepipe.errors import ConfigError

    out = tmp_path / "out"
    with pytest.raises(ConfigError) as err:
        run_pipeline([], out, params={"clean.nope": 1, "clean.max_gap_s": -1})
    assert "unknown parameter clean.nope" in str(err.value)
    assert "parameter clean.max_gap_s must be a number >= 0, got -1" in str(err.value)
    assert err.value.exit_code == 2 and not out.exists()


@pytest.mark.parametrize("text, found", [
    ("[clean]\nmax_gap_s = " + "[" * 5000 + "]" * 5000 + "\n", "nested too deep"),
    ("[clean]\nmax_gap_s = [[[[[[[[[[[[[[[[[[[[0.5]]]]]]]]]]]]]]]]]]]]\n", "nested too deep"),
    ("[clean\n", "TOML syntax error"),
    ("[clean]\nnote = \"" + "a" * (2 << 20) + "\"\n", "at most 1 MiB"),
])
def test_a_params_file_is_bounded_like_the_session_files(tmp_path, text, found):
    params = tmp_path / "studio.toml"
    params.write_text(text)
    res, _ = run(tmp_path, "--params", str(params), "--dry-run")
    lines = error_lines(res)
    assert res.exit_code == 2 and len(lines) == 1, res.output[-500:]
    assert str(params) in lines[0] and found in lines[0] and len(lines[0]) < 300, lines[0][:300]


def test_a_huge_param_value_is_shown_clipped(tmp_path):
    res, _ = run(tmp_path, "--param", "clean.max_gap_s=" + "[" * 3000 + "]" * 3000, "--dry-run")
    lines = error_lines(res)
    assert res.exit_code == 2 and len(lines) == 1 and "clean.max_gap_s" in lines[0]
    assert "(6002 characters)" in lines[0] and len(lines[0]) < 200, lines[0][:300]
