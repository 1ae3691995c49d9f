"""The final model's start, refined on the whole recording (and, after a board reset, the counter's offset
under the model the rounds found: ``hold_offset_of``).

The start is estimated from the first seconds (``estimate.initial_state``): enough to rank
candidates, but a slow mode (the armature's La/Ra of seconds, a backlash or a stick near the
start) can leave a transient there that outlasts the window and reads as structure the model
lacks.  Before the verdict, the final model's initial state is refined by a few Gauss-Newton
steps on every sample (each signal weighted by its misfit, as the concentrated likelihood
does) and kept only when the likelihood improves; validation's x0 stays the window estimate.

When the motor's start is only inferred (no logged command), the onset the rounds chose on the
first phase is chosen again on the whole recording first: the start, estimated over the first
seconds, absorbs a sample's error in the onset there, but the plant's slow electrical mode
carries it through the rest of the run (one 10 ms sample late read as 46 noise variances of
angle structure on a clean segment after a board reset).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.discover.candidates import ONSET_SHIFTS, Evaluator
from pipeline.discover.joint import Sensitivity, sensitivity
from pipeline.discover.residuals import residuals
from pipeline.errors import PdrError
from pipeline.model.effects import Effect
from pipeline.estimate.initial_state import STATE_SCALES
from pipeline.estimate.start import Start

STEPS = 3
RELATIVE_STEP = 1e-3          # of each state's typical size (``STATE_SCALES``), for the Jacobian


def _replayed_nll(ev: Evaluator, effects: tuple[Effect, ...], command: np.ndarray,
                  start: Start | None = None) -> float:
    """The likelihood of the whole recording replayed under ``command`` from ``start`` (default: the
    start estimated for it)."""
    meas = ev.meas
    full = meas.spec(effects)
    try:
        start = meas.x0(full, command) if start is None else start
        sim = meas.run(start, replace(full, I0=0.0), command)
    except (RuntimeError, FloatingPointError, ValueError, np.linalg.LinAlgError):
        return float("inf")
    ev.simulations += 1
    return ev.nll(replace(sim, current_measured=sim.current + full.I0))


def _command_on_the_whole_run(ev: Evaluator, effects: tuple[Effect, ...]) -> np.ndarray:
    """The command to replay under ``effects``: the logged one; or, with an inferred onset, the onset
    (``ONSET_SHIFTS``) that replays the whole recording best under ``effects``.  After a reset the
    counter's offset is fitted with each onset (either bends the other) and the best one's held."""
    meas = ev.meas
    full = meas.spec(effects)
    chosen = ev.command_for(effects)
    began = replace(meas, dir=chosen)          # its onset is the chosen one
    k0 = began.onset
    if k0 is None and meas.angle_reference_known:
        return chosen

    def trial(d: np.ndarray) -> tuple[float, float | None]:
        offset = meas.segment_offset(full, d)
        start = None if offset is None else meas.start_with_offset(full, d, offset)
        return _replayed_nll(ev, effects, d, start), offset

    best, (best_nll, best_offset) = chosen, trial(chosen)
    for shift in ONSET_SHIFTS if k0 is not None else ():
        d = began.with_onset(k0 + shift)
        if shift != 0 and (tried := trial(d))[0] < best_nll:
            best, (best_nll, best_offset) = d, tried
    if best_offset is not None:
        meas.hold_offset(full, best_offset)
    return best


def refine_start(ev: Evaluator, effects: tuple[Effect, ...]) -> Start | None:
    """A start (and, for an inferred onset, a command) that replays the whole recording better
    under ``effects``, or None; the Evaluator replays them from now on."""
    meas = ev.meas
    spec = replace(meas.spec(effects), I0=0.0)
    full = meas.spec(effects)
    before = ev.nll(ev.sim(effects))
    chosen = ev.commands.get(spec)
    held = meas.held_offset
    logged_start = meas.x0(full)           # the start the Evaluator keys its replays on
    command = _command_on_the_whole_run(ev, effects)
    if held is not None and meas.held_offset == held:
        held = None                        # the offset did not move
    start = meas.x0(full, command)
    z0 = np.array(start.x0 if start.z is None else start.z, dtype=float)

    at = start.with_z

    def stacked(z: np.ndarray, weights: dict[str, float] | None = None) -> tuple[np.ndarray, dict[str, float]]:
        sim = meas.run(at(z), spec, command)
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
        z = z0
    if np.array_equal(z, z0) and np.array_equal(command, ev.command_for(effects)) and held is None:
        return None
    refined = at(z)
    # the Evaluator replays from the start under the logged command, under ``command`` from its own start
    meas.pin_start(full, meas.dir, refined)
    meas.pin_start(full, command, refined)
    ev.use_command(spec, command)
    if ev.nll(ev.sim(effects)) < before:
        return refined
    if held is not None:
        meas.hold_offset(full, held)
    else:
        meas.pin_start(full, meas.dir, logged_start)
        meas.pin_start(full, command, start)
    ev.use_command(spec, chosen)
    return None


def held_start_sensitivity(ev: Evaluator, effects: tuple[Effect, ...]) -> Sensitivity:
    """The final model's sensitivity, for its intervals: each parameter moved with the start held where
    ``refine_start`` left it, and the start's three states as columns of their own (nuisances the
    intervals are marginal over).  Moving a parameter with its start estimated afresh from the first
    seconds (``joint.sensitivity``) compares two estimates of the start, the whole run's and the
    window's, a step of 1e-3 apart in the parameter: their difference read as a steep slope and an
    interval tens of times too narrow (draw 277: a backlash gap in [0.0562, 0.0564], the truth 0.044)."""
    meas = ev.meas
    command = ev.command_for(effects)
    start = meas.x0(meas.spec(effects), command)
    z0 = np.array(start.x0 if start.z is None else start.z, dtype=float)

    def replayed(effs: tuple[Effect, ...], z: np.ndarray = z0) -> dict[str, np.ndarray]:
        spec = meas.spec(effs)
        try:
            sim = meas.run(start.with_z(z), replace(spec, I0=0.0), command)
        except (RuntimeError, FloatingPointError, ValueError, PdrError):    # as the Evaluator scores it
            return {s: np.full(meas.n, np.nan) for s in meas.signals}
        return residuals(meas, replace(sim, current_measured=sim.current + spec.I0))

    sens = sensitivity(ev, effects, replayed)
    for i in range(3):
        h = RELATIVE_STEP * STATE_SCALES[i]
        r1 = replayed(effects, z0 + h * np.eye(3)[i])
        sens.jac.append({s: (r1[s] - sens.r0[s]) / h for s in sens.r0})
    return sens


def hold_offset_of(ev: Evaluator, effects: tuple[Effect, ...]) -> None:
    """After a board reset: the counter's offset (a nuisance held from the base model's fit through the
    rounds) estimated again under the model the rounds found, and held for every model compared from
    then on, so the elimination and the verdict judge each model at one offset its best one chose."""
    meas = ev.meas
    if meas.angle_reference_known or not effects:
        return
    offset = meas.segment_offset(meas.spec(effects), ev.command_for(effects))
    if offset is not None:
        meas.hold_offset(None, offset)
