"""Shared fixtures: a tiny hand-made session, the README examples' working folder, and the outputs built once
per test run and shared read-only (``generated_datasets``: the small datasets of :mod:`tests.helpers.datasets`).
The helpers they use are in :mod:`tests.helpers`."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers import make_tiny_session
from tests.helpers.shared import build_once, changes

#: shared outputs by fixture name: every test that uses one (directly or through another fixture) fails if the
#: folder differs afterwards from what was built
_SHARED: dict[str, tuple[Path, dict[str, list]]] = {}


def _build_generated_datasets(folder: Path) -> None:
    from tests.helpers.datasets import make_datasets

    make_datasets(folder)


@pytest.fixture(scope="session")
def generated_datasets(tmp_path_factory) -> Path:
    """The datasets folder of :func:`tests.helpers.datasets.make_datasets`, built once per test run. Read only."""
    folder, recorded = build_once(tmp_path_factory, "generated_datasets", _build_generated_datasets)
    _SHARED["generated_datasets"] = (folder, recorded)
    yield folder / "datasets"
    assert not changes(folder, recorded), "the shared generated datasets changed"


@pytest.fixture(autouse=True)
def _shared_outputs_unchanged(request):
    """After each test that used a shared output: the output is what was built (the test fails otherwise)."""
    yield
    for name in _SHARED.keys() & set(request.fixturenames):
        folder, recorded = _SHARED[name]
        diff = changes(folder, recorded)
        assert not diff, f"{request.node.nodeid} changed the shared {name} output: {diff[:20]}"


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
