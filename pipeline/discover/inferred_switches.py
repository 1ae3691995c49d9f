"""Switches whose sample the data leave open, a nuisance of discovery: settled under a model (``settled``),
again under the effects found (``search.select``).

- A recording without a logged command: its command is inferred from the guards (the derive stage), and
  a switch whose measured angle lies on a guard (within half a count) may have come a sample later.
- A reversal in a gap of rows lost over serial: the sketch's rule on the angle interpolated at the lost
  instant decides it (``simulate.lost_samples_filled``), and where that angle lies on a guard (within
  half a count) it may be a sample off.
- The motor's start in a gap of lost rows: at a lost instant or at the next logged sample."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.discover.measurement import Measurement
from pipeline.discover.residuals import noise_floor, residuals
from pipeline.model.effects import Effect
from pipeline.model.simulate import lost_reversals_on_guard, lost_starts


def ambiguous_switches(meas: Measurement) -> list[int]:
    """Samples where an inferred command may be off by one sample: the measured angle is within
    half an encoder count of a guard, so the controller (which saw the unrounded angle, or a
    count rounded the other way) may have decided one sample later or earlier."""
    if meas.dir_source != "inferred":
        return []
    half = np.pi / meas.config.encoder.counts_per_rev
    g = meas.config.controller.guard_rad
    near = (np.abs(meas.theta - g) <= half) | (np.abs(meas.theta + g) <= half)
    return [int(k) for k in np.flatnonzero(near) if 0 < k < meas.n - 1 and meas.dir[k] != 0]


def ambiguous_lost_reversals(meas: Measurement) -> list[int]:
    """Logged samples after which a reversal in a gap of lost rows has its interpolated angle within half an
    encoder count of a guard (``simulate.lost_reversals_on_guard``), or the motor started in a gap of lost
    rows (``simulate.lost_starts``: no rule decides that instant)."""
    if meas.dir_source != "logged":
        return []
    return sorted(lost_reversals_on_guard(meas.t, meas.dir, meas.theta, float(meas.config.controller.guard_rad),
                                          np.pi / meas.config.encoder.counts_per_rev) + lost_starts(meas.t, meas.dir))


def ambiguous(meas: Measurement) -> bool:
    return bool(ambiguous_switches(meas) or ambiguous_lost_reversals(meas))


def timing(meas: Measurement) -> bytes:
    """The switches' timing a measurement replays (a key: the commands and the lost rows' reversals)."""
    return meas.dir.tobytes() + np.asarray(meas.lost_shifts, dtype=np.int64).tobytes()


def settle_switches(meas: Measurement, nll) -> Measurement:
    """Decide each ambiguous inferred switch (``ambiguous_switches``), then each ambiguous reversal on a lost
    row (``ambiguous_lost_reversals``), by which timing the rig's model replays better
    (``nll(measurement) -> float``), one at a time in time order."""
    for k in ambiguous_switches(meas):
        d = meas.dir
        options = []
        if d[k] != d[k - 1] and d[k - 1] != 0:          # switched at k: perhaps only at k + 1
            alt = d.copy()
            alt[k] = d[k - 1]
            options.append(alt)
        elif d[k + 1] != d[k] and d[k] != 0:            # switched at k + 1 (settled so before): perhaps at k
            alt = d.copy()
            alt[k] = d[k + 1]
            options.append(alt)
        elif d[k + 1] == d[k]:                          # did not switch at k: perhaps it did
            alt = d.copy()
            g_sign = 1 if meas.theta[k] > 0 else -1
            nxt = np.flatnonzero(d[k + 1:] != d[k])
            end = k + 1 + (int(nxt[0]) if len(nxt) else meas.n - k - 1)
            if d[k] == g_sign:                          # moving towards this guard: reverse from k on
                alt[k:end] = -d[k]
                options.append(alt)
        best, best_nll = meas, nll(meas)
        for alt in options:
            trial = replace(meas, dir=alt)
            value = nll(trial)
            if value < best_nll:
                best, best_nll = trial, value
        meas = best
    current = nll(meas)
    for i in ambiguous_lost_reversals(meas):
        trial = replace(meas, lost_shifts=tuple(sorted(set(meas.lost_shifts) ^ {i})))
        if (value := nll(trial)) < current:
            meas, current = trial, value
    return meas


def settled(meas: Measurement, effects: tuple[Effect, ...]) -> Measurement:
    """The ambiguous switches (inferred, and reversals on lost rows) settled under ``effects``, each timing
    judged by the pattern it leaves in each signal about its own mean: a level the model misses (a sensor's
    offset, where a constant torque rests the springs) moves both timings alike, and judged with it the
    timing went whichever way the missing level leaned."""
    spec = meas.spec(effects)
    floor = noise_floor(meas)

    def nll(m: Measurement) -> float:
        res = residuals(m, m.replay(spec))
        total = sum(0.5 * len(r) * np.log(np.var(r) + 1e-3 * floor[s]) for s, r in res.items())
        return float(total) if np.isfinite(total) else np.inf      # a replay that failed is never chosen

    return settle_switches(meas, nll)
