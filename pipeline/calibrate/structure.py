"""What recordings of angle, velocity and current under a known voltage can pin down, and the
convention that fixes the rest (MODEL.md eqs. 2, 4/8, 5).

The electrical equation ``La dI/dt = u - Ra I - Ke w`` has the known input u on its right: with I and
w measured, Ra, Ke and La are pinned in absolute units.  The mechanical one, divided by J,
``dw/dt = (Kt/J) I - (b/J) w - (R^2 (K1 + K2)/J) theta``, pins only ratios to J: any J fits as well
once Kt, b and the springs scale with it.  The convention: J and R keep their prior values (Table I
or the rig's declared ones) and K1 = K2; Kt, b and the springs are fitted under it and reported as
not identifiable, their ratios to J as ``combinations``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.config import DEFAULT_SOURCE
from pipeline.estimate import SPRINGS, Prior, Unknown
from pipeline.model.params import ModelParams

IDENTIFIABLE = ("Ra", "Ke", "La")
FITTED = ("Ra", "Ke", "La", "Kt", "b", SPRINGS)         # under the convention; J and R held
CONVENTION = ("J and R are held at their prior values and K1 = K2: the mechanical equation pins only "
              "Kt/J, b/J and R^2 (K1 + K2)/J, so Kt, b, K1 and K2 are fitted under that J")
UNITS = {"R": "m", "J": "N m s^2", "Ke": "V s/rad", "Kt": "N m/A", "La": "H", "Ra": "Ohm", "K1": "N/m",
         "K2": "N/m", "b": "N m s/rad", SPRINGS: "N/m"}
BOUNDS = (1e-4, 1e4)      # of each fitted value relative to its prior: positive, any plausible rig

# sd of log(value) of the prior: Table I describes the paper's rig, and another lab's motor, gearbox and
# springs may differ from it by tens of percent; a declared value was measured or calibrated on this rig.
TABLE_I_TOLERANCE = 0.5
DECLARED_TOLERANCE = 0.1


@dataclass(frozen=True)
class Combination:
    name: str
    unit: str
    numerator: str

    def value(self, params: ModelParams) -> float:
        top = params.R ** 2 * (params.K1 + params.K2) if self.numerator == SPRINGS else getattr(params, self.numerator)
        return float(top / params.J)


COMBINATIONS = (Combination("Kt/J", "1/(A s^2)", "Kt"), Combination("b/J", "1/s", "b"),
                Combination("R^2 (K1 + K2)/J", "1/s^2", SPRINGS))


def base_unknowns(prior: ModelParams, declared: bool, names: tuple[str, ...] = FITTED) -> list[Unknown]:
    """The base parameters ``names`` as unknowns, log-normal priors about ``prior``."""
    sd = DECLARED_TOLERANCE if declared else TABLE_I_TOLERANCE
    out = []
    for name in names:
        centre = float(prior.K1 if name == SPRINGS else getattr(prior, name))
        out.append(Unknown(name=name, start=centre, bounds=(centre * BOUNDS[0], centre * BOUNDS[1]),
                           unit=UNITS[name], prior=Prior(centre=centre, sd=sd), log=True))
    return out


def declared_model(sources: dict[str, str]) -> bool:
    """Whether the rig's TOML set any ``[model]`` key (else the model is Table I's defaults)."""
    return any(key.startswith("model.") and src != DEFAULT_SOURCE for key, src in sources.items())


def scaled_interval(span: tuple[float, float] | None, factor: float) -> list[float] | None:
    if span is None or not all(np.isfinite(span)):
        return None
    return [float(span[0] * factor), float(span[1] * factor)]
