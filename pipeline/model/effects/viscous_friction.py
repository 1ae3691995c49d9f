"""Viscous friction (MODEL.md): a torque proportional to speed, folded into the base ``b`` of eq. (8)."""

from __future__ import annotations

from dataclasses import dataclass, replace

from pipeline.model.effects.base import Effect, Param, geometric_scan
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class ViscousFriction(Effect):
    b: float
    name = "viscous_friction"
    ORDER = 1
    WHAT = "J dw/dt gains -b*w"
    PARAMS = (
        Param("b", "N m s/rad", bounds=(0.0, 0.01), absent=0.0, typical=0.00077,
              scan=geometric_scan(1e-2)),)
    SIGNATURE = "everywhere"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, params=spec.params.with_(b=spec.params.b + self.b))
