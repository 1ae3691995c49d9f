"""Loop delay (MODEL.md): the command decided at a sample reaches the motor Td later."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

from pipeline.model.effects.base import Effect, Param, geometric_scan
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class LoopDelay(Effect):
    Td: float
    name: ClassVar[str] = "loop_delay"
    ORDER: ClassVar[int] = 5
    WHAT: ClassVar[str] = "a direction change reaches the motor Td after the sample that decided it"
    PARAMS: ClassVar[tuple[Param, ...]] = (
        Param("Td", "s", bounds=(0.0, 0.5), absent=0.0, typical=0.05,
              scan=geometric_scan(0.3)),)
    SIGNATURE: ClassVar[str] = "after_switch"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, Td=spec.Td + self.Td)
