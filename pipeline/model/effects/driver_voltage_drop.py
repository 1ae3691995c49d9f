"""Driver voltage drop (MODEL.md): the H-bridge's loss, so the motor sees less than V_in in both modes."""

from __future__ import annotations

from dataclasses import dataclass, replace

from pipeline.model.effects.base import Effect, Param, geometric_scan
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class DriverVoltageDrop(Effect):
    Vd: float
    name = "driver_voltage_drop"
    ORDER = 3
    WHAT = "the H-bridge loses Vd: u = sign * max(V_in - Vd, 0)"
    PARAMS = (
        Param("Vd", "V", bounds=(0.0, 6.0), absent=0.0, typical=1.2,
              scan=geometric_scan(5.0)),)
    SIGNATURE = "everywhere"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, v_drive=max(spec.v_drive - self.Vd, 0.0))
