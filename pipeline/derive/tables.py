"""Row records -> a typed DataFrame, without pandas' per-row and astype overhead (it dominated the stage)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.columns import stored


def frame(rows: list[dict], columns: list[str], dtypes: dict[str, str]) -> pd.DataFrame:
    """Columns in ``columns`` order; ``dtypes`` names the non-float ones (everything else is float64)."""
    data = {}
    for name in columns:
        kind = dtypes.get(name, "float64")
        values = [r[name] for r in rows]
        data[name] = np.array(values, dtype=object if kind == "str" else kind)
    return pd.DataFrame(data, columns=columns)


def schema_table(name: str, df: pd.DataFrame, where: str = ""):
    """``load_schema(name).to_arrow(df)`` at a third of the cost: convert column by column, then the Arrow check.

    Each column goes from its numpy values straight to an Arrow array of the
    schema's type (``from_pandas=True``: NaN becomes null, as ``to_arrow``
    does), skipping pandas' block manager.  Whatever this cannot take as it is
    (a column the schema does not define, values Arrow refuses to cast,
    anything ``check_arrow`` doubts) goes through ``to_arrow``, so the same
    tables are refused with the same messages.
    """
    import pyarrow as pa

    from pipeline.schemas import load_schema

    schema = load_schema(name)
    if not set(df.columns) <= {c.name for c in schema.columns}:
        return schema.to_arrow(df, where)
    arrow_schema = schema.arrow_schema(df.columns)
    try:
        arrays = [pa.array(stored(df, f.name), type=f.type, from_pandas=True) for f in arrow_schema]
        table = pa.Table.from_arrays(arrays, schema=arrow_schema)
    except (pa.ArrowInvalid, pa.ArrowTypeError, TypeError, ValueError, OverflowError):
        return schema.to_arrow(df, where)
    schema.check_arrow(table, where)
    return table
