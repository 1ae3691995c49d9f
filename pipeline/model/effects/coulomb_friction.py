"""Coulomb friction (MODEL.md): a constant torque against the motion and a stick mode at w = 0,
simulated exactly by the event-driven plant (``pipeline.model.nonsmooth``)."""

from __future__ import annotations

from dataclasses import dataclass, replace

from pipeline.model.effects.base import Effect, Param, geometric_scan
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class CoulombFriction(Effect):
    Tc: float
    name = "coulomb_friction"
    ORDER = 2
    WHAT = "J dw/dt gains -Tc*sign(w); the pinion sticks at w = 0 while the other torques stay within Tc"
    PARAMS = (
        Param("Tc", "N m", bounds=(0.0, 0.01), absent=0.0, typical=0.0015,
              scan=geometric_scan(5e-3)),)
    SIGNATURE = "low_speed"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, Tc=spec.Tc + self.Tc)
