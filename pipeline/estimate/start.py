"""A recording's estimated start, as a value: x0 at the first sample with its uncertainty and the
pre-log commands, and how to simulate from it on the sketch's own loop instants.  How it is
estimated is ``initial_state.py``'s business; validation, discovery and their reports only use this."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from pipeline.model.effects import PlantSpec
from pipeline.model.simulate import SimResult, simulate, with_lost_samples

STATE_NAMES = ("current_a", "omega_rad_s", "delta_m")


@dataclass(frozen=True)
class Start:
    """The estimated start of a recording; hashable, so fits can key caches on it."""

    x0: tuple[float, float, float]          # [I A, w rad/s, delta m] at the first sample
    sigma: tuple[float, float, float]       # their 1-sigma uncertainty
    lead_s: tuple[float, ...] = ()          # when the pre-log commands were decided, s relative to t0 (< 0)
    commands: tuple[int, ...] = ()          # those commands: the one in force at t0, then those in flight
    z: tuple[float, float, float] | None = None   # state at the first lead instant (x0 without a lead)
    current_offset: float = 0.0             # A: the current sensor's offset the start was estimated under
    angle_offset: float = 0.0               # rad: the counter's zero off the springs' rest it was estimated with

    @classmethod
    def given(cls, x0: tuple[float, float, float]) -> "Start":
        """A start known exactly (a simulation from rest, a test)."""
        return cls(x0=tuple(map(float, x0)), sigma=(0.0, 0.0, 0.0))

    def with_z(self, z) -> "Start":
        """This start moved to the state ``z`` at its first instant (x0 too, when there is no lead-in)."""
        z = tuple(float(v) for v in z)
        return replace(self, z=z, x0=z if not self.lead_s else self.x0)

    def simulate(self, spec: PlantSpec, t: np.ndarray, dir_log: np.ndarray, *, closed_loop: bool,
                 angle: np.ndarray | None = None, shifted: tuple[int, ...] = ()) -> SimResult:
        """``simulate`` from this start at the instants ``t`` (replay, or closed loop after the log's start),
        on the sketch's own loop instants: a row lost over serial is simulated too, its command decided
        by the sketch's rule (``with_lost_samples``: on the measured ``angle`` when given, one per
        sample in the guard's frame, else on the model's; ``shifted``: the gaps whose reversal is a sample
        from the rule's), and left out of the result."""
        t = np.asarray(t, dtype=float)
        dir0 = first_dir(np.concatenate([np.asarray(self.commands, dtype=np.int8), np.asarray(dir_log, dtype=np.int8)]))
        t_loop, d_loop, kept = with_lost_samples(t, np.asarray(dir_log, dtype=np.int8), angle, float(spec.guard_rad),
                                                  shifted)
        log = np.concatenate([np.asarray(self.commands, dtype=np.int8), d_loop])
        t_all = np.concatenate([t[0] + np.asarray(self.lead_s, dtype=float), t_loop])
        z = self.x0 if self.z is None else self.z
        sim = drop_lead(simulate(spec, t_all, x0=z, dir0=dir0, dir_log=log, closed_loop=closed_loop), len(self.lead_s))
        return sim if len(kept) == len(t_loop) else take(sim, kept)

    def to_json(self) -> dict:
        """What ``validation.json`` reports: x0 with its 1-sigma, and the pre-log commands."""
        return {**{k: float(v) for k, v in zip(STATE_NAMES, self.x0)},
                "sigma": {k: float(v) for k, v in zip(STATE_NAMES, self.sigma)},
                "pre_log_commands": [{"decided_s": float(s), "dir": int(c)}
                                     for s, c in zip(self.lead_s, self.commands)],
                "method": "least squares over the first samples (superposed simulations), "
                          "signals weighted by their noise"}


def first_dir(d: np.ndarray) -> int:
    """The first non-zero command (1 when there is none): the mode a closed loop starts in."""
    nz = np.flatnonzero(np.asarray(d) != 0)
    return int(d[nz[0]]) if len(nz) else 1


def take(sim: SimResult, index) -> SimResult:
    """The result at the samples ``index`` (a slice or an index array)."""
    return replace(sim, **{f.name: getattr(sim, f.name)[index] for f in fields(sim)
                           if isinstance(getattr(sim, f.name), np.ndarray)})


def drop_lead(sim: SimResult, m: int) -> SimResult:
    """The result without its first ``m`` samples (the pre-log instants)."""
    return sim if m == 0 else take(sim, slice(m, None))
