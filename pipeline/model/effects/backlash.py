"""Backlash (MODEL.md): play between pinion and racks, a dead zone of the springs centred on theta = 0."""

from __future__ import annotations

from dataclasses import dataclass, replace

from pipeline.model.effects.base import Effect, Param, geometric_scan
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class Backlash(Effect):
    gap: float
    name = "backlash"
    ORDER = 4
    WHAT = "play between pinion and racks: the springs act on R*dz(theta), a dead zone of width gap around 0"
    PARAMS = (
        Param("gap", "rad", bounds=(0.0, 0.5), absent=0.0, typical=0.08,
              scan=geometric_scan(0.4)),)
    SIGNATURE = "after_zero_crossing"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, gap=spec.gap + self.gap)
