"""Spring stiffness (MODEL.md): both springs stiffer or softer than Table I by one factor."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.model.effects.base import Effect, Param
from pipeline.model.params import PlantSpec


@dataclass(frozen=True)
class SpringStiffness(Effect):
    k_scale: float
    name = "spring_stiffness"
    ORDER = 8
    WHAT = "K1 = K2 = k_scale * 0.8682 (both springs scaled)"
    PARAMS = (
        Param("k_scale", "-", bounds=(0.2, 5.0), absent=1.0, typical=1.3,
              scan=tuple(np.unique(np.concatenate([np.geomspace(0.25, 4.0, 17), [0.9, 0.95, 0.98, 1.0, 1.02, 1.05, 1.1]])))),)
    SIGNATURE = "everywhere"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, params=spec.params.with_(K1=spec.params.K1 * self.k_scale, K2=spec.params.K2 * self.k_scale))

    def combine(self, other: Effect) -> Effect:
        """Two scalings of the springs multiply."""
        return SpringStiffness(k_scale=self.k_scale * other.parameters["k_scale"])
