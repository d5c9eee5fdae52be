"""One BLAS thread around every unit (gazepipe.blas): the pools really are limited, and the scan of the
process's libraries is kept between units."""

from __future__ import annotations

from threadpoolctl import threadpool_info

from gazepipe import blas


def test_every_pool_has_one_thread_inside_and_is_given_back_after() -> None:
    before = {(p["filepath"], p["num_threads"]) for p in threadpool_info()}
    with blas.one_blas_thread():
        inside = threadpool_info()
        assert inside, "no BLAS pool found (numpy and scipy each ship one)"
        assert all(p["num_threads"] == 1 for p in inside)
    assert {(p["filepath"], p["num_threads"]) for p in threadpool_info()} == before


def test_the_scan_is_reused_until_a_module_is_imported() -> None:
    with blas.one_blas_thread():
        pass
    first = blas._scan
    with blas.one_blas_thread():
        pass
    assert blas._scan is first
    import importlib
    import sys

    sys.modules.pop("json.tool", None)
    importlib.import_module("json.tool")          # a new module: the libraries may have changed
    with blas.one_blas_thread():
        pass
    assert blas._scan is not first
