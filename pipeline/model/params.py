"""The model's parameters: the paper's (Table I, the controller, the drive) and, with the effects
folded in, the plant a simulator runs (``PlantSpec``).

Why ``Ra = 2.59 Ohm`` and not Table I's printed ``2.59e2``: with 259 Ohm the
static gain theta/u is 0.0165 rad/V, so 6 V holds the pinion near 0.10 rad, the
0.94 rad guard is never reached and nothing switches; with 2.59 Ohm the gain
is 1.65 rad/V, the rig oscillates with about 13 switches in 24.95 s and the
paper's energy estimate comes out near its 16.496 J (see docs/MODEL.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Iterable

import numpy as np

if TYPE_CHECKING:
    from pipeline.model.effects.base import Effect


@dataclass(frozen=True)
class ModelParams:
    """Base model of eqs. (2), (4)/(8), (5): SI units, MODEL.md names."""

    R: float = 49.5e-3      # m        pinion radius
    J: float = 4.857e-4     # N m s^2  pinion + motor inertia
    Ke: float = 1.1459      # V s/rad  back-EMF constant
    Kt: float = 0.01819     # N m/A    torque constant
    La: float = 18.138      # H        armature inductance
    Ra: float = 2.59        # Ohm      armature resistance (Table I misprints 2.59e2, see module doc)
    K1: float = 0.8682      # N/m      spring 1 stiffness
    K2: float = 0.8682      # N/m      spring 2 stiffness
    b: float = 7.7e-4       # N m s/rad viscous friction identified in Sec. IV-A (eq. 8); 0 gives eq. (6)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def with_(self, **changes: float) -> "ModelParams":
        return replace(self, **changes)

    @property
    def spring_torque_per_rad(self) -> float:
        """Ks [N m/rad]: torque of both springs per radian of pinion angle, R^2 (K1 + K2)."""
        return self.R * self.R * (self.K1 + self.K2)

    def static_gain(self) -> float:
        """theta/u at rest [rad/V]: Kt / (Ra * Ks) -- 1.65 rad/V for Table I with Ra = 2.59."""
        return self.Kt / (self.Ra * self.spring_torque_per_rad)

    def state_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """A, B of eq. (8) for x = [I, w, delta] (eq. (6) when b = 0)."""
        R, J, La = self.R, self.J, self.La
        a00, a01 = -self.Ra / La, -self.Ke / La                               # (2)
        a10, a11, a12 = self.Kt / J, -self.b / J, -R * (self.K1 + self.K2) / J   # (4), (8)
        a21, b0 = R, 1.0 / La                                                 # (5), (2)
        return np.array([[a00, a01, 0.0], [a10, a11, a12], [0.0, a21, 0.0]]), np.array([b0, 0.0, 0.0])


@dataclass(frozen=True)
class ControllerParams:
    """The Arduino's bang-bang law: sample every period_s, reverse at +/- guard_rad."""

    period_s: float = 0.05                       # s   T_c, the sketch's loop period
    guard_rad: float = 2.0 * math.pi * 0.15      # rad theta_g = 0.15 rev = 0.9425 rad


@dataclass(frozen=True)
class DriveParams:
    """The H-bridge output: +v_in in q1, -v_in in q2 (Sec. IV-C)."""

    v_in: float = 6.0                            # V   12 V at 25 % PWM duty as RMS, 12*sqrt(0.25)


@dataclass(frozen=True)
class PlantSpec:
    """What a simulator runs: effective parameters plus the mechanisms effects act through, in SI units.

    An effect (``pipeline.model.effects``) never reaches into a simulator; it
    folds itself into a ``PlantSpec`` through one of these mechanisms, which
    both the fast simulator and the independent reference plant implement: the
    base parameters of eqs. (2), (4)/(8), (5) (``params``) and the drive
    voltage; a constant external torque on the pinion (``torque``); Coulomb
    friction with a stick mode (``Tc``), a dead zone of the springs (``gap``);
    a delay between the controller's decision and the motor (``Td``); a
    sensor-side offset of the measured current (``I0``).
    """

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
