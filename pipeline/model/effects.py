"""The catalogue of named effects (shared/MODEL.md), as small pluggable pieces.

Every effect is a frozen dataclass holding its parameter(s) with units, bounds
and a one-line physical meaning.  ``apply`` folds it into a ``PlantSpec``: the
linear effects change the base parameters (b, J, K1/K2) or the drive voltage,
the non-smooth ones set a term (Coulomb torque, backlash gap, loop delay,
sensor offset) that the simulators treat exactly.  Any combination is a list of
effects; stacking two of the same kind adds them up.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields, replace
from typing import ClassVar, Iterable

from pipeline.errors import ConfigError
from pipeline.model.params import ControllerParams, DriveParams, ModelParams


@dataclass(frozen=True)
class PlantSpec:
    """What a simulator needs: effective parameters plus the non-smooth terms.

    ``params`` already contains the linear effects (viscous friction added to
    b, rack inertia added to J, scaled springs); ``v_drive`` is the magnitude of
    the voltage the motor sees after the driver drop.
    """

    params: ModelParams
    v_drive: float          # V        |u| applied in q1/q2
    guard_rad: float        # rad      controller guard
    period_s: float         # s        nominal control period (used when no sample times are given)
    Tc: float = 0.0         # N m      Coulomb friction torque (0: none)
    gap: float = 0.0        # rad      total backlash width centred on theta = 0 (0: none)
    Td: float = 0.0         # s        loop delay from deciding sample to motor (0: none)
    I0: float = 0.0         # A        current sensor offset added to the measured current
    v_supply: float | None = None  # V  supply voltage before any driver drop (the paper's V_RMS); None: v_drive

    @property
    def v_rms(self) -> float:
        """The voltage the paper's energy estimate multiplies by: the supply's, not what reaches the motor."""
        return self.v_drive if self.v_supply is None else self.v_supply

    @property
    def is_linear(self) -> bool:
        """True when the plant is one linear system per mode (no Coulomb friction, no backlash)."""
        return self.Tc == 0.0 and self.gap == 0.0


@dataclass(frozen=True)
class Effect(ABC):
    """Base class: subclasses declare ``name``, ``UNITS``, ``BOUNDS``, ``WHAT`` and ``apply``."""

    name: ClassVar[str]
    UNITS: ClassVar[dict[str, str]]
    BOUNDS: ClassVar[dict[str, tuple[float, float]]]   # physically sensible range, used for checks and fits
    WHAT: ClassVar[str]

    @abstractmethod
    def apply(self, spec: PlantSpec) -> PlantSpec:
        """Fold this effect into the plant spec."""

    @property
    def parameters(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}

    def to_json(self) -> dict:
        return {"name": self.name, "parameters": self.parameters, "units": dict(self.UNITS)}


@dataclass(frozen=True)
class ViscousFriction(Effect):
    b: float
    name: ClassVar[str] = "viscous_friction"
    UNITS: ClassVar[dict[str, str]] = {"b": "N m s/rad"}
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"b": (0.0, 1e-2)}
    WHAT: ClassVar[str] = "J dw/dt gains -b*w"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, params=spec.params.with_(b=spec.params.b + self.b))


@dataclass(frozen=True)
class CoulombFriction(Effect):
    Tc: float
    name: ClassVar[str] = "coulomb_friction"
    UNITS: ClassVar[dict[str, str]] = {"Tc": "N m"}
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"Tc": (0.0, 1e-2)}
    WHAT: ClassVar[str] = "J dw/dt gains -Tc*sign(w); the pinion sticks at w = 0 while the other torques stay within Tc"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, Tc=spec.Tc + self.Tc)


@dataclass(frozen=True)
class DriverVoltageDrop(Effect):
    Vd: float
    name: ClassVar[str] = "driver_voltage_drop"
    UNITS: ClassVar[dict[str, str]] = {"Vd": "V"}
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"Vd": (0.0, 6.0)}
    WHAT: ClassVar[str] = "the H-bridge loses Vd: u = sign * max(V_in - Vd, 0)"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, v_drive=max(spec.v_drive - self.Vd, 0.0))


@dataclass(frozen=True)
class Backlash(Effect):
    gap: float
    name: ClassVar[str] = "backlash"
    UNITS: ClassVar[dict[str, str]] = {"gap": "rad"}
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"gap": (0.0, 0.5)}
    WHAT: ClassVar[str] = "play between pinion and racks: the springs act on R*dz(theta), a dead zone of width gap around 0"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, gap=spec.gap + self.gap)


@dataclass(frozen=True)
class LoopDelay(Effect):
    Td: float
    name: ClassVar[str] = "loop_delay"
    UNITS: ClassVar[dict[str, str]] = {"Td": "s"}
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"Td": (0.0, 0.5)}
    WHAT: ClassVar[str] = "a direction change reaches the motor Td after the sample that decided it"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, Td=spec.Td + self.Td)


@dataclass(frozen=True)
class CurrentSensorOffset(Effect):
    I0: float
    name: ClassVar[str] = "current_sensor_offset"
    UNITS: ClassVar[dict[str, str]] = {"I0": "A"}
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"I0": (-1.0, 1.0)}
    WHAT: ClassVar[str] = "the measured current is I + I0 (ACS712 zero mis-set)"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, I0=spec.I0 + self.I0)


@dataclass(frozen=True)
class RackInertia(Effect):
    Jr: float
    name: ClassVar[str] = "rack_inertia"
    UNITS: ClassVar[dict[str, str]] = {"Jr": "kg m^2"}
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"Jr": (0.0, 1e-2)}
    WHAT: ClassVar[str] = "inertia is J + Jr; the neglected racks give Jr = 2*M*R^2 = 1.94e-3"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        return replace(spec, params=spec.params.with_(J=spec.params.J + self.Jr))


@dataclass(frozen=True)
class SpringStiffness(Effect):
    k_scale: float
    name: ClassVar[str] = "spring_stiffness"
    UNITS: ClassVar[dict[str, str]] = {"k_scale": "-"}
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"k_scale": (0.2, 5.0)}
    WHAT: ClassVar[str] = "K1 = K2 = k_scale * 0.8682 (both springs scaled)"

    def apply(self, spec: PlantSpec) -> PlantSpec:
        p = spec.params
        return replace(spec, params=p.with_(K1=p.K1 * self.k_scale, K2=p.K2 * self.k_scale))


CATALOGUE: dict[str, type[Effect]] = {
    cls.name: cls for cls in (
        ViscousFriction, CoulombFriction, DriverVoltageDrop, Backlash,
        LoopDelay, CurrentSensorOffset, RackInertia, SpringStiffness,
    )
}
"""Every named effect of MODEL.md, by name, in MODEL.md's order."""


def parameter_names(name: str) -> tuple[str, ...]:
    return tuple(CATALOGUE[name].UNITS)


def make_effect(name: str, parameters: dict, *, where: str = "effects") -> Effect:
    """Build an effect from its MODEL.md name and parameter table, refusing unknown names, keys and bad values."""
    cls = CATALOGUE.get(name)
    if cls is None:
        raise ConfigError(f"unknown effect '{name}', expected one of {', '.join(CATALOGUE)}",
                          key=f"{where}.{name}")
    if not isinstance(parameters, dict):
        raise ConfigError(f"expected a table such as {{ {next(iter(cls.UNITS))} = ... }}",
                          key=f"{where}.{name}")
    expected = set(cls.UNITS)
    unknown = set(parameters) - expected
    if unknown:
        raise ConfigError(f"unknown parameter '{sorted(unknown)[0]}', expected {', '.join(sorted(expected))}",
                          key=f"{where}.{name}")
    missing = expected - set(parameters)
    if missing:
        raise ConfigError(f"missing parameter '{sorted(missing)[0]}' [{cls.UNITS[sorted(missing)[0]]}]",
                          key=f"{where}.{name}")
    values = {}
    for key, value in parameters.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"expected a number in {cls.UNITS[key]}, got {value!r}", key=f"{where}.{name}.{key}")
        lo, hi = cls.BOUNDS[key]
        if not (lo <= float(value) <= hi):
            raise ConfigError(f"expected a value in [{lo:g}, {hi:g}] {cls.UNITS[key]}, got {value!r}",
                              key=f"{where}.{name}.{key}")
        values[key] = float(value)
    return cls(**values)


def build_spec(params: ModelParams, controller: ControllerParams, drive: DriveParams,
               effects: Iterable[Effect] = ()) -> PlantSpec:
    """Fold a list of effects into the plant the simulators run."""
    spec = PlantSpec(params=params, v_drive=drive.v_in, v_supply=drive.v_in, guard_rad=controller.guard_rad,
                     period_s=controller.period_s)
    for effect in effects:
        spec = effect.apply(spec)
    return spec
