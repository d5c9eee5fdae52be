"""Shared fixtures: a tiny hand-made session, the README examples' working folder, and the outputs built once
per test run and shared read-only (``sample_run`` and ``sample_process_run``: ``gazepipe run`` on the sample
session, serial and in worker processes; ``generated_datasets``: the small datasets of
:mod:`tests.helpers.datasets`). The helpers they use are in :mod:`tests.helpers`."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.helpers import SAMPLE, make_tiny_session, tree_digest
from tests.helpers.shared import REGISTRY, changes, shared_folder


def _run_sample(folder: Path) -> None:
    from click.testing import CliRunner

    from gazepipe.cli.main import cli

    res = CliRunner().invoke(cli, ["run", str(SAMPLE), "--out", str(folder / "out"), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code == 0, res.output[-3000:]


def _run_sample_twice_in_processes(folder: Path) -> None:
    """The process executor's run, then the same command again with nothing changed: what the second one said,
    and the digests of the products before and after it, in ``second_run.json``."""
    from click.testing import CliRunner

    from gazepipe.cli.main import cli
    from tests.helpers.sample import PRODUCT_PARTS

    out = folder / "out"
    args = ["run", str(SAMPLE), "--out", str(out), "--executor", "process", "--log-format", "json"]
    first = CliRunner().invoke(cli, args)
    assert first.exit_code == 0, first.output[-3000:]
    before = tree_digest(out, PRODUCT_PARTS)
    second = CliRunner().invoke(cli, args)
    after = tree_digest(out, PRODUCT_PARTS)
    (folder / "second_run.json").write_text(json.dumps({"exit_code": second.exit_code, "output": second.output,
                                                        "before": before, "after": after}))


def _build_generated_datasets(folder: Path) -> None:
    from tests.helpers.datasets import make_datasets

    make_datasets(folder)


@pytest.fixture(scope="session")
def sample_run(tmp_path_factory) -> Path:
    """``OUT`` of ``gazepipe run sample_data/session01 --out OUT --executor serial`` (exit 0), built once per test
    run. Read only: a test that changes outputs copies this folder (``shutil.copytree``) or runs its own."""
    return shared_folder(tmp_path_factory, "sample_run", _run_sample) / "out"


@pytest.fixture(scope="session")
def sample_process_run(tmp_path_factory) -> dict:
    """``gazepipe run sample_data/session01 --out OUT --executor process`` (exit 0), then the same command again
    with nothing changed, once per test run: ``{"out": OUT, "second": its exit_code and output, "before": ...,
    "after": ...}`` (digests of the products before and after the second run). Read only."""
    folder = shared_folder(tmp_path_factory, "sample_process_run", _run_sample_twice_in_processes)
    second = json.loads((folder / "second_run.json").read_text())
    return {"out": folder / "out", "second": SimpleNamespace(exit_code=second["exit_code"], output=second["output"]),
            "before": second["before"], "after": second["after"]}


@pytest.fixture(scope="session")
def generated_datasets(tmp_path_factory) -> Path:
    """The datasets folder of :func:`tests.helpers.datasets.make_datasets`, built once per test run. Read only."""
    return shared_folder(tmp_path_factory, "generated_datasets", _build_generated_datasets) / "datasets"


@pytest.fixture(autouse=True)
def _shared_outputs_unchanged(request):
    """After each test that used a shared output: the output is what was built (the test fails otherwise)."""
    yield
    used = set(request.fixturenames)
    for name, (fixture, folder, recorded) in sorted(REGISTRY.items()):
        if fixture in used:
            diff = changes(folder, recorded)
            assert not diff, f"{request.node.nodeid} changed the shared {name} output: {diff[:20]}"


@pytest.fixture(scope="session", autouse=True)
def _shared_outputs_unchanged_at_the_end():
    """At the end of the run (of each pytest-xdist worker): every shared output this process used is what was
    built."""
    yield
    changed = {name: diff for name, (_, folder, recorded) in sorted(REGISTRY.items())
               if (diff := changes(folder, recorded))}
    assert not changed, f"shared outputs changed during the run: {changed}"


@pytest.fixture
def tiny_session(tmp_path: Path) -> Path:
    return make_tiny_session(tmp_path / "tiny")


@pytest.fixture
def workdir(datasets, tmp_path, monkeypatch) -> Path:
    """A folder with out/datasets as `gazepipe run ... --out out` leaves it, for the README examples to run from
    (``datasets``: the requesting module's built datasets folder)."""
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "datasets").symlink_to(datasets, target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    return tmp_path
