"""Current sensor offset (MODEL.md): the ACS712's zero mis-set; only the measured current moves."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.model.effects.base import Effect, Param
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class CurrentSensorOffset(Effect):
    I0: float
    name = "current_sensor_offset"
    ORDER = 6
    WHAT = "the measured current is I + I0 (ACS712 zero mis-set)"
    PARAMS = (
        Param("I0", "A", bounds=(-1.0, 1.0), absent=0.0, typical=0.06,
              scan=tuple(np.linspace(-1.0, 1.0, 161)), zero_of="current"),)
    SIGNATURE = "current_bias"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, I0=spec.I0 + self.I0)
