"""Rig configuration: built-in defaults < raw/rig.toml < raw/<name>.toml.

The defaults are the paper's rig (docs/MODEL.md) and live only here and in
``pipeline.model.params``.  Every key read from a file is checked (known key,
type, sign) and the error names the file and the key; every resolved value
remembers where it came from, for the ingest report.
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Callable

from pipeline.errors import ConfigError, shown
from pipeline.model.effects import Effect, PlantSpec, build_spec, make_effect
from pipeline.model.params import ControllerParams, DriveParams, ModelParams

DEFAULT_SOURCE = "default"


@dataclass(frozen=True)
class EncoderConfig:
    counts_per_rev: float = 6533.12      # counts per pinion rev: 64 counts per motor rev (x4 quadrature) x 102.08 gearbox


@dataclass(frozen=True)
class CurrentSensorConfig:
    sensitivity_v_per_a: float = 0.185   # V/A, ACS712-05B (0.100 for 20 A, 0.066 for 30 A parts)
    zero_v: float | str = 2.5            # V at 0 A, or "auto": estimated from samples at rest
    adc_vref: float = 5.0                # V, UNO analogRead reference
    adc_steps: int = 1024                # 10-bit ADC


@dataclass(frozen=True)
class ColumnsConfig:
    """Raw column names; an empty string means the sketch does not log that column."""

    t_ms: str = "t_ms"
    counts: str = "counts"
    adc: str = "adc"
    dir: str = "dir"
    time_unit: str = "ms"                # "ms" (millis), "us" (micros) or "s"


@dataclass(frozen=True)
class IngestConfig:
    max_bad_fraction: float = 0.2        # refuse a recording when more than this share of data lines is unreadable


@dataclass(frozen=True)
class RigConfig:
    encoder: EncoderConfig = EncoderConfig()
    current_sensor: CurrentSensorConfig = CurrentSensorConfig()
    drive: DriveParams = DriveParams()
    controller: ControllerParams = ControllerParams()
    model: ModelParams = ModelParams()
    effects: tuple[Effect, ...] = ()
    columns: ColumnsConfig = ColumnsConfig()
    ingest: IngestConfig = IngestConfig()
    # "section.key" -> "default" or the path of the file that set it
    sources: dict[str, str] = field(default_factory=dict, compare=False)

    def plant_spec(self, extra_effects: tuple[Effect, ...] = ()) -> PlantSpec:
        """The model the simulators run for this rig: [model] + [effects] (+ extra)."""
        return build_spec(self.model, self.controller, self.drive, (*self.effects, *extra_effects))

    def to_dict(self) -> dict[str, Any]:
        """Nested plain dict in the TOML layout (round-trips through ``config_from_dict``)."""
        out: dict[str, Any] = {}
        for section in _SECTIONS:
            out[section] = {k: v for k, v in asdict(getattr(self, section)).items()}
        out["effects"] = {e.name: e.parameters for e in self.effects}
        return out


# section -> (dataclass type, per-key checker)
Checker = Callable[[str, Any], Any]


def _number(positive: bool = True, allow_zero: bool = False, lo: float | None = None,
            hi: float | None = None, integer: bool = False) -> Checker:
    def check(key: str, value: Any) -> Any:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
            kind = "an integer" if integer else "a number"
            raise ValueError(f"expected {kind}, got {shown(value)}")
        if isinstance(value, float) and not math.isfinite(value):      # an int is finite (and may not fit a float)
            raise ValueError(f"expected a finite number, got {shown(value)}")
        if positive and (value < 0 or (value == 0 and not allow_zero)):
            raise ValueError(f"expected a {'non-negative' if allow_zero else 'positive'} number, got {shown(value)}")
        if lo is not None and value < lo or hi is not None and value > hi:
            raise ValueError(f"expected a value in [{lo}, {hi}], got {shown(value)}")
        return value if integer else float(value)
    return check


def _zero_v(key: str, value: Any) -> Any:
    if value == "auto":
        return "auto"
    try:
        return _number(lo=0.0, hi=50.0, allow_zero=True)(key, value)
    except ValueError:
        raise ValueError(f"expected a voltage in volts or \"auto\", got {shown(value)}") from None


def _string(key: str, value: Any) -> str:
    if not isinstance(value, str):
        raise ValueError(f"expected a column name (string, \"\" if not logged), got {shown(value)}")
    return value


def _time_unit(key: str, value: Any) -> str:
    if value not in ("ms", "us", "s"):
        raise ValueError(f"expected \"ms\", \"us\" or \"s\", got {shown(value)}")
    return value


# Physically sensible ranges, wide enough for any bench rig of this kind (a 1 kHz logger, a 24-bit
# ADC, Table I's misprinted Ra = 259 Ohm) and narrow enough that a slip of the exponent is refused.
MODEL_BOUNDS = {"R": (1e-4, 10.0), "J": (1e-9, 1e3), "Ke": (1e-6, 1e3), "Kt": (1e-6, 1e3), "La": (1e-9, 1e3),
                "Ra": (1e-4, 1e5), "K1": (1e-6, 1e7), "K2": (1e-6, 1e7), "b": (0.0, 1e3)}


def _bounded(lo: float, hi: float, integer: bool = False) -> Checker:
    return _number(allow_zero=lo == 0.0, lo=lo, hi=hi, integer=integer)


_SECTIONS: dict[str, tuple[type, dict[str, Checker]]] = {
    "encoder": (EncoderConfig, {"counts_per_rev": _bounded(1.0, 1e7)}),
    "current_sensor": (CurrentSensorConfig, {
        "sensitivity_v_per_a": _bounded(1e-4, 100.0), "zero_v": _zero_v,
        "adc_vref": _bounded(0.1, 50.0), "adc_steps": _bounded(2, 1 << 24, integer=True)}),
    "drive": (DriveParams, {"v_in": _bounded(1e-3, 1000.0)}),
    "controller": (ControllerParams, {"period_s": _bounded(1e-6, 60.0), "guard_rad": _bounded(1e-4, 1000.0)}),
    "model": (ModelParams, {name: _bounded(*MODEL_BOUNDS[name]) for name in ModelParams.names()}),
    "columns": (ColumnsConfig, {"t_ms": _string, "counts": _string, "adc": _string, "dir": _string,
                                "time_unit": _time_unit}),
    "ingest": (IngestConfig, {"max_bad_fraction": _number(lo=0.0, hi=1.0, allow_zero=True)}),
}


def _apply_layer(cfg: RigConfig, data: dict[str, Any], source: str) -> RigConfig:
    sources = dict(cfg.sources)
    changes: dict[str, Any] = {}
    for section, table in data.items():
        if section == "effects":
            if not isinstance(table, dict):
                raise ConfigError("expected a table of effects, e.g. effects.loop_delay = { Td = 0.05 }",
                                  path=source, key="effects")
            effects = []
            for name, params in table.items():
                try:
                    effects.append(make_effect(name, params))
                except ConfigError as err:
                    raise ConfigError(err.detail, path=source, key=err.key) from None
                sources[f"effects.{name}"] = source
            # a layer's [effects] replaces the whole effect list of the layers below
            changes["effects"] = tuple(effects)
            continue
        if section not in _SECTIONS:
            raise ConfigError(f"unknown section, expected one of {', '.join([*_SECTIONS, 'effects'])}",
                              path=source, key=section)
        if not isinstance(table, dict):
            raise ConfigError("expected a table", path=source, key=section)
        cls, checkers = _SECTIONS[section]
        updates = {}
        for key, value in table.items():
            if key not in checkers:
                raise ConfigError(f"unknown key, expected one of {', '.join(checkers)}",
                                  path=source, key=f"{section}.{key}")
            try:
                updates[key] = checkers[key](key, value)
            except ValueError as err:
                raise ConfigError(str(err), path=source, key=f"{section}.{key}") from None
            sources[f"{section}.{key}"] = source
        changes[section] = replace(changes.get(section, getattr(cfg, section)), **updates)
    if "columns" in changes:
        _check_columns(changes["columns"], source)
    return replace(cfg, **changes, sources=sources)


def _check_columns(columns: ColumnsConfig, source: str) -> None:
    """The time column is required, and the angle or the current; no two logical columns may name one raw column.

    Without an encoder (``counts = ""``) what needs the angle is skipped by each stage, which says so;
    without the current too, nothing is measured that pdr could process.
    """
    if not columns.t_ms:
        raise ConfigError("expected the name of the column holding the sample time", path=source, key="columns.t_ms")
    if not columns.counts and not columns.adc:
        raise ConfigError("expected the name of the column holding the encoder count, or of the current "
                          "(columns.adc): with neither, the capture has nothing pdr can process",
                          path=source, key="columns.counts")
    named: dict[str, str] = {}
    for key in ("t_ms", "counts", "adc", "dir"):
        name = getattr(columns, key)
        if name and name in named:
            raise ConfigError(f"'{name}' is already the column of columns.{named[name]}; expected a different "
                              f"raw column (or \"\" when not logged)", path=source, key=f"columns.{key}")
        named[name] = key


def default_config() -> RigConfig:
    cfg = RigConfig()
    sources = {f"{s}.{f.name}": DEFAULT_SOURCE for s, (cls, _) in _SECTIONS.items() for f in fields(cls)}
    return replace(cfg, sources=sources)


MAX_TOML_BYTES = 1 << 20    # a rig file is a few hundred bytes; a bigger one is not a rig file


def check_toml_file(path: Path) -> None:
    """Refuse, by ``stat`` alone, a TOML path that is not a regular file of rig-file size."""
    from pipeline.io.files import regular_file_problem

    problem = regular_file_problem(path)
    if problem is not None:
        raise ConfigError(problem.replace("CSV", "TOML"), path=path)
    size = os.path.getsize(path)
    if size > MAX_TOML_BYTES:
        raise ConfigError(f"{size} bytes, expected a rig TOML of at most {MAX_TOML_BYTES} bytes", path=path)


def read_toml(path: Path) -> dict[str, Any]:
    """A rig TOML's tables, refused by kind and size before it is opened (a FIFO would block the read,
    ``/dev/zero`` never end) and by key when its values are not what a rig file holds."""
    check_toml_file(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"expected UTF-8 TOML text ({err.reason} at byte {err.start})", path=path) from None
    except OSError as err:
        raise ConfigError(f"cannot read: {err.strerror}", path=path) from None
    if text.startswith("\ufeff"):
        raise ConfigError("starts with a UTF-8 byte-order mark (BOM), which TOML does not allow; save it as "
                          "UTF-8 without BOM", path=path, line=1)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"expected valid TOML: {err}", path=path) from None
    except ValueError as err:       # an integer of more than 4300 digits (Python's limit on converting one)
        line, key = _where(text, lambda part, depth: LONG_DIGITS.search(part) is not None)
        raise ConfigError(f"expected a number a rig file can hold: {err}".split("; use")[0],
                          path=path, line=line, key=key) from None
    except RecursionError:
        line, key = _where(text, lambda part, depth: depth > MAX_NESTING)
        raise ConfigError(f"arrays or inline tables nested deeper than the TOML reader can follow (more than "
                          f"{MAX_NESTING} levels here); expected a number or a string",
                          path=path, line=line, key=key) from None


MAX_NESTING = 100          # where the message looks: a rig file nests nothing, Python's reader stops near 300
LONG_DIGITS = re.compile(r"[0-9_]{4300,}")


def _where(text: str, bad: Callable[[str, int], bool]) -> tuple[int | None, str | None]:
    """The line and key (``section.key``) of the first value the TOML reader gave up on: the first line
    for which ``bad(text so far on the line, bracket depth)`` holds.  Brackets are counted roughly
    (strings included): only to name where the reader gave up."""
    section, depth, where = "", 0, None
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if depth == 0 and stripped.startswith("[") and "=" not in stripped:
            section = stripped.strip("[] ")
            continue
        if depth == 0 and "=" in stripped:
            key = stripped.split("=", 1)[0].strip()
            where = f"{section}.{key}" if section else key
        for ch in stripped:
            depth += ch in "[{"
            depth -= ch in "]}"
            if depth > MAX_NESTING and bad("", depth):
                return number, where
        if bad(stripped, depth):
            return number, where
    return None, None


def resolve_config(layers: list[Path], base: RigConfig | None = None) -> RigConfig:
    """Apply TOML files in order (later wins) over the defaults."""
    cfg = base if base is not None else default_config()
    for path in layers:
        cfg = _apply_layer(cfg, read_toml(path), str(path))
    return cfg


def config_layers_for(csv_path: Path) -> list[Path]:
    """The TOML files that apply to a recording: raw/rig.toml, then raw/<name>.toml, when present."""
    folder = csv_path.parent
    layers = [p for p in (folder / "rig.toml", csv_path.with_suffix(".toml")) if os.path.lexists(p)]
    for path in layers:         # a FIFO would block the read, a directory or dead link would be skipped unseen
        check_toml_file(path)
    return layers


def config_for_recording(csv_path: Path) -> RigConfig:
    return resolve_config(config_layers_for(csv_path))


def config_from_dict(data: dict[str, Any], source: str = "stored") -> RigConfig:
    """Inverse of ``RigConfig.to_dict`` (used for the resolved config stored beside processed data)."""
    return _apply_layer(default_config(), data, source)


def effects_toml_snippet(effects: tuple[Effect, ...] | list[Effect]) -> str:
    """The ``[effects]`` table a user can paste into a rig TOML (docs/FORMAT.md form)."""
    lines = ["[effects]"]
    for e in effects:
        inner = ", ".join(f"{k} = {v:.6g}" for k, v in e.parameters.items())
        lines.append(f"{e.name} = {{ {inner} }}")
    return "\n".join(lines) + "\n"
