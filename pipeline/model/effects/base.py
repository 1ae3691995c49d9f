"""An effect as one self-contained piece: its parameters, how it enters the plant, what a fitter needs.

A subclass is a frozen dataclass with one float field per ``Param`` and lives
in its own module of this package; defining it registers it in the catalogue
(``pipeline.model.effects.CATALOGUE``), so nothing else has to name it.  Its
``name``, ``ORDER``, ``WHAT``, ``PARAMS`` and ``SIGNATURE`` are plain class
attributes (typed here, on ``Effect``; only the parameters are annotated in a
subclass, so only they are dataclass fields).  What it declares, and who reads it:

- ``PARAMS``: name, unit, physical bounds, the value meaning "absent", a
  typical visible value, the coarse scan points of discovery (as an lmfit
  ``Parameter`` carries its bounds);
- ``apply``: how it enters the plant, through a mechanism of ``PlantSpec``
  (simulators, reference plant, energy balance, virtual rig);
- ``SIGNATURE``: where its fingerprint lives in a residual (discovery);
- ``combine``: how two instances add up (merging found and declared effects).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from pipeline.model.params import PlantSpec

# Where an effect's residual fingerprint lives (``pipeline.discover.residuals.signatures``).
SIGNATURES = ("everywhere", "after_switch", "low_speed", "after_zero_crossing", "current_bias")

REGISTRY: dict[str, type["Effect"]] = {}


@dataclass(frozen=True)
class Param:
    """One parameter of an effect, with everything a check, a simulation or a fit needs to know."""

    name: str
    unit: str
    bounds: tuple[float, float]     # physically sensible range: config checks and fits stay inside
    absent: float                   # the value at which the effect is not there (an interval must exclude it)
    typical: float                  # a clearly visible value (examples, conformance tests, compile)
    scan: tuple[float, ...]         # discovery's coarse scan points, inside bounds, ``absent`` among them
    zero_of: str = ""               # the logged signal whose zero the value also is, were that zero read off the data

    @property
    def signed(self) -> bool:
        """Can the parameter sit on either side of ``absent`` (an offset, a scale)?"""
        return self.bounds[0] < self.absent < self.bounds[1]


def geometric_scan(top: float, lo: float = 0.0) -> tuple[float, ...]:
    """``lo`` then 11 values geometric up to ``top``, a factor 500 ** (1/14) apart (magnitudes span decades),
    from ~top/85.  Each point costs discovery a replay and a start estimate; the four below, down to top/500,
    were ~20 % of a scan and all under the smallest size discovery names (a tenth of the typical; a
    catalogue test checks every scan still reaches down to about that size)."""
    return (lo, *(float(v) for v in np.geomspace(top * 2e-3, top, 15)[4:]))


@dataclass(frozen=True)
class Effect(ABC):
    """Base class of the catalogue; see the module docstring for what a subclass declares."""

    name: ClassVar[str]
    ORDER: ClassVar[int]                 # position in MODEL.md's catalogue
    WHAT: ClassVar[str]                  # the change to the model, one line (MODEL.md's words)
    PARAMS: ClassVar[tuple[Param, ...]]
    SIGNATURE: ClassVar[str] = "everywhere"
    UNITS: ClassVar[dict[str, str]]
    BOUNDS: ClassVar[dict[str, tuple[float, float]]]

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        cls.UNITS = {p.name: p.unit for p in cls.PARAMS}
        cls.BOUNDS = {p.name: p.bounds for p in cls.PARAMS}
        REGISTRY[cls.name] = cls

    @abstractmethod
    def apply(self, spec: PlantSpec) -> PlantSpec:
        """Fold this effect into the plant spec (two instances of one effect must stack)."""

    def combine(self, other: "Effect") -> "Effect":
        """One effect equivalent to this and ``other`` together; parameters add unless overridden."""
        return type(self)(**{k: v + other.parameters[k] for k, v in self.parameters.items()})

    @classmethod
    def at(cls, value: float) -> "Effect":
        """The effect with its first parameter at ``value`` and any others at their typical values."""
        first, *rest = cls.PARAMS
        return cls(**{first.name: float(value), **{p.name: p.typical for p in rest}})

    @classmethod
    def typical(cls) -> "Effect":
        return cls(**{p.name: p.typical for p in cls.PARAMS})

    @property
    def parameters(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}

    @property
    def value(self) -> float:
        """The first parameter: the one discovery scans."""
        return float(getattr(self, self.PARAMS[0].name))

    def to_json(self) -> dict:
        return {"name": self.name, "parameters": self.parameters, "units": dict(self.UNITS)}
