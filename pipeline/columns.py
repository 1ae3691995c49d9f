"""A DataFrame's column as a read-only numpy array, or as pandas stores it.

One place for how the stages read a column: numpy columns as read-only views (no stage writes
into a table it was given), extension columns (nullable, Arrow-backed strings) the public way.
Through pandas' public API only: its internal column access would save ~4 ms of a recording's
~85 ms of CPU in ``pdr run`` (docs/PERFORMANCE.md), at the price of depending on a private method.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd


def stored(df: pd.DataFrame, name: str):
    """The column as pandas stores it: a numpy array (read it, never write it) or an extension array
    (nullable, Arrow-backed strings), which ``pyarrow.array`` takes without a detour through Python objects."""
    values = df[name]
    return values.array if isinstance(values, pd.Series) and not isinstance(values.dtype, np.dtype) \
        else values.to_numpy()


def column(df: pd.DataFrame, name: str, dtype: Any = None, na_value: Any = None) -> np.ndarray:
    """``df[name].to_numpy(dtype, na_value=...)``, read-only, as pandas 3 gives it.

    A column pandas keeps in a numpy block is returned as a read-only view (or
    converted to ``dtype``; a float block's NaN stays NaN, so ``na_value``
    only matters for the extension arrays, which take the public way).
    """
    series = df[name]
    values = series.to_numpy() if isinstance(series, pd.Series) and isinstance(series.dtype, np.dtype) else None
    if values is None:                      # an extension column, or a duplicated name
        kwargs = {} if na_value is None else {"na_value": na_value}
        return df[name].to_numpy(dtype=dtype, **kwargs)
    if dtype is not None and values.dtype != np.dtype(dtype):
        return values.astype(dtype)
    view = values.view()
    view.flags.writeable = False
    return view
