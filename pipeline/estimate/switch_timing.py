"""Switches whose sample the data leave open: a nuisance of the recording, settled by the replay each
timing gives, the same way for validation and discovery.

- A command inferred from the guards (no logged ``dir``): a switch whose measured angle lies on a guard
  (within half a count) may have come a sample later, or earlier.
- A reversal in a gap of rows lost over serial: the sketch's rule on the angle interpolated at the lost
  instants decides it (``simulate.lost_samples_filled``); where that angle lies on a guard within the
  error half a count in each logged angle carries into the interpolation, the rule may be a sample off.
- The motor's start in a gap of lost rows: at the last lost instant or at the next logged sample; no rule
  on the angle decides it (a timer's or a button's).

A timing is a value: the commands replayed and the gaps whose reversal or start is moved a sample from
the rule's (``shifted``, as ``Start.simulate`` takes it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from pipeline.model.simulate import lost_reversals_on_guard, lost_starts


@dataclass(frozen=True, eq=False)
class Timing:
    dir: np.ndarray                 # the command in force over each logged sample
    shifted: tuple[int, ...] = ()   # logged samples after whose gap the reversal or start is a sample moved

    def key(self) -> bytes:
        return np.asarray(self.dir, dtype=np.int8).tobytes() + np.asarray(self.shifted, dtype=np.int64).tobytes()

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Timing) and self.key() == other.key()

    def __hash__(self) -> int:
        return hash(self.key())


def inferred_on_guard(dir_inferred: np.ndarray, theta: np.ndarray, guard: float, half_count: float) -> list[int]:
    """Samples where a command inferred from the guards may be off by one sample: the measured angle is
    within half an encoder count of a guard, so the controller (which saw the unrounded angle, or a count
    rounded the other way) may have decided a sample later or earlier."""
    d = np.asarray(dir_inferred)
    near = (np.abs(theta - guard) <= half_count) | (np.abs(theta + guard) <= half_count)
    return [int(k) for k in np.flatnonzero(near) if 0 < k < len(d) - 1 and d[k] != 0]


def lost_on_guard(t: np.ndarray, dir_logged: np.ndarray, theta: np.ndarray, guard: float,
                  half_count: float) -> list[int]:
    """Logged samples after which a reversal in a gap of lost rows has its interpolated angle within the
    error half a count in each logged angle carries into it of a guard, or the motor started in a gap of
    lost rows."""
    return sorted(lost_reversals_on_guard(t, dir_logged, theta, guard, half_count) + lost_starts(t, dir_logged))


def _alternative(d: np.ndarray, theta: np.ndarray, k: int) -> np.ndarray | None:
    """The inferred command with the switch at ``k`` (or the one due there) moved a sample, or None."""
    alt = d.copy()
    if d[k] != d[k - 1] and d[k - 1] != 0:          # switched at k: perhaps only at k + 1
        alt[k] = d[k - 1]
    elif d[k + 1] != d[k] and d[k] != 0:            # switched at k + 1 (settled so before): perhaps at k
        alt[k] = d[k + 1]
    elif d[k + 1] == d[k] and d[k] == (1 if theta[k] > 0 else -1):
        nxt = np.flatnonzero(d[k + 1:] != d[k])     # did not switch at k, moving towards this guard: perhaps it did
        end = k + 1 + (int(nxt[0]) if len(nxt) else len(d) - k - 1)
        alt[k:end] = -d[k]
    else:
        return None
    return alt


def settle(timing: Timing, *, t: np.ndarray, theta: np.ndarray, guard: float, half_count: float, inferred: bool,
           misfit: Callable[[Timing], float]) -> Timing:
    """Each open switch decided by which timing the model replays better (``misfit``, lower is better), one
    at a time in time order (the inferred switches on a guard, then the lost rows' reversals and starts),
    pass after pass until none moves: one switch a sample off leaves a slow transient that can outweigh
    what moving an earlier one gains, so that one is judged again once the later ones are settled."""
    current = None
    while True:
        before = timing
        for k in inferred_on_guard(timing.dir, theta, guard, half_count) if inferred else ():
            alt = _alternative(timing.dir, theta, k)
            if alt is None:
                continue
            current = misfit(timing) if current is None else current
            trial = Timing(alt, timing.shifted)
            if (value := misfit(trial)) < current:
                timing, current = trial, value
        for i in () if inferred else lost_on_guard(t, timing.dir, theta, guard, half_count):
            current = misfit(timing) if current is None else current
            trial = Timing(timing.dir, tuple(sorted(set(timing.shifted) ^ {i})))
            if (value := misfit(trial)) < current:
                timing, current = trial, value
        if timing == before:
            return timing


def pattern_misfit(res: dict[str, np.ndarray], floor: dict[str, float]) -> float:
    """-log L of residuals with each signal's variance about its own mean concentrated out: a timing is
    judged by the pattern it leaves, so a level the model misses (a sensor's offset, where a constant torque
    rests the springs), which moves both timings alike, does not decide it.  A failed replay is never chosen."""
    total = sum(0.5 * len(r) * np.log(np.var(r) + 1e-3 * floor[s]) for s, r in res.items())
    return float(total) if np.isfinite(total) else np.inf
