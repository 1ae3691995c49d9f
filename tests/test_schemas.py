"""One schema definition feeds Parquet, MCAP JSON schemas and the pre-write checks."""

import io

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from pipeline.config import default_config
from pipeline.errors import SchemaError
from pipeline.schemas import load_schema, schema_names


def signals_frame(n: int = 5) -> pd.DataFrame:
    return pd.DataFrame({
        "t_s": np.arange(n) * 0.05, "t_raw": np.arange(n) * 50, "line": np.arange(n) + 2,
        "segment": np.zeros(n, dtype="int32"), "counts": np.arange(n) * 9,
        "theta_rad": np.arange(n) * 9 * 2 * np.pi / 6533.12,
        "dir": np.ones(n, dtype="int8"), "mode": np.ones(n, dtype="int8"),
    })


def test_every_schema_file_loads_with_known_types():
    for name in schema_names():
        schema = load_schema(name)
        assert schema.columns, name
        schema.arrow_schema()       # raises on an unknown type
        schema.json_schema()


def test_parquet_schema_carries_units_and_round_trips():
    schema = load_schema("signals")
    df = signals_frame()
    buf = io.BytesIO()
    pq.write_table(schema.to_arrow(df), buf)
    table = pq.read_table(io.BytesIO(buf.getvalue()))
    assert table.schema.field("theta_rad").metadata[b"unit"] == b"rad"
    assert table.schema.field("dir").type == schema.column("dir").arrow_type
    pd.testing.assert_frame_equal(table.to_pandas(), df, check_dtype=False)
    assert "adc" not in table.column_names        # optional columns absent, not invented


def test_json_schema_lists_only_present_columns_with_units():
    js = load_schema("signals").json_schema(["t_s", "dir"])
    assert set(js["properties"]) == {"t_s", "dir"}
    assert js["properties"]["dir"]["enum"] == [-1, 0, 1]
    assert "[s]" in js["properties"]["t_s"]["description"]


@pytest.mark.parametrize("mutate, message", [
    (lambda df: df.assign(dir=np.array([1, 1, 2, 1, 1], dtype="int8")), "column 'dir' has values outside .* rows 2"),
    (lambda df: df.assign(t_s=df.t_s - 1.0), "column 't_s' below 0.0 s at rows 0, 1, 2, 3, 4"),
    (lambda df: df.drop(columns=["counts"]), "column 'theta_rad' without 'counts' .columns counts, theta_rad come"),
    (lambda df: df.drop(columns=["counts", "theta_rad"]), "none of the columns theta_rad, current_a"),
    (lambda df: df.drop(columns=["t_s"]), "lacks required column 't_s'"),
    (lambda df: df.assign(extra=1), "column 'extra' not defined"),
    (lambda df: df.assign(theta_rad=[0.0, np.nan, 0.1, 0.2, 0.3]), "column 'theta_rad' has nulls at rows 1"),
    (lambda df: df.assign(adc=[0, 10, 2000, 3, 4]), "column 'adc' above 1023"),
])
def test_violations_name_column_rows_and_rule(mutate, message):
    with pytest.raises(SchemaError, match=message):
        load_schema("signals", default_config()).check(mutate(signals_frame()), "run1")



def test_an_infinite_value_in_an_integer_column_is_refused_as_non_integer():
    schema = load_schema("phases")
    df = pd.DataFrame({c.name: [c.allowed[0] if c.allowed else (c.min or 0)] * 3 for c in schema.columns})
    df["n_samples"] = np.array([10.0, np.inf, 3.0])
    with pytest.raises(SchemaError, match=r"'n_samples' has non-integer values at rows 1; rule: int64"):
        schema.check(df)


def test_a_recording_without_an_encoder_keeps_to_the_schema_with_its_angle_columns_absent():
    """counts and theta_rad are optional together, as long as the current is there (schemas/signals.json)."""
    df = signals_frame().drop(columns=["counts", "theta_rad"])
    df = df.assign(adc=np.full(5, 512, dtype="int32"), current_v=np.full(5, 2.5), current_a=np.zeros(5))
    schema = load_schema("signals")
    schema.check(df, "run1")
    table = schema.to_arrow(df)
    schema.check_arrow(table, "run1")
    assert "counts" not in table.column_names and "theta_rad" not in table.column_names
    with pytest.raises(SchemaError, match="column 'dir' without 'mode'"):
        schema.check_arrow(schema.to_arrow(df).drop_columns(["mode"]), "run1")
