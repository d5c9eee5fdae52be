"""A long take's markers tables read and written a row group at a time (issue 47): the same arrays and the same
bytes as the whole tables, the rows checked as they pass, and nothing half-written when a batch fails."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from gazepipe.dag.store import read_stored_batches, write_stored_table
from gazepipe.errors import SchemaError
from gazepipe.io.parquet import ROW_GROUP_ROWS, read_batches, write_batches, write_table
from gazepipe.model import Markers
from gazepipe.pipeline.registry import TableBatches
from gazepipe.schemas.clean_tables import clean_tables
from gazepipe.schemas.markers import (
    MARKERS_CLEAN,
    MARKERS_RAW,
    MarkersBatches,
    batches_to_markers,
    checked_markers_batches,
    markers_batches,
    markers_to_table,
    table_to_markers,
)


def _take(frames: int, markers: int = 3, seed: int = 0) -> Markers:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(0.0, 300.0, (frames, markers, 3))
    valid = rng.random((frames, markers)) > 0.05
    xyz[~valid] = np.nan
    return Markers(labels=[f"m{i}" for i in range(markers)], xyz=xyz, valid=valid, rate_hz=120.0, first_frame=7)


def _columns(mk: Markers, seed: int = 1) -> dict:
    rng = np.random.default_rng(seed)
    err = np.where(rng.random(mk.valid.shape) < 0.1, rng.random(mk.valid.shape), np.nan)
    return {"frames": np.arange(5, 5 + mk.n_frames), "fill_code": rng.integers(0, 4, mk.valid.shape, dtype=np.int8),
            "spike": rng.random(mk.valid.shape) < 0.01, "fill_error_mm": err, "meta": {"crop": [5, 9]}}


@pytest.fixture(scope="module")
def long_take() -> Markers:
    """A take of more than one row group (1.2 million samples)."""
    return _take(400_000)


def test_a_table_written_in_batches_of_any_size_has_the_bytes_of_the_whole_table(long_take, tmp_path):
    cols = _columns(long_take)
    whole = markers_to_table(long_take, **cols)
    assert whole.num_rows > ROW_GROUP_ROWS
    write_table(whole.combine_chunks(), tmp_path / "whole.parquet", MARKERS_CLEAN)   # one chunk, as it was made
    expected = (tmp_path / "whole.parquet").read_bytes()
    for rows in (ROW_GROUP_ROWS, 300_001, 5_000_000):
        schema, n, batches = markers_batches(long_take, **cols, rows=rows)
        assert n == whole.num_rows
        write_batches(schema, batches, tmp_path / f"{rows}.parquet", MARKERS_CLEAN)
        assert (tmp_path / f"{rows}.parquet").read_bytes() == expected, rows
    write_table(whole, tmp_path / "chunked.parquet", MARKERS_CLEAN)          # a chunk per row group
    assert (tmp_path / "chunked.parquet").read_bytes() == expected


def test_an_empty_table_in_batches_has_the_bytes_of_the_empty_table(tmp_path):
    mk = _take(0)
    write_table(markers_to_table(mk), tmp_path / "a.parquet", MARKERS_RAW)
    schema, _, batches = markers_batches(mk)
    write_batches(schema, batches, tmp_path / "b.parquet", MARKERS_RAW)
    write_batches(schema, iter(()), tmp_path / "c.parquet", MARKERS_RAW)
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes() \
        == (tmp_path / "c.parquet").read_bytes()


def test_a_table_read_a_row_group_at_a_time_gives_the_arrays_of_the_whole_table(long_take, tmp_path):
    path = tmp_path / "markers_raw.parquet"
    write_table(markers_to_table(long_take), path, MARKERS_RAW)
    stored = read_stored_batches(path, "markers_raw")
    mk, frames = batches_to_markers(stored.schema, stored.num_rows, stored.batches)
    ref, ref_frames, _, _ = table_to_markers(markers_to_table(long_take))
    np.testing.assert_array_equal(mk.xyz, ref.xyz)
    np.testing.assert_array_equal(mk.valid, ref.valid)
    np.testing.assert_array_equal(frames, ref_frames)
    assert (mk.labels, mk.rate_hz, mk.first_frame) == (ref.labels, ref.rate_hz, ref.first_frame)


def _batches(table: pa.Table, rows: int = 1000) -> tuple[pa.Schema, int, list[pa.RecordBatch]]:
    return table.schema, table.num_rows, table.to_batches(rows)


def test_rows_out_of_order_or_short_fail_as_they_are_read():
    table = markers_to_table(_take(2500))
    assert len(list(checked_markers_batches(*_batches(table)))) == 8
    swapped = pa.concat_tables([table.slice(2500, 2500), table.slice(0, 2500), table.slice(5000)])
    with pytest.raises(SchemaError, match="marker-major"):
        list(checked_markers_batches(*_batches(swapped)))
    frames = table.column("frame").to_numpy().copy()
    frames[6000] += 1
    moved = table.set_column(1, table.schema.field("frame"), pa.array(frames))
    with pytest.raises(SchemaError, match="share the same frames"):
        list(checked_markers_batches(*_batches(moved)))
    schema, n, batches = _batches(table)
    with pytest.raises(SchemaError, match="rows read"):
        list(checked_markers_batches(schema, n, batches[:-1]))
    with pytest.raises(SchemaError, match="whole frames"):     # the metadata, before any batch is read
        checked_markers_batches(schema, n + 1, batches)


def test_a_file_of_another_table_is_refused_before_its_rows_are_read(tmp_path):
    path = tmp_path / "markers_raw.parquet"
    write_table(markers_to_table(_take(10), **_columns(_take(10))), path, MARKERS_CLEAN)
    with pytest.raises(SchemaError, match="expected a 'markers_raw' table"):
        read_stored_batches(path, "markers_raw")


def test_a_batch_that_fails_part_way_leaves_no_file(long_take, tmp_path):
    """The engine's atomic write of a unit's tables: a table given in batches that fails after a row group is
    written leaves neither its final file nor a temporary."""
    from gazepipe.pipeline.registry import TableStore
    from gazepipe.pipeline.runner import _write_tables

    schema, n, batches = markers_batches(long_take, rows=ROW_GROUP_ROWS)

    def failing():
        yield next(batches)
        raise RuntimeError("the stage's arrays went away")

    store = TableStore(write=write_stored_table, read=lambda p: pa.table({}), check=lambda *a: None)
    final, tmp = tmp_path / "out" / "markers.parquet", tmp_path / "tmp"
    with pytest.raises(RuntimeError):
        _write_tables({"markers": (TableBatches(schema, n, failing()), MARKERS_RAW)}, lambda name: final, tmp,
                      store, [])
    assert not final.exists() and not any(tmp.iterdir())


def test_a_long_cleaned_take_is_given_to_the_engine_in_batches_and_a_short_one_whole(tmp_path):
    class Cleaned:
        def __init__(self, mk: Markers) -> None:
            cols = _columns(mk)
            self.markers, self.frames, self.fill_code = mk, cols["frames"], cols["fill_code"]
            self.spike, self.fill_error_mm = cols["spike"], cols["fill_error_mm"]
            self.crop, self.rests = (5, 5 + mk.n_frames), [(5, 15)]
            self.speed_mm_s = np.zeros(mk.n_frames)
            self.neutral, self.neutral_fill_code = _take(10, mk.n_markers), self.fill_code[:10]

    for frames, batched in ((1000, False), (ROW_GROUP_ROWS // 3 + 1, True)):
        mk = _take(frames)
        res = Cleaned(mk)
        tables = clean_tables(res, mk)
        assert isinstance(tables["markers"][0], MarkersBatches) == batched
        assert isinstance(tables["neutral"][0], pa.Table)
        path = tmp_path / f"{frames}.parquet"
        table = tables["markers"][0]
        write_stored_table(TableBatches(*table) if isinstance(table, MarkersBatches) else table, path, MARKERS_CLEAN)
        whole = markers_to_table(mk, frames=res.frames, fill_code=res.fill_code, spike=res.spike,
                                 fill_error_mm=res.fill_error_mm,
                                 meta={"crop": [5, 5 + frames], "rests": [[5, 15]], "stabilised": True})
        write_table(whole, tmp_path / "whole.parquet", MARKERS_CLEAN)
        assert path.read_bytes() == (tmp_path / "whole.parquet").read_bytes()


def test_a_unit_keeps_only_short_tables_for_the_takes_later_units(monkeypatch):
    from gazepipe.pipeline import runner

    small, big = pa.table({"a": [1, 2]}), pa.table({"a": np.zeros(1000)})
    monkeypatch.setattr(runner, "WRITTEN_MAX_BYTES", 4000)
    written: dict[Path, pa.Table] = {Path("old_big"): small}
    runner._remember(written, {Path("small"): small, Path("old_big"): big,
                               Path("batches"): TableBatches(big.schema, 1000, iter(big.to_batches()))})
    assert written == {Path("small"): small}


def test_read_batches_names_an_unreadable_file(tmp_path):
    from gazepipe.errors import InputError

    (tmp_path / "x.parquet").write_bytes(b"not parquet at all")
    with pytest.raises(InputError, match="x.parquet"):
        read_batches(tmp_path / "x.parquet")


def test_the_clean_unit_writes_a_long_takes_markers_in_batches_with_the_same_bytes(tmp_path, monkeypatch):
    """Through the engine, as ``gazepipe run`` runs it: the ``markers`` table given as batches (here from 30
    samples on) is the file written whole, and the engine does write it a batch at a time."""
    from gazepipe import dag
    from gazepipe.dag import store
    from gazepipe.io.session_toml import load_session
    from gazepipe.pipeline.engine import run_pipeline
    from tests.helpers import make_tiny_session

    session = load_session(make_tiny_session(tmp_path / "tiny", n_takes=1))
    dag.declare()
    assert run_pipeline([session], tmp_path / "a", until="clean", executor="serial").count("ok", datasets=False) == 2
    batched: list[Path] = []
    monkeypatch.setattr("gazepipe.schemas.clean_tables.BATCH_ROWS", 30)
    monkeypatch.setattr(store, "write_batches", lambda *a: (batched.append(a[2]), write_batches(*a))[1])
    assert run_pipeline([session], tmp_path / "b", until="clean", executor="serial").count("ok", datasets=False) == 2
    assert len(batched) == 1 and batched[0].name.startswith(".markers.parquet")     # a temporary, renamed after
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a" / "takes").rglob("*.parquet"))
    assert {f.name for f in files} >= {"markers_raw.parquet", "markers.parquet", "neutral.parquet"}
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
