"""The catalogue of named effects (docs/MODEL.md): one module per effect in this package.

Every module here defines one ``Effect`` subclass (``base.py`` says what it
declares); importing the package imports them all, so a new effect is a new
module and nothing else.  ``CATALOGUE`` lists them in MODEL.md's order.
"""

from __future__ import annotations

import importlib
import pkgutil

from pipeline.errors import ConfigError, shown
from pipeline.model.effects.base import REGISTRY, SIGNATURES, Effect, Param
from pipeline.model.params import PlantSpec, build_spec

for _module in pkgutil.iter_modules(__path__):
    if _module.name != "base":
        importlib.import_module(f"{__name__}.{_module.name}")

CATALOGUE: dict[str, type[Effect]] = dict(sorted(REGISTRY.items(), key=lambda item: item[1].ORDER))
"""Every named effect of MODEL.md, by name, in MODEL.md's order."""

__all__ = ["CATALOGUE", "SIGNATURES", "Effect", "Param", "PlantSpec", "build_spec", "make_effect",
           "parameter_names"]


def parameter_names(name: str) -> tuple[str, ...]:
    return tuple(CATALOGUE[name].UNITS)


def make_effect(name: str, parameters: dict, *, where: str = "effects") -> Effect:
    """Build an effect from its MODEL.md name and parameter table, refusing unknown names, keys and bad values."""
    cls = CATALOGUE.get(name)
    if cls is None:
        raise ConfigError(f"unknown effect '{name}', expected one of {', '.join(CATALOGUE)}",
                          key=f"{where}.{name}")
    if not isinstance(parameters, dict):
        raise ConfigError(f"expected a table such as {{ {cls.PARAMS[0].name} = ... }}", key=f"{where}.{name}")
    expected = set(cls.UNITS)
    unknown = set(parameters) - expected
    if unknown:
        raise ConfigError(f"unknown parameter '{sorted(unknown)[0]}', expected {', '.join(sorted(expected))}",
                          key=f"{where}.{name}")
    missing = expected - set(parameters)
    if missing:
        raise ConfigError(f"missing parameter '{sorted(missing)[0]}' [{cls.UNITS[sorted(missing)[0]]}]",
                          key=f"{where}.{name}")
    values = {}
    for key, value in parameters.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"expected a number in {cls.UNITS[key]}, got {shown(value)}", key=f"{where}.{name}.{key}")
        lo, hi = cls.BOUNDS[key]
        if not (lo <= value <= hi):         # compared as given: a 400-digit integer is too large for float()
            raise ConfigError(f"expected a value in [{lo:g}, {hi:g}] {cls.UNITS[key]}, got {shown(value)}",
                              key=f"{where}.{name}.{key}")
        values[key] = float(value)
    return cls(**values)
