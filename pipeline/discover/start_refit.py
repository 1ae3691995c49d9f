"""The final model's start, refined on the whole recording.

The start is estimated from the first seconds (``validate.initial_state``): enough to rank
candidates, but a slow mode (the armature's La/Ra of seconds, a backlash or a stick near the
start) can leave a transient there that outlasts the window and reads as structure the model
lacks.  Before the verdict, the final model's initial state is refined by a few Gauss-Newton
steps on every sample (each signal weighted by its misfit, as the concentrated likelihood
does) and kept only when the likelihood improves; validation's x0 stays the window estimate.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.discover.candidates import Evaluator
from pipeline.discover.residuals import residuals
from pipeline.model.effects import Effect
from pipeline.validate.initial_state import STATE_SCALES
from pipeline.validate.start import Start

STEPS = 3
RELATIVE_STEP = 1e-3          # of each state's typical size (``STATE_SCALES``), for the Jacobian


def refine_start(ev: Evaluator, effects: tuple[Effect, ...]) -> Start | None:
    """A start that replays the whole recording better under ``effects``, or None."""
    meas = ev.meas
    spec = replace(meas.spec(effects), I0=0.0)
    full = meas.spec(effects)
    command = ev.command_for(effects)
    start = meas.x0(full)                  # the start the Evaluator replays from (keyed on the logged command)
    z0 = np.array(start.x0 if start.z is None else start.z, dtype=float)

    def at(z: np.ndarray) -> Start:
        return replace(start, z=tuple(float(v) for v in z), x0=tuple(float(v) for v in z) if not start.lead_s
                       else start.x0)

    def stacked(z: np.ndarray, weights: dict[str, float] | None = None) -> tuple[np.ndarray, dict[str, float]]:
        sim = at(z).simulate(spec, meas.t_fit, command, closed_loop=False, angle=meas.guard_angle)
        sim = replace(sim, current_measured=sim.current + full.I0)
        res = residuals(meas, sim)
        w = weights or {s: 1.0 / np.sqrt(float(np.mean(r * r)) + 1e-3 * ev.floor[s]) for s, r in res.items()}
        return np.concatenate([w[s] * r for s, r in res.items()]), w

    try:
        r, w = stacked(z0)
        z = z0
        for _ in range(STEPS):
            cols = []
            for i in range(3):
                h = np.zeros(3)
                h[i] = RELATIVE_STEP * STATE_SCALES[i]
                cols.append((stacked(z + h, w)[0] - r) / h[i])
            J = np.column_stack(cols)
            step = -np.linalg.lstsq(J, r, rcond=None)[0]
            trial, _ = stacked(z + step, w)
            if not np.all(np.isfinite(trial)) or trial @ trial >= r @ r:
                break
            z, r = z + step, trial
    except (RuntimeError, FloatingPointError, ValueError, np.linalg.LinAlgError):
        return None
    if np.array_equal(z, z0):
        return None
    refined = at(z)
    before = ev.nll(ev.sim(effects))
    meas.pin_start(full, meas.dir, refined)
    if ev.nll(ev.sim(effects)) < before:
        return refined
    meas.pin_start(full, meas.dir, start)
    return None
