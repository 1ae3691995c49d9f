"""Constant load torque (MODEL.md): a torque on the pinion that does not depend on the motion,
e.g. racks of unequal weight on a tilted rig or a cable pulling one way.  The oscillation centres
on theta = -Tl / (R^2 (K1 + K2)) instead of 0."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.model.effects.base import Effect, Param
from pipeline.model.params import PlantSpec

_MAGNITUDES = tuple(float(v) for v in np.geomspace(1e-5, 5e-3, 12))


@dataclass(frozen=True)
class ConstantLoadTorque(Effect):
    Tl: float
    name = "constant_load_torque"
    ORDER = 9
    WHAT = "J dw/dt gains -Tl: a constant torque on the pinion"
    PARAMS = (
        Param("Tl", "N m", bounds=(-2e-2, 2e-2), absent=0.0, typical=1e-3,
              scan=(*(-v for v in reversed(_MAGNITUDES)), 0.0, *_MAGNITUDES)),)
    SIGNATURE = "everywhere"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, torque=spec.torque - self.Tl)
