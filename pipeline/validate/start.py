"""A recording's estimated start, as a value: x0 at the first sample with its uncertainty and the
pre-log commands, and how to simulate from it on the sketch's own loop instants.  How it is
estimated is ``initial_state.py``'s business; validation, discovery and their reports only use this."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from pipeline.model.effects import PlantSpec
from pipeline.model import loop
from pipeline.model.simulate import SimResult, next_dir, simulate, with_lost_samples

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

    @classmethod
    def given(cls, x0: tuple[float, float, float]) -> "Start":
        """A start known exactly (a simulation from rest, a test)."""
        return cls(x0=tuple(map(float, x0)), sigma=(0.0, 0.0, 0.0))

    def simulate(self, spec: PlantSpec, t: np.ndarray, dir_log: np.ndarray, *, closed_loop: bool,
                 angle: np.ndarray | None = None) -> SimResult:
        """``simulate`` from this start at the instants ``t`` (replay, or closed loop after the log's start),
        on the sketch's own loop instants: a row lost over serial is simulated too, its command held
        (``held_through_gaps``) or decided by the sketch's rule (``with_lost_samples``) -- on the
        measured ``angle`` when given (``decided_in_gaps``) -- and left out of the result."""
        t = np.asarray(t, dtype=float)
        dir0 = first_dir(np.concatenate([np.asarray(self.commands, dtype=np.int8), np.asarray(dir_log, dtype=np.int8)]))
        t_loop, d_loop, kept = with_lost_samples(t, np.asarray(dir_log, dtype=np.int8))
        d_loop = held_through_gaps(d_loop)
        if angle is not None:
            d_loop = decided_in_gaps(t_loop, d_loop, kept, t, np.asarray(angle, dtype=float), float(spec.guard_rad))
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


def held_through_gaps(d_loop: np.ndarray) -> np.ndarray:
    """The commands at lost rows that the log itself decides: where the commands logged on both
    sides of a gap agree, the sketch held that command through it (a reversal and back needs both
    guards, which one lost row cannot span).  Only a gap at a reversal is left to the model's
    controller, whose guard is in the model's frame: after a board reset the sketch's counter is
    not, so a model deciding every lost row would reverse at the wrong angles."""
    unknown = np.flatnonzero(d_loop == loop.UNKNOWN)
    if len(unknown) == 0:
        return d_loop
    known = np.flatnonzero(d_loop != loop.UNKNOWN)
    out = d_loop.copy()
    at = np.searchsorted(known, unknown)
    inside = (at > 0) & (at < len(known))
    before = d_loop[known[np.clip(at - 1, 0, len(known) - 1)]]
    after = d_loop[known[np.clip(at, 0, len(known) - 1)]]
    agreed = inside & (before == after)
    out[unknown[agreed]] = before[agreed]
    return out


def decided_in_gaps(t_loop: np.ndarray, d_loop: np.ndarray, kept: np.ndarray, t: np.ndarray,
                    angle: np.ndarray, guard_rad: float) -> np.ndarray:
    """The commands at lost rows across a reversal, by the sketch's rule on the measured angle
    interpolated there (a cubic through the two logged samples either side): the angle is the
    sketch's own count, in its frame, where a model's angle is in the springs' frame -- after a
    board reset these differ by the counter's unknown zero."""
    out = d_loop.copy()
    for i in np.flatnonzero(np.diff(kept) > 1):
        before, after = int(d_loop[kept[i]]), int(d_loop[kept[i + 1]])
        if before == after or before == 0 or after == 0 or out[kept[i] + 1] != loop.UNKNOWN:
            continue
        near = np.arange(max(i - 1, 0), min(i + 3, len(t)))
        fit = np.polyfit(t[near] - t[i], angle[near], min(3, len(near) - 1))
        d = before
        for j in range(kept[i] + 1, kept[i + 1]):
            d = next_dir(d, float(np.polyval(fit, t_loop[j] - t[i])), guard_rad)
            out[j] = d
    return out


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
