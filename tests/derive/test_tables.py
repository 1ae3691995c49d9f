"""schema_table: the fast column-by-column conversion gives ``to_arrow``'s table and refuses what it refuses."""

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from pipeline.derive.tables import schema_table
from pipeline.errors import SchemaError
from pipeline.schemas import load_schema


def phases(n: int = 4) -> pd.DataFrame:
    return pd.DataFrame({
        "phase": np.arange(n, dtype=np.int32), "start_s": np.arange(n) * 1.0, "end_s": np.arange(n) + 1.0,
        "duration_s": np.ones(n), "dir": np.array([1, -1] * (n // 2), np.int8),
        "mode": np.array([1, 2] * (n // 2), np.int8), "first_sample": np.arange(n) * 10,
        "n_samples": np.full(n, 10), "peak_omega_rad_s": np.linspace(-2, 2, n),
        "peak_current_a": np.linspace(-0.2, 0.2, n), "theta_extreme_rad": np.linspace(-1, 1, n),
        "ended_at_guard": np.array([True, False] * (n // 2)), "end_reason": ["guard", "reversed before guard"] * (n // 2),
    })


def _verdict(df: pd.DataFrame) -> str:
    try:
        schema_table("phases", df)
    except SchemaError as err:
        return str(err)
    return "accepted"


def _reference_verdict(df: pd.DataFrame) -> str:
    try:
        load_schema("phases").to_arrow(df)
    except SchemaError as err:
        return str(err)
    return "accepted"


def test_same_values_types_and_units_as_to_arrow():
    df = phases()
    df.loc[1, "peak_current_a"] = np.nan           # nullable: NaN becomes null on both paths
    fast, ref = schema_table("phases", df), load_schema("phases").to_arrow(df)
    assert fast.schema.remove_metadata() == ref.schema.remove_metadata()
    assert fast.schema.field("peak_current_a").metadata[b"unit"] == b"A"
    assert fast.column("peak_current_a").null_count == 1
    for name in df.columns:
        assert fast.column(name).to_pylist() == ref.column(name).to_pylist(), name


@pytest.mark.parametrize("column, value", [
    ("peak_omega_rad_s", np.nan),       # not nullable
    ("duration_s", -1.0),               # below min
    ("dir", 3),                         # outside allowed
    ("end_reason", "bored"),            # outside allowed
    ("peak_current_a", np.inf),         # nullable, but not infinite
])
def test_refuses_what_to_arrow_refuses_with_the_same_message(column, value):
    df = phases()
    df[column] = df[column].astype(object)
    df.loc[2, column] = value
    df[column] = df[column].infer_objects()
    assert _verdict(df) == _reference_verdict(df) != "accepted"
    assert "rows 2" in _verdict(df)


def test_an_unknown_column_is_refused_by_name():
    df = phases().assign(extra=1.0)
    with pytest.raises(SchemaError, match="'extra' not defined"):
        schema_table("phases", df)
    assert isinstance(schema_table("phases", phases()), pa.Table)
