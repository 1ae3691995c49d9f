"""Table schemas, defined once in ``schemas/*.json``.

Each schema lists columns with type, unit, range, allowed values, nullability
and whether the column is required, and which optional columns come only
together (``together``: e.g. counts and theta_rad) or of which at least one is
present (``any_of``: a recording measures the angle, the current or both).  From that one definition come the Parquet
schema (units in field metadata), the JSON schema of the MCAP channels, and the
checks run before anything is written.

A range that depends on the rig (the ADC's top step, the reference voltage) is written in the
JSON as ``{"rig": "section.key", "plus": k}``: ``load_schema(name)`` leaves it unchecked and
``load_schema(name, cfg)`` fills it from that rig's configuration, so a 12-bit ADC's recording
is held to 0..4095 and a 10-bit one's to 0..1023 by the same definition.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from pipeline.errors import SchemaError

SCHEMA_DIR = Path(__file__).resolve().parent.parent / "schemas"

_ARROW = {
    "float64": pa.float64(), "float32": pa.float32(), "int64": pa.int64(), "int32": pa.int32(),
    "int16": pa.int16(), "int8": pa.int8(), "bool": pa.bool_(), "string": pa.string(),
}
_JSON = {"float64": "number", "float32": "number", "int64": "integer", "int32": "integer",
         "int16": "integer", "int8": "integer", "bool": "boolean", "string": "string"}


@dataclass(frozen=True)
class Column:
    name: str
    type: str
    unit: str
    description: str = ""
    nullable: bool = False
    required: bool = True
    min: float | None = None
    max: float | None = None
    allowed: tuple | None = None
    rig_min: tuple[str, float] | None = None    # ("section.key", plus): min = rig value + plus
    rig_max: tuple[str, float] | None = None

    def for_rig(self, values: dict[str, float]) -> Column:
        """This column with its rig-dependent range filled from the rig's ``values`` ("section.key" -> value)."""
        if self.rig_min is None and self.rig_max is None:
            return self
        return replace(self, min=_bound(values, self.rig_min, self.min), max=_bound(values, self.rig_max, self.max),
                       rig_min=None, rig_max=None)

    @property
    def arrow_type(self) -> pa.DataType:
        return _ARROW[self.type]

    def arrow_field(self) -> pa.Field:
        meta = {"unit": self.unit, "description": self.description}
        return pa.field(self.name, self.arrow_type, nullable=self.nullable, metadata=meta)

    def json_schema(self) -> dict[str, Any]:
        out: dict[str, Any] = {"type": _JSON[self.type] if not self.nullable else [_JSON[self.type], "null"],
                               "description": f"{self.description} [{self.unit}]"}
        if self.min is not None:
            out["minimum"] = self.min
        if self.max is not None:
            out["maximum"] = self.max
        if self.allowed is not None:
            out["enum"] = list(self.allowed)
        return out


@dataclass(frozen=True)
class TableSchema:
    name: str
    description: str
    columns: tuple[Column, ...]
    together: tuple[tuple[str, ...], ...] = ()     # each group: all of its columns or none
    any_of: tuple[tuple[str, ...], ...] = ()       # each group: at least one of its columns

    def column(self, name: str) -> Column:
        for c in self.columns:
            if c.name == name:
                return c
        raise KeyError(name)

    def present(self, names) -> tuple[Column, ...]:
        """The schema's columns that are in ``names``, in schema order."""
        names = set(names)
        return tuple(c for c in self.columns if c.name in names)

    def arrow_schema(self, names=None) -> pa.Schema:
        cols = self.columns if names is None else self.present(names)
        return pa.schema([c.arrow_field() for c in cols],
                         metadata={"table": self.name, "description": self.description})

    def json_schema(self, names=None, title: str | None = None) -> dict[str, Any]:
        cols = self.columns if names is None else self.present(names)
        return {"title": title or self.name, "description": self.description, "type": "object",
                "properties": {c.name: c.json_schema() for c in cols},
                "required": [c.name for c in cols]}

    def presence_problem(self, names) -> str | None:
        """What is wrong with a table's set of column names (``together``/``any_of``), or None."""
        names = set(names)
        for group in self.together:
            have = [c for c in group if c in names]
            if have and len(have) < len(group):
                missing = next(c for c in group if c not in names)
                return (f"table '{self.name}' has column '{have[0]}' without '{missing}' "
                        f"(columns {', '.join(group)} come together)")
        for group in self.any_of:
            if not names & set(group):
                return f"table '{self.name}' has none of the columns {', '.join(group)} (at least one is needed)"
        return None

    def check(self, df: pd.DataFrame, where: str = "") -> None:
        """Refuse a table that breaks the schema, naming the column, the rows and the rule."""
        prefix = f"{where}: " if where else ""
        unknown = [c for c in df.columns if c not in {col.name for col in self.columns}]
        if unknown:
            raise SchemaError(f"{prefix}table '{self.name}' has column '{unknown[0]}' not defined in schemas/{self.name}.json")
        problem = self.presence_problem(df.columns)
        if problem:
            raise SchemaError(prefix + problem)
        for col in self.columns:
            if col.name not in df.columns:
                if col.required:
                    raise SchemaError(f"{prefix}table '{self.name}' lacks required column '{col.name}'")
                continue
            s = df[col.name]
            null = s.isna().to_numpy()
            if null.any() and not col.nullable:
                raise SchemaError(f"{prefix}column '{col.name}' has nulls at rows {_rows(null)}; rule: not nullable")
            values = s.to_numpy()[~null]
            if col.type.startswith(("int", "float")) and len(values):
                values = values.astype(float)
                if col.type.startswith("int") and not np.all(np.isfinite(values) & (values == np.round(values))):
                    full = s.to_numpy(dtype=float, na_value=0.0)
                    raise SchemaError(f"{prefix}column '{col.name}' has non-integer values at rows "
                                      f"{_rows(~np.isfinite(full) | (full != np.round(full)))}; rule: {col.type}")
                if col.type.startswith("float") and not np.all(np.isfinite(values)):
                    bad = ~np.isfinite(s.to_numpy(dtype=float, na_value=0.0))
                    raise SchemaError(f"{prefix}column '{col.name}' has non-finite values at rows {_rows(bad)}")
                full = s.to_numpy(dtype=float, na_value=np.nan)
                if col.min is not None and np.any(values < col.min):
                    raise SchemaError(f"{prefix}column '{col.name}' below {col.min} {col.unit} at rows "
                                      f"{_rows(full < col.min)}; rule: min {col.min}")
                if col.max is not None and np.any(values > col.max):
                    raise SchemaError(f"{prefix}column '{col.name}' above {col.max} {col.unit} at rows "
                                      f"{_rows(full > col.max)}; rule: max {col.max}")
            if col.allowed is not None and len(values):
                bad = ~np.isin(s.to_numpy(), np.array(col.allowed)) & ~null
                if bad.any():
                    raise SchemaError(f"{prefix}column '{col.name}' has values outside {list(col.allowed)} "
                                      f"at rows {_rows(bad)}")

    def check_arrow(self, table: pa.Table, where: str = "") -> None:
        """``check`` for an Arrow table: a min/max pass per column instead of pandas masks (~10x faster).

        A table this clears would pass ``check``; anything it cannot clear at once is handed
        to ``check`` on its pandas form, so what is refused and the messages are the same.
        """
        known = {c.name for c in self.columns}
        names = set(table.column_names)
        if (names <= known and all(c.name in names for c in self.columns if c.required)
                and self.presence_problem(names) is None
                and all(_clears(c, table.column(c.name)) for c in self.present(names))):
            return
        self.check(table.to_pandas(), where)

    def to_arrow(self, df: pd.DataFrame, where: str = "") -> pa.Table:
        """Check, then convert with the schema's exact types and unit metadata."""
        self.check(df, where)
        schema = self.arrow_schema(df.columns)
        return pa.Table.from_pandas(df[[f.name for f in schema]], schema=schema, preserve_index=False)


def _clears(col: Column, arr: pa.ChunkedArray) -> bool:
    """True when ``arr`` surely meets ``col``'s rules (nulls, NaN, range, allowed); False: look closer."""
    import pyarrow.compute as pc
    if arr.null_count:
        if not col.nullable:
            return False
        arr = arr.drop_null()           # a nullable column's rules apply to its values
    if not len(arr):
        return True
    numeric = pa.types.is_integer(arr.type) or pa.types.is_floating(arr.type)
    if col.type.startswith(("int", "float")) != numeric or (
            col.type.startswith("int") and not pa.types.is_integer(arr.type)):
        return False
    if numeric:
        x = arr.to_numpy()                  # zero copy for one chunk; numpy's min/max beat Arrow's NaN-aware ones 20x
        with np.errstate(over="ignore", invalid="ignore"):
            if x.dtype.kind == "f" and not np.isfinite(x.sum()):     # a NaN or inf makes the sum so
                return False
    if col.min is None and col.max is None and col.allowed is None:
        return True
    if numeric:
        lo, hi = float(x.min()), float(x.max())     # float() as in check: monotone, so the same verdict
        if (col.min is not None and lo < col.min) or (col.max is not None and hi > col.max):
            return False
    if col.allowed is None:
        return True
    if (pa.types.is_integer(arr.type) and hi - lo < len(col.allowed)
            and set(range(int(lo), int(hi) + 1)) <= set(col.allowed)):
        return True             # every integer from min to max is allowed (dir: -1..1, mode: 0..2)
    try:
        allowed = pa.array(col.allowed, arr.type)
    except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError):
        return False
    return pc.all(pc.is_in(arr, value_set=allowed)).as_py()


def _rows(mask: np.ndarray, limit: int = 5) -> str:
    idx = np.flatnonzero(mask)
    shown = ", ".join(str(i) for i in idx[:limit])
    return shown + (f" (+{len(idx) - limit} more)" if len(idx) > limit else "")


def _bound(values: dict[str, float], ref: tuple[str, float] | None, fixed: float | None) -> float | None:
    return fixed if ref is None else values[ref[0]] + ref[1]


def _column(spec: dict[str, Any]) -> Column:
    """One column of a schema file; a bound given as ``{"rig": "section.key", "plus": k}`` depends on the rig."""
    spec = {**spec, "allowed": tuple(spec["allowed"]) if "allowed" in spec else None}
    for bound in ("min", "max"):
        if isinstance(spec.get(bound), dict):
            ref = spec.pop(bound)
            spec[f"rig_{bound}"] = (ref["rig"], ref.get("plus", 0))
    return Column(**spec)


def rig_keys(schema: TableSchema) -> tuple[str, ...]:
    """The rig configuration keys ("section.key") the schema's ranges depend on."""
    return tuple(sorted({ref[0] for c in schema.columns for ref in (c.rig_min, c.rig_max) if ref is not None}))


def load_schema(name: str, cfg: Any = None) -> TableSchema:
    """A table's schema; with ``cfg`` (a RigConfig) its rig-dependent ranges are that rig's, without
    it they are left unchecked (enough for names, types and units)."""
    schema = _load_schema(name)
    keys = rig_keys(schema)
    if cfg is None or not keys:
        return schema
    values = tuple((key, getattr(getattr(cfg, key.split(".")[0]), key.split(".")[1])) for key in keys)
    return _for_rig(name, values)


@lru_cache(maxsize=32)
def _for_rig(name: str, values: tuple[tuple[str, float], ...]) -> TableSchema:
    schema, resolved = _load_schema(name), dict(values)
    return replace(schema, columns=tuple(c.for_rig(resolved) for c in schema.columns))


@lru_cache(maxsize=None)
def _load_schema(name: str) -> TableSchema:
    path = SCHEMA_DIR / f"{name}.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    return TableSchema(name=data["name"], description=data.get("description", ""),
                       columns=tuple(_column(c) for c in data["columns"]),
                       together=tuple(tuple(g) for g in data.get("together", ())),
                       any_of=tuple(tuple(g) for g in data.get("any_of", ())))


def schema_names() -> list[str]:
    return sorted(p.stem for p in SCHEMA_DIR.glob("*.json"))
