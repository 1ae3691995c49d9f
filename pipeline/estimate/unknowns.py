"""What a fit may move: base parameters and effect parameters, each with its bounds and prior.

A model is a value: the base parameters of eqs. (2), (4)/(8), (5) (``ModelParams``) plus a set of
catalogued effects.  An ``Unknown`` names one number of it: a base parameter (``"Ra"``), the two
springs together (``"K"``: K1 = K2, the only spring quantity a symmetric rig's data can tell), or an
effect's parameter (``"coulomb_friction.Tc"``).  Positive scales are fitted in log space (a
relative error is what a tolerance on Table I means); offsets are fitted as they are.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.model.effects import CATALOGUE, Effect
from pipeline.model.params import ModelParams

SPRINGS = "K"        # K1 = K2 moved together


@dataclass(frozen=True)
class Prior:
    """Normal in the fitted coordinate: log space for a positive scale (``sd`` ~ a relative tolerance)."""

    centre: float
    sd: float


@dataclass(frozen=True)
class Unknown:
    name: str
    start: float
    bounds: tuple[float, float]
    unit: str = ""
    prior: Prior | None = None
    log: bool = False            # fitted as log(value) (a positive scale)
    scale: float = 1.0           # otherwise fitted as value / scale (a parameter that may be 0, in its own size)

    def to_internal(self, value: float) -> float:
        return float(np.log(value)) if self.log else float(value / self.scale)

    def to_value(self, z: float) -> float:
        return float(np.exp(z)) if self.log else float(z * self.scale)

    @property
    def internal_bounds(self) -> tuple[float, float]:
        lo, hi = self.bounds
        if self.log:
            return float(np.log(max(lo, 1e-300))), float(np.log(hi)) if np.isfinite(hi) else np.inf
        return float(lo / self.scale), float(hi / self.scale)

    def prior_row(self, z: float) -> float | None:
        """The prior's residual row, in the fitted coordinate (None: no prior)."""
        if self.prior is None:
            return None
        return (z - self.to_internal(self.prior.centre)) / self.prior.sd


@dataclass(frozen=True)
class Model:
    """Base parameters plus effects: what a simulator runs for one rig (controller and drive aside)."""

    base: ModelParams
    effects: tuple[Effect, ...] = ()

    def value_of(self, name: str) -> float:
        if name == SPRINGS:
            return float(self.base.K1)
        if "." in name:
            effect, param = name.split(".", 1)
            return next(e.parameters[param] for e in self.effects if e.name == effect)
        return float(getattr(self.base, name))

    def with_values(self, values: dict[str, float]) -> "Model":
        base_changes: dict[str, float] = {}
        effect_changes: dict[str, dict[str, float]] = {}
        for name, v in values.items():
            if name == SPRINGS:
                base_changes.update(K1=v, K2=v)
            elif "." in name:
                effect, param = name.split(".", 1)
                effect_changes.setdefault(effect, {})[param] = v
            else:
                base_changes[name] = v
        effects = tuple(type(e)(**{**e.parameters, **effect_changes.get(e.name, {})}) for e in self.effects)
        return Model(base=replace(self.base, **base_changes), effects=effects)


def effect_unknowns(effect: Effect, scaled: bool = False) -> list[Unknown]:
    """Every parameter of an effect (all of them, not the first), within its physical bounds, no prior;
    ``scaled``: each in units of its own size (its value, or its typical size near absent)."""
    return [Unknown(name=f"{effect.name}.{p.name}", start=effect.parameters[p.name], bounds=p.bounds, unit=p.unit,
                    scale=max(abs(effect.parameters[p.name]), abs(p.typical - p.absent), 1e-12) if scaled else 1.0)
            for p in CATALOGUE[effect.name].PARAMS]
