"""Run records: npz + JSON sidecar round trip, and the doubling column buffer."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.oatf import OatfConfig
from controller.pi import PIConfig
from controller.record import RECORD_FORMAT, ROW_BLOCK, ChunkedRecord, ColumnBuffer, RowCounter, load_record, save_record


def test_round_trip(tmp_path: Path) -> None:
    n = 257
    rng = np.random.default_rng(0)
    columns = {
        "t_s": np.arange(n) * 0.005,
        "setpoint_phi1": rng.normal(size=n),
        "raw_counts_ext1": rng.integers(0, 4096, size=n).astype(np.uint16),
        "saturated_1": rng.random(n) > 0.5,
        "oatf.freq_hz": np.full(n, 3.9, dtype=np.float32),
    }
    config = {"pi": PIConfig(), "oatf": OatfConfig(), "seed": np.int64(7)}
    metadata = {"speed_in_per_s": 5.0, "payload": True, "note": None, "bad": math.nan, "where": Path("/x/y")}
    npz, js = save_record(tmp_path / "runs" / "r1.npz", columns, config, metadata)
    assert npz.name == "r1.npz" and js.name == "r1.json"
    assert not list((tmp_path / "runs").glob("*.tmp*"))
    rec = load_record(tmp_path / "runs" / "r1")
    assert list(rec.columns) == list(columns)
    for name, arr in columns.items():
        np.testing.assert_array_equal(rec[name], arr)
        assert rec[name].dtype == arr.dtype
    assert len(rec) == n
    assert rec.config["pi"]["kp_mv_per_rad"] == [7500.0, 6250.0]
    assert rec.config["oatf"]["plausible_band_hz"] == [1.0, 20.0]
    assert rec.config["seed"] == 7
    assert rec.metadata == {"speed_in_per_s": 5.0, "payload": True, "note": None, "bad": "nan", "where": "/x/y"}
    sidecar = json.loads(js.read_text())
    assert sidecar["format"] == RECORD_FORMAT and sidecar["n_samples"] == n
    assert sidecar["columns"]["raw_counts_ext1"] == "uint16"
    assert load_record(js).columns.keys() == rec.columns.keys()


def test_bad_columns_are_rejected(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="rows"):
        save_record(tmp_path / "a", {"a": np.zeros(3), "b": np.zeros(4)})
    with pytest.raises(ValueError, match="1-D"):
        save_record(tmp_path / "a", {"a": np.zeros((3, 2))})
    with pytest.raises(ValueError, match="name"):
        save_record(tmp_path / "a", {"a/b": np.zeros(3)})
    (tmp_path / "x.json").write_text('{"format": "other"}')
    with pytest.raises(ValueError, match="not a"):
        load_record(tmp_path / "x")


def test_column_buffer_grows_by_doubling(tmp_path: Path) -> None:
    buf = ColumnBuffer({"t_s": np.float64, "count": np.int32, "flag": np.bool_}, capacity=4)
    capacities = set()
    for k in range(1000):
        buf.append(t_s=k * 0.005, count=k, flag=k % 3 == 0)
        capacities.add(buf.capacity)
    assert len(buf) == 1000
    assert capacities == {4 * 2**i for i in range(9)}  # 4 ... 1024
    cols = buf.to_columns()
    np.testing.assert_array_equal(cols["count"], np.arange(1000))
    np.testing.assert_allclose(cols["t_s"], np.arange(1000) * 0.005)
    assert cols["flag"].dtype == np.bool_ and cols["flag"].sum() == 334
    buf.append({"t_s": 9.0, "count": 9}, flag=False)
    assert len(cols["count"]) == 1000  # copies are independent of later appends
    view = buf.column("count")
    with pytest.raises(ValueError):
        view[0] = 5
    with pytest.raises(KeyError, match="missing"):
        buf.append(t_s=1.0, count=1)
    with pytest.raises(KeyError, match="unknown"):
        buf.append(t_s=1.0, count=1, flag=True, extra=2)
    assert len(buf) == 1001
    buf.save(tmp_path / "buf", metadata={"n": 1001})
    rec = load_record(tmp_path / "buf")
    np.testing.assert_array_equal(rec["count"][:1000], np.arange(1000))
    assert rec.metadata == {"n": 1001}
    buf.clear()
    assert len(buf) == 0 and buf.capacity == 1024


@settings(max_examples=30, deadline=None)
@given(rows=st.lists(st.tuples(st.floats(allow_nan=False, allow_infinity=False), st.integers(-1000, 1000)), max_size=300), capacity=st.integers(1, 64))
def test_column_buffer_equals_list_append(rows: list[tuple[float, int]], capacity: int) -> None:
    buf = ColumnBuffer({"x": np.float64, "k": np.int64}, capacity=capacity)
    for x, k in rows:
        buf.append(x=x, k=k)
    cols = buf.to_columns()
    np.testing.assert_array_equal(cols["x"], np.array([r[0] for r in rows], dtype=float))
    np.testing.assert_array_equal(cols["k"], np.array([r[1] for r in rows], dtype=np.int64))


def test_a_full_chunk_is_written_one_column_per_row_and_the_record_is_unchanged(tmp_path: Path) -> None:
    """The row that fills a chunk writes nothing; each later row writes at most
    one of its columns, so no tick pays for the whole chunk; the parts and the
    saved record are byte for byte what the rows make, whatever the chunk size."""
    columns = {"a": np.float64, "b": np.int64, "flag": np.bool_, "c": np.float32}
    rng = np.random.default_rng(3)
    rows = [[float(rng.normal()), int(i), bool(i % 3 == 0), float(i) * 0.25] for i in range(53)]
    want = ColumnBuffer(columns, capacity=4)
    for row in rows:
        want.append_row(list(row))
    for chunk in (1, 2, 4, 5, 64):
        rec = ChunkedRecord(tmp_path / f"r{chunk}", columns, chunk_rows=chunk)
        parts = tmp_path / f"r{chunk}.parts"
        written = 0
        for i, row in enumerate(rows):
            if i == 20:
                rec.append(dict(zip(columns, row, strict=True)))  # the mapping form takes the same path
            else:
                rec.append_row(list(row))
            size = sum(f.stat().st_size for f in parts.iterdir())
            if chunk >= len(columns):  # (a chunk of fewer rows than columns finishes the one before at once)
                assert size - written <= chunk * 8  # at most one column of one chunk per row
            written = size
            assert len(rec) == i + 1
        rec.save()
        got = load_record(tmp_path / f"r{chunk}").columns
        for name, column in want.to_columns().items():
            assert got[name].dtype == column.dtype and got[name].tobytes() == column.tobytes()


def test_append_row_stores_what_append_stores(tmp_path: Path) -> None:
    columns = {"a": np.float64, "b": np.float64, "flag": np.bool_, "tick": np.int64}
    by_row, by_map = ColumnBuffer(columns, capacity=16), ColumnBuffer(columns, capacity=16)
    chunked = ChunkedRecord(tmp_path / "r", columns, chunk_rows=700)
    counter = RowCounter(columns)
    rng = np.random.default_rng(2)
    n = 3 * ROW_BLOCK + 17
    for i in range(n):
        row = [float(rng.normal()), math.nan if i % 97 == 0 else i * 0.5, i % 3 == 0, i]
        if i == ROW_BLOCK + 5:
            by_row.append(dict(zip(columns, row, strict=True)))  # a mapping between rows keeps the order
        else:
            by_row.append_row(row)
        by_map.append(dict(zip(columns, row, strict=True)))
        chunked.append_row(row)
        counter.append_row(row)
        if i == 100:
            assert len(by_row) == 101 and by_row.column("tick").tolist() == list(range(101))
    assert len(by_row) == len(by_map) == len(chunked) == len(counter) == n
    got, want, streamed = by_row.to_columns(), by_map.to_columns(), chunked.to_columns()
    for name in columns:
        assert got[name].dtype == want[name].dtype == streamed[name].dtype
        assert got[name].tobytes() == want[name].tobytes() == streamed[name].tobytes()
    chunked.close()
    with pytest.raises(ValueError, match="one per column"):
        by_row.append_row([1.0, 2.0])
    by_row.clear()
    assert len(by_row) == 0


def test_a_chunked_record_saved_again_keeps_its_file_or_copies_it(tmp_path: Path) -> None:
    """Saved at the run's end (``run_record``) and again by a caller: the same
    path stays as first written; another path gets the same columns and its own sidecar."""
    rec = ChunkedRecord(tmp_path / "r", {"tick": np.int64, "x": np.float64}, chunk_rows=64)
    for i in range(150):  # two full chunks and a partial one
        rec.append_row((i, i * 0.5))
    first = rec.save(tmp_path / "r", metadata={"who": "first"})
    assert not (tmp_path / "r.parts").exists()
    assert rec.save(tmp_path / "r.npz", metadata={"who": "second"}) == first
    assert load_record(tmp_path / "r").metadata == {"who": "first"}
    rec.save(tmp_path / "copy", metadata={"who": "copy"})
    a, b = load_record(tmp_path / "r"), load_record(tmp_path / "copy")
    assert len(a) == len(b) == 150 and b.metadata == {"who": "copy"}
    assert np.array_equal(a["tick"], np.arange(150)) and np.array_equal(a["x"], b["x"])
    assert np.array_equal(rec.to_columns()["x"], np.arange(150) * 0.5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["copy.json", "copy.npz", "r.json", "r.npz"]
