"""A DataFrame's column as a numpy array, without building a pandas Series.

``df[name].to_numpy()`` costs ~50 us a column in pandas 3 (a Series and its
copy-on-write bookkeeping); pandas' own storage is ~2 us away.  One recording
reads a few hundred columns across the stages, so the Series nobody needed
cost more than some stages' work.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd


def stored(df: pd.DataFrame, name: str):
    """The column as pandas stores it: a numpy array (read it, never write it) or an extension array
    (nullable, Arrow-backed strings), which ``pyarrow.array`` takes without a detour through Python objects."""
    where = df.columns.get_loc(name)
    return df._get_column_array(where) if isinstance(where, int) else df[name].to_numpy()


def column(df: pd.DataFrame, name: str, dtype: Any = None, na_value: Any = None) -> np.ndarray:
    """``df[name].to_numpy(dtype, na_value=...)``, read-only, as pandas 3 gives it.

    A column pandas keeps in a numpy block is returned as a read-only view (or
    converted to ``dtype``; a float block's NaN stays NaN, so ``na_value``
    only matters for the extension arrays, which take the public way).
    """
    where = df.columns.get_loc(name)
    values = df._get_column_array(where) if isinstance(where, int) else None   # None: a duplicated name
    if not isinstance(values, np.ndarray):
        kwargs = {} if na_value is None else {"na_value": na_value}
        return df[name].to_numpy(dtype=dtype, **kwargs)
    if dtype is not None and values.dtype != np.dtype(dtype):
        return values.astype(dtype)
    view = values.view()
    view.flags.writeable = False
    return view
