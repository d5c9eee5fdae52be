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
