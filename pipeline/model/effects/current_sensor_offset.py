"""Current sensor offset (MODEL.md): the ACS712's zero mis-set; only the measured current moves."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.model.effects.base import Effect, Param
from pipeline.model.params import PlantSpec


# Discovery's scan points, A (and their negatives): finer than an ADC step near zero, where a
# zero mis-set lives, a quarter of the value beyond.  Each point is a replay (the start is estimated
# under each offset); the 161 evenly spaced points they replace cost a tenth to a fifth of discovery's CPU.
_SCAN = np.array([0.0125, 0.025, 0.0375, 0.05, 0.0625, 0.075, 0.1, 0.125, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5,
                  0.6, 0.8, 1.0])


@dataclass(frozen=True)
class CurrentSensorOffset(Effect):
    I0: float
    name = "current_sensor_offset"
    ORDER = 6
    WHAT = "the measured current is I + I0 (ACS712 zero mis-set)"
    PARAMS = (
        Param("I0", "A", bounds=(-1.0, 1.0), absent=0.0, typical=0.06,
              scan=tuple(np.concatenate([-_SCAN[::-1], [0.0], _SCAN])), zero_of="current"),)
    SIGNATURE = "current_bias"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, I0=spec.I0 + self.I0)
