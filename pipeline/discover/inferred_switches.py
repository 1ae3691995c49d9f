"""A recording without a logged command: its command is inferred from the guards (the derive stage), and
a switch whose measured angle lies on a guard (within half a count) may have come a sample later.  These
switches are a nuisance of discovery: settled under a model (``settled``), again under the effects found
(``search.select``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.discover.measurement import Measurement
from pipeline.discover.residuals import noise_floor, residuals
from pipeline.model.effects import Effect


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


def settle_switches(meas: Measurement, nll) -> Measurement:
    """Decide each ambiguous inferred switch (``ambiguous_switches``) by which timing the rig's
    model replays better (``nll(measurement) -> float``), one at a time in time order."""
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
    return meas


def settled(meas: Measurement, effects: tuple[Effect, ...]) -> Measurement:
    """The ambiguous inferred switches settled under ``effects``, each timing judged by the pattern it
    leaves in each signal about its own mean: a level the model misses (a sensor's offset, where a
    constant torque rests the springs) moves both timings alike, and judged with it the timing went
    whichever way the missing level leaned."""
    spec = meas.spec(effects)
    floor = noise_floor(meas)

    def nll(m: Measurement) -> float:
        res = residuals(m, m.replay(spec))
        total = sum(0.5 * len(r) * np.log(np.var(r) + 1e-3 * floor[s]) for s, r in res.items())
        return float(total) if np.isfinite(total) else np.inf      # a replay that failed is never chosen

    return settle_switches(meas, nll)
