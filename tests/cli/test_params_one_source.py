"""One form for parameters: each stage's parameters dataclass is the one source of their names, defaults, value
rules and help, for `gazepipe run` (the units' parameters), `gazepipe params` and `gazepipe fill`."""

from __future__ import annotations

import dataclasses

import click
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli


@pytest.fixture(scope="module")
def classes() -> dict[str, type]:
    import gazepipe.dag
    from gazepipe.pipeline.registry import param_classes

    gazepipe.dag.declare()   # the stages and their parameters

    return param_classes()


def test_every_stage_with_parameters_declares_a_dataclass(classes):
    from gazepipe.pipeline.registry import default_params, defaults_of

    assert set(classes) == {"clean", "frames", "face", "sync", "eyes", "build"}
    # the engine's parameters (the units' fingerprints) are exactly the dataclasses' fields and defaults
    assert default_params() == {f"{g}.{k}": v for g, cls in classes.items() for k, v in defaults_of(cls).items()}


def test_params_shows_every_field_with_its_default_and_its_help(classes):
    from gazepipe.pipeline.registry import helps_of, show_value

    lines = CliRunner().invoke(cli, ["params"]).output.splitlines()
    for group, cls in classes.items():
        helps = helps_of(cls)
        for f in dataclasses.fields(cls):
            assert helps.get(f.name, "").strip(), f"{group}.{f.name} has no help in its metadata"
            default = getattr(cls(), f.name)
            shown = (f"{group}.{f.name} = {show_value(list(default) if isinstance(default, tuple) else default)}"
                     if default is not None else f"# {group}.{f.name} = (off by default)")
            i = next((i for i, ln in enumerate(lines) if ln.startswith(shown + " ")), None)
            assert i is not None, shown
            assert lines[i - 1] == f"# {helps[f.name]}", f"{group}.{f.name}"


def test_a_units_parameters_are_built_whole_from_their_values():
    from gazepipe.pipeline.registry import defaults_of, params_from
    from gazepipe.stages.clean.stage import CleanParams

    assert params_from(CleanParams, defaults_of(CleanParams)) == CleanParams()
    got = params_from(CleanParams, {"max_gap_s": 0.5, "fill_methods": ["pchip"], "not_a_field": 1})
    assert got == dataclasses.replace(CleanParams(), max_gap_s=0.5, fill_methods=("pchip",))


def test_fill_and_run_get_the_same_clean_parameters():
    """Every CleanParams field: `gazepipe fill` with no option fills with `gazepipe run`'s default, but the
    fields it deliberately keeps off (FILL_OVERRIDES: a file filler keeps measured samples unless asked)."""
    from gazepipe.cli.param_help import FILL_OVERRIDES, fill_params
    from gazepipe.pipeline.registry import default_params
    from gazepipe.stages.clean.stage import CleanParams

    command = cli.commands["fill"]
    ctx = click.Context(command)
    given = {p.name: p.get_default(ctx) for p in command.params
             if p.name in {f.name for f in dataclasses.fields(CleanParams)}}
    assert set(given) >= {"max_gap_s", "remove_spikes", "repair_swaps", "fill_unlabeled"}
    filled = fill_params(**given)
    run = default_params()
    assert set(FILL_OVERRIDES) == {"remove_spikes", "repair_swaps"}
    for f in dataclasses.fields(CleanParams):
        value = getattr(filled, f.name)
        expected = FILL_OVERRIDES.get(f.name, run[f"clean.{f.name}"])
        assert (list(value) if isinstance(value, tuple) else value) == expected, f.name
    # an option given wins; its help and default come from the dataclass
    assert fill_params(max_gap_s=0.5).max_gap_s == 0.5
    text = CliRunner().invoke(cli, ["fill", "--help"]).output
    assert "clean.max_gap_s" in " ".join(text.split()) and f"default: {CleanParams().max_gap_s}" in text
