"""The help of the stage commands teaches: examples, and a --params file that really loads."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from gazepipe.cli.common import parse_params
from gazepipe.cli.main import cli


@pytest.mark.parametrize("name", ["run", "ingest", "clean", "build"])
def test_stage_help_shows_examples_and_a_valid_params_file(name, tmp_path):
    text = CliRunner().invoke(cli, [name, "--help"]).output
    assert f"gazepipe {name} sample_data/session01 --out out/" in text
    lines = text.split("A --params file has one table per stage")[1].split("Options:")[0].splitlines()[1:]
    toml = "\n".join(ln.strip() for ln in lines if ln.strip())
    assert "[clean]" in toml
    path = tmp_path / "p.toml"
    path.write_text(toml)
    values = parse_params((), str(path))
    assert values["clean.max_gap_s"] == 0.5 and values["build.train_frac"] == 0.8
    assert values["clean.fill_methods"] == ["rigid", "pca", "pchip"]


def test_params_lists_every_default_with_what_it_accepts_as_loadable_toml(tmp_path):
    """`gazepipe params` prints TOML (dotted keys, comments): a file of it loads back as the defaults."""
    from gazepipe.pipeline.registry import default_params

    text = CliRunner().invoke(cli, ["params"]).output
    assert "clean.max_gap_s = 3.0" in text and "# a number >= 0" in text
    path = tmp_path / "all.toml"
    path.write_text(text)
    values = parse_params((), str(path))
    assert values == {k: v for k, v in default_params().items() if v is not None}
    assert "# clean.lowpass_hz = (off by default)" in text


def test_a_file_system_refusal_is_one_line_naming_the_file_not_an_internal_error():
    import click

    from gazepipe.cli.common import handle_errors

    @click.command()
    @handle_errors
    def cmd() -> None:
        raise FileExistsError(17, "File exists", "/some/out")

    res = CliRunner().invoke(cmd, [])
    assert res.exit_code == 1
    assert res.output.strip() == "error: /some/out: File exists"


def test_fill_and_run_fill_the_same_gaps_by_default():
    """``gazepipe fill`` and ``fill_capture`` default to the clean stage's ``max_gap_s``, not a length of their own."""
    import inspect

    import click

    from gazepipe.cli.main import fill
    from gazepipe.stages.clean.stage import CleanParams
    from gazepipe.stages.clean.standalone import fill_capture

    option = next(p for p in fill.params if p.name == "max_gap_s")
    assert option.get_default(click.Context(fill)) == CleanParams().max_gap_s
    assert inspect.signature(fill_capture).parameters["max_gap_s"].default == CleanParams().max_gap_s
