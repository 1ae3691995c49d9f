"""What a simulator runs: the plant's effective parameters and the mechanisms effects act through.

An effect (``pipeline.model.effects``) never reaches into a simulator; it folds
itself into a ``PlantSpec`` through one of these mechanisms, which both the
fast simulator and the independent reference plant implement:

- the base parameters of eqs. (2), (4)/(8), (5) (``params``) and the drive voltage;
- a constant external torque on the pinion (``torque``);
- Coulomb friction with a stick mode (``Tc``), a dead zone of the springs (``gap``);
- a delay between the controller's decision and the motor (``Td``);
- a sensor-side offset of the measured current (``I0``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable

from pipeline.model.params import ControllerParams, DriveParams, ModelParams

if TYPE_CHECKING:
    from pipeline.model.effects.base import Effect


@dataclass(frozen=True)
class PlantSpec:
    """Effective parameters plus the non-smooth and additive terms, all in SI units."""

    params: ModelParams
    v_drive: float          # V        |u| applied in q1/q2
    guard_rad: float        # rad      controller guard
    period_s: float         # s        nominal control period (used when no sample times are given)
    Tc: float = 0.0         # N m      Coulomb friction torque (0: none)
    gap: float = 0.0        # rad      total width of the springs' dead zone, centred on theta = 0 (0: none)
    Td: float = 0.0         # s        delay from deciding sample to motor (0: none)
    I0: float = 0.0         # A        offset added to the measured current
    torque: float = 0.0     # N m      constant external torque on the pinion, positive towards +theta
    v_supply: float | None = None  # V  supply voltage before any driver drop (the paper's V_RMS); None: v_drive

    @property
    def v_rms(self) -> float:
        """The voltage the paper's energy estimate multiplies by: the supply's, not what reaches the motor."""
        return self.v_drive if self.v_supply is None else self.v_supply

    @property
    def is_linear(self) -> bool:
        """True when the plant is one affine system per mode (no Coulomb friction, no dead zone)."""
        return self.Tc == 0.0 and self.gap == 0.0


def build_spec(params: ModelParams, controller: ControllerParams, drive: DriveParams,
               effects: Iterable["Effect"] = ()) -> PlantSpec:
    """Fold a list of effects into the plant the simulators run (in order; two of a kind stack)."""
    spec = PlantSpec(params=params, v_drive=drive.v_in, v_supply=drive.v_in, guard_rad=controller.guard_rad,
                     period_s=controller.period_s)
    for effect in effects:
        spec = effect.apply(spec)
    return spec
