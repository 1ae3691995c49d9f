"""Loop delay (MODEL.md): the command decided at a sample reaches the motor Td later."""

from __future__ import annotations

from dataclasses import dataclass, replace

from pipeline.model.effects.base import Effect, Param, geometric_scan
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class LoopDelay(Effect):
    Td: float
    name = "loop_delay"
    ORDER = 5
    WHAT = "a direction change reaches the motor Td after the sample that decided it"
    PARAMS = (
        Param("Td", "s", bounds=(0.0, 0.5), absent=0.0, typical=0.05,
              scan=geometric_scan(0.3)),)
    SIGNATURE = "after_switch"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, Td=spec.Td + self.Td)
