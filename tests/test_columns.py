"""``pipeline.columns.column`` must give what ``df[name].to_numpy(...)`` gives, for every kind of column."""

import numpy as np
import pandas as pd
import pytest

from pipeline.columns import column


@pytest.fixture
def df() -> pd.DataFrame:
    return pd.DataFrame({
        "f": np.linspace(0.0, 1.0, 7), "i": np.arange(7, dtype=np.int64), "b": np.arange(7) % 2 == 0,
        "d": np.array([1, 1, -1, -1, 0, 1, -1], dtype=np.int8),
        "nullable": pd.array([1.0, None, 3.0, None, 5.0, 6.0, 7.0], dtype="Float64"),
        "s": ["a", "b", "c", "d", "e", "f", "g"],
    })


@pytest.mark.parametrize("name", ["f", "i", "b", "d", "s"])
def test_same_values_and_dtype_as_to_numpy(df, name):
    got, want = column(df, name), df[name].to_numpy()
    assert got.dtype == want.dtype
    assert list(got) == list(want)


@pytest.mark.parametrize("name,dtype", [("i", float), ("d", np.int8), ("b", bool), ("f", float), ("d", float)])
def test_dtype_conversion(df, name, dtype):
    got = column(df, name, dtype)
    assert got.dtype == np.dtype(dtype)
    np.testing.assert_array_equal(got, df[name].to_numpy(dtype=dtype))


def test_nullable_column_takes_na_value(df):
    got = column(df, "nullable", dtype=float, na_value=np.nan)
    np.testing.assert_array_equal(got, df["nullable"].to_numpy(dtype=float, na_value=np.nan))
    assert np.isnan(got[[1, 3]]).all()


def test_view_is_read_only_so_the_frame_cannot_be_changed_through_it(df):
    got = column(df, "f")
    with pytest.raises(ValueError):
        got[0] = 99.0
    assert df["f"].iloc[0] == 0.0


def test_converted_copy_leaves_the_frame_alone(df):
    got = column(df, "i", float)
    got[0] = 99.0
    assert df["i"].iloc[0] == 0


def test_duplicate_names_fall_back_to_pandas():
    df = pd.DataFrame([[1.0, 2.0]], columns=["x", "x"])
    np.testing.assert_array_equal(column(df, "x"), df["x"].to_numpy())


def test_missing_column_raises_key_error(df):
    with pytest.raises(KeyError):
        column(df, "nope")


def test_stored_columns_convert_to_arrow_as_their_pandas_values_do(df):
    import pyarrow as pa

    from pipeline.columns import stored
    for name, typ in (("f", pa.float64()), ("d", pa.int8()), ("nullable", pa.float64()), ("s", pa.string()),
                      ("b", pa.bool_())):
        ours = pa.array(stored(df, name), type=typ, from_pandas=True)
        values = df[name].to_numpy(dtype=float, na_value=np.nan) if name == "nullable" else df[name].to_numpy()
        theirs = pa.array(values, type=typ, from_pandas=True)
        assert ours.equals(theirs), name
    assert pa.array(stored(df, "nullable"), type=pa.float64()).null_count == 2
