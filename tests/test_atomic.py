"""Atomic outputs: the old file or the new one, never a torn one, and no temporary left behind."""

import os
from pathlib import Path

import pytest

from pipeline.io import atomic
from pipeline.io.atomic import atomic_path, write_bytes, write_json


def _temps(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.name.endswith(".tmp")]


def test_write_bytes_creates_parents_replaces_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "a" / "b" / "out.bin"
    write_bytes(target, b"first")
    write_bytes(target, b"second")
    assert target.read_bytes() == b"second"
    assert _temps(target.parent) == []


def test_permissions_are_those_of_a_plain_open(tmp_path):
    plain = tmp_path / "plain"
    plain.write_bytes(b"x")
    write_bytes(tmp_path / "atomic", b"x")
    with atomic_path(tmp_path / "via_path") as tmp:
        tmp.write_bytes(b"x")
    mode = plain.stat().st_mode & 0o777
    assert (tmp_path / "atomic").stat().st_mode & 0o777 == mode
    assert (tmp_path / "via_path").stat().st_mode & 0o777 == mode


def test_large_payload_is_written_whole(tmp_path):
    data = os.urandom(5_000_000)
    write_bytes(tmp_path / "big", data)
    assert (tmp_path / "big").read_bytes() == data


def test_failure_inside_keeps_the_previous_file(tmp_path):
    target = tmp_path / "out.json"
    write_json(target, {"v": 1})
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half a fi")
            raise RuntimeError("killed halfway")
    assert target.read_text() == '{\n  "v": 1\n}\n'
    assert _temps(tmp_path) == []


def test_unserialisable_json_keeps_the_previous_file(tmp_path):
    target = tmp_path / "out.json"
    write_json(target, {"v": 1})
    with pytest.raises(TypeError):
        write_json(target, {"v": object()})
    assert target.read_text() == '{\n  "v": 1\n}\n'
    assert _temps(tmp_path) == []


def test_a_stale_temporary_of_the_same_name_is_skipped_not_overwritten(tmp_path, monkeypatch):
    target = tmp_path / "out.bin"
    monkeypatch.setattr(atomic, "_serial", iter(range(5)))
    stale = tmp_path / f".out.bin.{os.getpid()}.0.tmp"
    stale.write_bytes(b"left by a killed run")
    write_bytes(target, b"new")
    assert target.read_bytes() == b"new"
    assert stale.read_bytes() == b"left by a killed run"


def _table():
    import numpy as np
    import pyarrow as pa
    schema = pa.schema([pa.field("t_s", pa.float64(), metadata={"unit": "s"}), pa.field("dir", pa.int8()),
                        pa.field("current_a", pa.float64(), nullable=True), pa.field("mode", pa.string())])
    return pa.Table.from_arrays([pa.array(np.linspace(0, 1, 50)), pa.array(np.ones(50, np.int8)),
                                 pa.array([None if i % 7 == 0 else i * 0.1 for i in range(50)], pa.float64()),
                                 pa.array(["q1", "q2"] * 25)], schema=schema)


def test_parquet_in_memory_and_streamed_give_the_same_bytes(tmp_path, monkeypatch):
    import pyarrow.parquet as pq
    table = _table()
    atomic.write_parquet(tmp_path / "memory.parquet", table)
    monkeypatch.setattr(atomic, "IN_MEMORY_PARQUET_BYTES", 0)         # force the streamed path
    atomic.write_parquet(tmp_path / "streamed.parquet", table)
    assert (tmp_path / "memory.parquet").read_bytes() == (tmp_path / "streamed.parquet").read_bytes()
    assert pq.read_table(tmp_path / "memory.parquet").equals(table)
    assert _temps(tmp_path) == []


def test_read_parquet_gives_what_pandas_gives(tmp_path):
    import pandas as pd
    atomic.write_parquet(tmp_path / "t.parquet", _table())
    ours, theirs = atomic.read_parquet(tmp_path / "t.parquet"), pd.read_parquet(tmp_path / "t.parquet")
    pd.testing.assert_frame_equal(ours, theirs)


def test_deferred_sync_skips_per_file_fsyncs_and_syncs_once_on_leaving(tmp_path, monkeypatch):
    calls = {"fsync": 0, "sync": 0}
    real_fsync, real_sync = os.fsync, os.sync

    def counting_fsync(fd):
        calls["fsync"] += 1
        real_fsync(fd)

    def counting_sync():
        calls["sync"] += 1
        real_sync()

    monkeypatch.setattr(os, "fsync", counting_fsync)
    monkeypatch.setattr(os, "sync", counting_sync)
    with atomic.deferred_sync():
        with atomic.deferred_sync():                        # nested: still one sync, at the outermost exit
            write_bytes(tmp_path / "a", b"a")
            with atomic_path(tmp_path / "b") as tmp:
                tmp.write_bytes(b"b")
        assert calls == {"fsync": 0, "sync": 0}
        assert (tmp_path / "a").read_bytes() == b"a" and (tmp_path / "b").read_bytes() == b"b"
    assert calls == {"fsync": 0, "sync": 1}
    write_bytes(tmp_path / "c", b"c")                       # outside: durable file by file again
    assert calls == {"fsync": 1, "sync": 1}
    assert _temps(tmp_path) == []
