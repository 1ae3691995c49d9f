"""Rack inertia (MODEL.md): the racks' mass, neglected by the paper, adds to the pinion's inertia."""

from __future__ import annotations

from dataclasses import dataclass, replace

from pipeline.model.effects.base import Effect, Param, geometric_scan
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class RackInertia(Effect):
    Jr: float
    name = "rack_inertia"
    ORDER = 7
    WHAT = "inertia is J + Jr; the neglected racks give Jr = 2*M*R^2 = 1.94e-3"
    PARAMS = (
        Param("Jr", "kg m^2", bounds=(0.0, 0.01), absent=0.0, typical=0.00194,
              scan=geometric_scan(1e-2)),)
    SIGNATURE = "everywhere"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, params=spec.params.with_(J=spec.params.J + self.Jr))
