"""The speed-ups of the ingest stage change nothing: the Arrow schema check refuses what the pandas
check refuses (same message), the per-column Parquet encodings read back exactly, and the threaded
Parquet write gives the same tables and report as the pure core."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.config import default_config
from pipeline.errors import SchemaError
from pipeline.ingest.stage import ingest_capture, ingest_signals
from pipeline.ingest.write import PARQUET_ENCODING, PARQUET_OPTIONS, signals_table, write_signals
from pipeline.runs import run_paths
from pipeline.schemas import load_schema
from tests.ingest.helpers import CLEAN

SCHEMA = load_schema("signals")


def _frame(n: int = 6) -> pd.DataFrame:
    return pd.DataFrame({
        "t_s": np.arange(n) * 0.05, "t_raw": np.arange(n) * 50.0, "line": np.arange(n) + 2,
        "segment": np.zeros(n, dtype="int32"), "counts": np.arange(n) * 9,
        "theta_rad": np.arange(n) * 9 * 2 * np.pi / 6533.12, "adc": np.full(n, 511, dtype="int32"),
        "current_v": np.full(n, 2.5), "current_a": np.zeros(n),
        "dir": np.array([0, 1, 1, -1, -1, 0][:n], dtype="int8"), "mode": np.array([0, 1, 1, 2, 2, 0][:n], dtype="int8"),
    })


def _arrow(df: pd.DataFrame) -> pa.Table:
    return pa.Table.from_pandas(df, preserve_index=False)


def _verdict(fn, table) -> str:
    try:
        fn(table, "run1")
    except SchemaError as err:
        return str(err)
    return "ok"


BAD_VALUES = [np.nan, np.inf, -np.inf, -1.0, -5, 0.5, 2, 3, 1023, 1024, 2**40, -(2**40)]
mutation = st.tuples(st.sampled_from([c.name for c in SCHEMA.columns]), st.integers(0, 5), st.sampled_from(BAD_VALUES))


@settings(max_examples=100, deadline=None)
@given(st.lists(mutation, max_size=3), st.sets(st.sampled_from(["adc", "current_v", "current_a", "dir", "mode",
                                                                    "counts"]), max_size=2))
def test_check_arrow_refuses_what_check_refuses_with_the_same_message(mutations, dropped):
    df = _frame()
    for name, row, value in mutations:
        col = df[name].to_numpy().astype(float) if isinstance(value, float) or df[name].dtype.kind == "f" \
            else df[name].to_numpy().astype(np.int64)
        col[row] = value
        df[name] = col
    df = df.drop(columns=sorted(dropped))
    expected = _verdict(SCHEMA.check, df)
    assert _verdict(SCHEMA.check_arrow, _arrow(df)) == expected


@pytest.mark.parametrize("table, message", [
    (_arrow(_frame()).append_column("extra", pa.array(np.zeros(6))), "column 'extra' not defined"),
    (_arrow(_frame()).set_column(10, "mode", pa.array([0, 1, 1, None, 2, 0], pa.int8())), "'mode' has nulls at rows 3"),
    (_arrow(_frame()).set_column(9, "dir", pa.array([0, 1, 1, -1, -1, 0], pa.int64())), "ok"),
    (_arrow(_frame()).set_column(2, "line", pa.array(np.arange(6) + 2.5)), "'line' has non-integer values at rows 0"),
])
def test_check_arrow_on_odd_tables(table, message):
    assert message in _verdict(SCHEMA.check_arrow, table)
    assert _verdict(SCHEMA.check_arrow, table) == _verdict(SCHEMA.check, table.to_pandas())


def test_parquet_encodings_read_back_exactly_with_units(tmp_path):
    df = _frame()
    pq.write_table(signals_table(df, "x", default_config()), tmp_path / "s.parquet", **PARQUET_OPTIONS)
    meta = pq.ParquetFile(tmp_path / "s.parquet").metadata.row_group(0)
    for i in range(meta.num_columns):
        col = meta.column(i)
        encoding, compression = PARQUET_ENCODING[col.path_in_schema]
        assert encoding in col.encodings and "PLAIN_DICTIONARY" not in col.encodings
        assert col.compression == compression.upper().replace("NONE", "UNCOMPRESSED")
        assert col.is_stats_set == (col.path_in_schema in PARQUET_OPTIONS["write_statistics"])
    table = pq.read_table(tmp_path / "s.parquet")
    assert table.schema.field("current_a").metadata[b"unit"] == b"A"
    pd.testing.assert_frame_equal(table.to_pandas(), df)


def test_write_signals_refuses_a_bad_table_and_leaves_nothing(tmp_path):
    paths = run_paths(tmp_path, "run1")
    df = _frame().assign(theta_rad=[0.0, np.nan, 0.1, 0.2, 0.3, 0.4])
    with pytest.raises(SchemaError, match="'theta_rad' has nulls at rows 1"):
        write_signals(paths, df, default_config())
    assert not list(tmp_path.rglob("*.parquet")) and not list(tmp_path.rglob("*.tmp"))


def test_write_signals_syncs_each_row_group_except_inside_deferred_sync(tmp_path, monkeypatch):
    import os

    from pipeline.io import atomic
    synced = []
    real = os.fdatasync
    monkeypatch.setattr(os, "fdatasync", lambda fd: (synced.append(fd), real(fd)))
    write_signals(run_paths(tmp_path / "a", "r"), _frame(), default_config(), row_group_rows=4)
    assert len(synced) == 2                                  # one per row group, started as each is written
    synced.clear()
    with atomic.deferred_sync():                             # pdr run: one os.sync at the end instead
        write_signals(run_paths(tmp_path / "b", "r"), _frame(), default_config(), row_group_rows=4)
    assert synced == []
    assert (tmp_path / "a" / "r" / "signals.parquet").read_bytes() == (tmp_path / "b" / "r" / "signals.parquet").read_bytes()


@pytest.mark.parametrize("capture", [CLEAN, CLEAN + CLEAN])        # one run; a reset: two runs
def test_threaded_parquet_write_gives_the_pure_cores_tables_and_report(tmp_path, capture):
    cfg = default_config()
    runs, report = ingest_capture(capture, cfg, "rec.csv", "rec")
    runs2, report2, paths = ingest_signals(capture, cfg, "rec.csv", "rec", tmp_path)
    assert json.dumps(report2, sort_keys=True) == json.dumps(report, sort_keys=True)
    assert [r.report for r in runs2] == [r.report for r in runs]
    assert len(paths) == len(runs) == len(capture.split(b"t_ms")) - 1
    for run, path in zip(runs, paths):
        assert pq.read_table(path.signals).to_pandas().equals(run.signals)


@pytest.mark.parametrize("body", [
    b"0,0,511,1\n\n50,9,516,1\n",            # blank line
    b"0,0,511,1\r\n\r\n50,9,516,1\r\n",      # blank CRLF line
    b"0,0,511,1\r50,9,516,1\n",              # stray carriage return inside the data
])
def test_plain_path_hands_blank_and_split_lines_to_the_general_path(body):
    from pipeline.config import ColumnsConfig
    from pipeline.ingest.plain import parse_plain

    assert parse_plain(b"t_ms,counts,adc,dir\n" + body, ColumnsConfig(), "x.csv") is None
    assert parse_plain(b"t_ms,counts,adc,dir\n0,0,511,1\n50,9,516,1\n", ColumnsConfig(), "x.csv") is not None


def _range_violations_by_masks(values, cfg):
    """The range rules as one mask per rule over every row: what ``range_violations`` must agree with."""
    from pipeline.ingest.timing import COUNTER_RANGE
    span = COUNTER_RANGE[cfg.columns.time_unit]
    t = values["t_raw"]
    rules = [((t < 0) | (t >= span if span else False), "time")]
    if "adc" in values:
        rules.append(((values["adc"] < 0) | (values["adc"] >= cfg.current_sensor.adc_steps), "adc"))
    if "dir" in values:
        rules.append(((values["dir"] < -1) | (values["dir"] > 1), "dir"))
    bad, first = np.zeros(len(t), dtype=bool), {}
    for mask, text in rules:
        first |= {int(i): text for i in np.flatnonzero(mask & ~bad)}
        bad |= mask
    return bad, first


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([-1.0, 0.0, 5.0, 2.0**32 - 1, 2.0**32, np.nan]),
                          st.integers(-2, 1025), st.integers(-2, 2)), min_size=0, max_size=8),
       st.sets(st.sampled_from(["adc", "dir"])), st.sampled_from(["ms", "s"]))
def test_range_rules_settled_by_min_max_agree_with_a_mask_per_rule(rows, absent, unit):
    import dataclasses

    from pipeline.ingest.convert import range_violations
    cfg = default_config()
    cfg = dataclasses.replace(cfg, columns=dataclasses.replace(cfg.columns, time_unit=unit))
    values = {"t_raw": np.array([r[0] for r in rows], dtype=np.float64),
              "adc": np.array([r[1] for r in rows], dtype=np.int64), "dir": np.array([r[2] for r in rows], dtype=np.int64)}
    values = {k: v for k, v in values.items() if k not in absent}
    bad, reason = range_violations(values, cfg)
    ref_bad, ref_first = _range_violations_by_masks(values, cfg)
    assert np.array_equal(bad, ref_bad)
    assert {i: r.split()[0] for i, r in reason.items()} == ref_first


@pytest.mark.parametrize("values", [
    np.arange(5000) % 7 * 0.1,                                        # few distinct: formatted once each
    np.tile([0.0, -0.0, np.nan, np.inf, -np.inf, 1e300, 5e-324, 2.5], 400),
    np.arange(5000) * 0.001,                                         # all distinct: cast directly
    np.arange(5000) % 3 - 1,
])
def test_value_text_is_arrows_cast_of_every_value(values):
    import pyarrow.compute as pc

    from pipeline.ingest.mcap_bulk import value_text
    assert value_text(values).equals(pc.cast(pa.array(values), pa.string()))


def test_signals_in_many_row_groups_read_back_exactly_and_write_the_same_bytes_twice(tmp_path):
    df = _frame()
    for k in (1, 2):
        write_signals(run_paths(tmp_path / f"p{k}", "r"), df, default_config(), row_group_rows=4)
    first, second = (tmp_path / f"p{k}" / "r" / "signals.parquet" for k in (1, 2))
    assert pq.ParquetFile(first).metadata.num_row_groups == 2
    assert first.read_bytes() == second.read_bytes()
    table = pq.read_table(first)
    assert table.schema.field("theta_rad").metadata[b"unit"] == b"rad"
    pd.testing.assert_frame_equal(table.to_pandas(), df)
