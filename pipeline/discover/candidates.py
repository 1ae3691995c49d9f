"""Fit each catalogued effect for its parameter, within bounds, with an interval.

The fit is on *replay* (the logged command drives the model), which is smooth
in the parameters; the closed-loop free run is only used to confirm.  The
objective is the Gaussian likelihood with an unknown variance per signal,
concentrated: nll = sum_s n_s/2 * log(mean(r_s^2)).  It needs no weights
between rad and A, and the search's held-out evidence is counted in it.

A candidate is scanned and fitted on its first parameter (``Param.scan``, the
effect's own coarse grid over its physical range), then Brent's method between
the best scan point's neighbours; every parameter of every effect found so far
is refitted jointly (``joint_fit``: the estimation core's ``estimate.fit``).  Effects
found in earlier rounds are not frozen: the scan predicts how they would move
(one Gauss-Newton step), and the candidate is refitted together with them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize_scalar

from pipeline.discover.joint import (Sensitivity, effect_intervals, gauss_newton, joint_fit, moved_effects,
                                     sensitivity, values_of)
from pipeline.discover.measurement import Measurement
from pipeline.discover.residuals import residuals
from pipeline.errors import PdrError
from pipeline.estimate.start import Start
from pipeline.model.effects import CATALOGUE, Effect, Param, PlantSpec
from pipeline.model.simulate import SimResult

def _first(name: str) -> Param:
    """The parameter discovery scans: the effect's first (its others are refitted jointly)."""
    return CATALOGUE[name].PARAMS[0]


def _scan(name: str) -> np.ndarray:
    """Coarse scan points inside the effect's bounds (its "absent" value included)."""
    return np.asarray(_first(name).scan, dtype=float)


def parameter_of(name: str) -> str:
    return _first(name).name


def make(name: str, value: float) -> Effect:
    """The effect at ``value`` (no range check: the scan stays inside the bounds)."""
    return CATALOGUE[name].at(value)


class Evaluator:
    """Replays a measurement under many models, caching by plant with I0 applied afterwards (a sensor
    offset changes nothing but the measured current), and the start estimated once per model."""

    def __init__(self, meas: Measurement, floor: dict[str, float], spent: int = 0) -> None:
        self.meas = meas
        self.spent = spent                   # the work of the searches on the recording before this one
        self.floor = floor
        self._cache: dict[tuple[PlantSpec, tuple], SimResult] = {}
        self.simulations = 0
        self._replayed = 0                   # the replays' work (``replay_cost``)
        self._start_runs = meas.start_runs   # the start estimates' simulations before this evaluator
        self.failures: list[str] = []
        self.commands: dict[PlantSpec, np.ndarray] = {}
        self._onset_shift: int | None = None   # the shift the last model's onset search ended on

    def sim(self, effects: tuple[Effect, ...], start: Start | None = None) -> SimResult:
        """The replay of the base plus ``effects`` from ``start``, by default the start estimated for it."""
        spec = self.meas.spec(effects)
        try:
            x0 = self.meas.x0(spec) if start is None else start     # estimated per model (the measurement caches it)
        except _SIMULATION_ERRORS as err:
            # a plant whose start the estimator cannot simulate (a chattering contact) is as bad as its replay
            key = (replace(spec, I0=0.0), "no start")
            if key not in self._cache:
                self.failures.append(f"{key[0]}: start: {err}")
                self._cache[key] = _failed(self.meas.t)
            return self._cache[key]
        key = (replace(spec, I0=0.0), x0)
        if key not in self._cache:
            self.simulations += 1
            self.count_replay(spec)
            try:
                self._cache[key] = self.meas.replay(key[0], x0, self.command(key[0], x0))
            except _SIMULATION_ERRORS as err:
                # a parameter value the simulator cannot run counts as infinitely bad, not as a crash
                self.failures.append(f"{key}: {err}")
                self._cache[key] = _failed(self.meas.t)
        base = self._cache[key]
        if spec.I0 == 0.0:
            return base
        return replace(base, current_measured=base.current + spec.I0)

    def count_replay(self, spec: PlantSpec) -> None:
        """A whole replay of ``spec`` (``replay_cost``), counted in this evaluator's work."""
        self._replayed += replay_cost(spec, self.meas.n)

    @property
    def work(self) -> int:
        """What the search has cost, in simulated samples: the searches before this evaluator, its replays,
        and the start estimates of the models it replayed (``START_RUN_COST`` per simulation of theirs)."""
        return self.spent + self._replayed + START_RUN_COST * (self.meas.start_runs - self._start_runs)

    def use_command(self, spec: PlantSpec, command: np.ndarray | None) -> None:
        """Replay ``spec`` (without sensor offset) under ``command`` from now on (None: the chosen one)."""
        if command is None:
            self.commands.pop(spec, None)
        else:
            self.commands[spec] = command
        self._cache = {k: v for k, v in self._cache.items() if k[0] != spec}

    def command(self, spec: PlantSpec, x0: tuple[float, float, float]) -> np.ndarray:
        """The command sequence to replay: the logged one, or -- when the motor's start is only
        inferred -- the start (within ``ONSET_SHIFTS`` samples) that fits this model best over
        the first phase: every shift for the first model, then a downhill search from the last
        model's (each shift costs a start estimate, Gauss-Newton for a Coulomb or backlash plant).
        Remembered per plant, so the final report uses the same one; ``use_command`` replaces it."""
        k0 = self.meas.onset
        if k0 is None:
            return self.commands.get(spec, self.meas.dir)     # one chosen on the whole run (start_refit)
        if spec not in self.commands:
            m = min(k0 + ONSET_WINDOW, self.meas.n)
            tried: dict[int, float] = {}

            def nll_at(shift: int) -> float:
                if shift not in tried:
                    tried[shift] = self._onset_nll(spec, x0, self.meas.with_onset(k0 + shift), m)
                return tried[shift]

            if self._onset_shift is None:            # the first model: every shift
                best = min(ONSET_SHIFTS, key=nll_at)
            else:
                # the next models differ a little: from where the last one's onset was, downhill
                best = self._onset_shift
                for step in (-1, 1):
                    while best + step in ONSET_SHIFTS and nll_at(best + step) < nll_at(best):
                        best += step
            self._onset_shift = best
            self.commands[spec] = self.meas.with_onset(k0 + best) if np.isfinite(nll_at(best)) else self.meas.dir
        return self.commands[spec]

    def _onset_nll(self, spec: PlantSpec, x0, d: np.ndarray, m: int) -> float:
        """The first phase's likelihood (``m`` samples) with the motor started as ``d`` says."""
        try:
            sim = self.meas.replay(spec, x0, d, n=m)
        except _SIMULATION_ERRORS:
            return float("inf")
        self.simulations += 1
        self._replayed += replay_cost(spec, m) - REPLAY_OVERHEAD     # the first phase only, start estimated
        return _nll_of(self, {s: r[:m] - v for (s, r), v in
                              zip(self.meas.signals.items(), _model_signals(sim, self.meas))})

    def command_for(self, effects: tuple[Effect, ...]) -> np.ndarray:
        spec = self.meas.spec(effects)
        x0 = self.meas.x0(spec)
        return self.command(replace(spec, I0=0.0), x0)

    def nll(self, sim: SimResult, mask: np.ndarray | None = None, taus: dict[str, float] | None = None) -> float:
        """Concentrated Gaussian negative log-likelihood over the fitted signals (on ``mask``); with ``taus``,
        each signal's in independent samples (over its residual's autocorrelation time)."""
        res = residuals(self.meas, sim)
        return _nll_of(self, res if mask is None else {s: r[mask] for s, r in res.items()}, taus)

    def mse(self, sim: SimResult, mask: np.ndarray | None = None) -> dict[str, float]:
        return {s: float(np.mean((r if mask is None else r[mask]) ** 2))
                for s, r in residuals(self.meas, sim).items()}


def _model_signals(sim: SimResult, meas: Measurement) -> list[np.ndarray]:
    """The simulated counterparts of ``meas.signals``, in the same order."""
    return [sim.theta if s == "theta" else sim.current_measured for s in meas.signals]


# A motor start inferred from the first motion can be late by a loop delay or by the time a
# sticking pinion needs to break away (up to ~0.3 s for large Coulomb torques), or early by
# a sample; the first phase (up to ONSET_WINDOW samples) decides.
ONSET_SHIFTS = tuple(range(-8, 3))
ONSET_WINDOW = 30

# Discovery's budget is in work: what its simulations cost, counted, not timed, so the same on every machine
# and under any load.  The unit is one sample of a linear plant's replay (~0.6 us of CPU).  Fitted to the
# CPU of discovery on 66 randomised recordings (median error 6 %): a sample of an event-driven plant
# (Coulomb friction, backlash: stick/slip and contact events located) costs 4/3 of it; a replay besides
# its samples (set-up, residuals, likelihood) 200; one simulation of a start estimate (a few dozen
# samples and its share of a Gauss-Newton step; ~20 of them per start of an event-driven plant) 260.
EVENT_SAMPLE_COST = 4 / 3
REPLAY_OVERHEAD = 200
START_RUN_COST = 260

# what a model the simulator cannot run scores: finite (Brent's method does arithmetic on it), huge
FAILED_NLL = 1e12


def replay_cost(spec: PlantSpec, n: int) -> int:
    """The work of replaying ``n`` samples of ``spec`` (see ``EVENT_SAMPLE_COST``)."""
    return round(n * (1.0 if spec.is_linear else EVENT_SAMPLE_COST)) + REPLAY_OVERHEAD


# what a simulation of a plant the simulator cannot run raises (a chattering contact, an unstable start fit)
_SIMULATION_ERRORS = (RuntimeError, FloatingPointError, ValueError, PdrError, np.linalg.LinAlgError)


def _failed(t: np.ndarray) -> SimResult:
    nan = np.full(len(t), np.nan)
    return SimResult(t=t, theta=nan, omega=nan, current=nan, current_measured=nan, delta=nan,
                     dir=np.zeros(len(t), dtype=np.int8), u=nan)


@dataclass
class Fit:
    """One candidate effect fitted on top of the current model (whose parameters may have moved)."""

    name: str
    parameter: str
    value: float
    nll: float                        # on all samples
    interval: tuple[float, float]     # ~95 %, Jacobian with an autocorrelation correction, widened by fold spread
    fold_values: tuple[float, ...]    # the estimate from each held-out fold's training half
    base: tuple[Effect, ...] = ()     # the effects found earlier, refitted together with this one
    heldout_mse_before: dict[str, float] = field(default_factory=dict)
    heldout_mse_after: dict[str, float] = field(default_factory=dict)
    heldout_nll_gain: float = 0.0     # nll decrease on held-out samples (> 0: better)
    fitted: Effect | None = None      # the candidate with every parameter as fitted (``value`` is its first)

    @property
    def effect(self) -> Effect:
        return self.fitted if self.fitted is not None else make(self.name, self.value)

    @property
    def effects(self) -> tuple[Effect, ...]:
        """The whole augmented model: earlier effects (refitted) plus this one."""
        return (*self.base, self.effect)


def value_of(e: Effect) -> float:
    return e.value


def _nll_of(ev: Evaluator, r: dict[str, np.ndarray], taus: dict[str, float] | None = None) -> float:
    """sum_s n_s/2 log(mean(r_s^2)) (over tau_s with ``taus``); a thousandth of the noise floor keeps the log
    finite on noiseless data."""
    total = sum(0.5 * len(x) * np.log(np.mean(x * x) + 1e-3 * ev.floor[s]) / (taus[s] if taus else 1.0)
                for s, x in r.items())
    return float(total) if np.isfinite(total) else FAILED_NLL


# ------------------------------------------------------------------ scan and fit

@dataclass
class Scan:
    """The coarse scan of one candidate: per point the nll with the earlier effects relaxed."""

    grid: np.ndarray
    nll: np.ndarray
    bases: list[tuple[Effect, ...]]      # the earlier effects, moved to accommodate each point


def scan(ev: Evaluator, base: tuple[Effect, ...], name: str, base_sens: Sensitivity | None = None) -> Scan:
    """nll over the scan points.  With earlier effects, each point's nll is also predicted
    with their parameters moved by one Gauss-Newton step (sensitivities taken once, at the
    current model; no extra simulation), so a candidate is not judged against an earlier
    estimate that had absorbed part of it.  The full fit checks the prediction.

    A point is first replayed from the model's own start where it changes neither the plant's
    inputs (the commands in flight at the first sample, the voltage they apply) nor where it rests
    (a constant torque), which pin the start: a start estimate per point cost as much as the rest of
    the search.  Around the best point (its neighbours bracket the fit) every point is then replayed
    from its own start, until the best point's neighbours are all so replayed."""
    grid = _scan(name)
    start_spec = ev.meas.spec(base)

    def point(v: float, own: bool) -> tuple[float, tuple[Effect, ...], bool]:
        effects = (*base, make(name, v))
        spec = ev.meas.spec(effects)
        shared = not own and (spec.Td, spec.v_drive, spec.torque) == (start_spec.Td, start_spec.v_drive,
                                                                       start_spec.torque)
        r = residuals(ev.meas, ev.sim(effects, ev.meas.x0(replace(start_spec, I0=spec.I0)) if shared else None))
        loss, moved = _nll_of(ev, r), base
        if base and base_sens is not None and loss < FAILED_NLL:
            step, _ = gauss_newton(r, base_sens.jac)
            trial = moved_effects(base, step)
            applied = values_of(trial) - values_of(base)
            predicted = {s: x + sum(j[s] * a for j, a in zip(base_sens.jac, applied)) for s, x in r.items()}
            loss_p = _nll_of(ev, predicted)
            if loss_p < loss:
                loss, moved = loss_p, trial
        return loss, moved, shared

    points = [point(v, own=False) for v in grid]
    while True:
        i = int(np.argmin([p[0] for p in points]))
        near = [k for k in range(max(i - 1, 0), min(i + 2, len(grid))) if points[k][2]]
        if not near:
            break
        for k in near:
            points[k] = point(grid[k], own=True)
    return Scan(grid=grid, nll=np.array([p[0] for p in points]), bases=[p[1] for p in points])


def fit_value(ev: Evaluator, base: tuple[Effect, ...], name: str, bracket: tuple[float, float],
              mask: np.ndarray | None = None) -> tuple[float, float]:
    """Best value of ``name``'s parameter in ``bracket`` on top of ``base`` (Brent), and its nll."""
    def loss(v: float) -> float:
        return ev.nll(ev.sim((*base, make(name, v))), mask)

    lo, hi = bracket
    scale = max(abs(lo), abs(hi), 1e-12)
    res = minimize_scalar(loss, bounds=(lo, hi), method="bounded", options={"xatol": 5e-4 * scale, "maxiter": 25})
    return float(res.x), float(res.fun)


def fit_candidate(ev: Evaluator, base: tuple[Effect, ...], name: str,
                  folds: tuple[np.ndarray, np.ndarray], scanned: Scan | None = None) -> Fit:
    """Fit ``name`` (and re-fit the earlier effects with it) on all samples; estimate on each
    fold's training half by one joint Gauss-Newton step and score on the other half."""
    sc = scanned if scanned is not None else scan(ev, base, name)
    i = int(np.argmin(sc.nll))
    moved = sc.bases[i]
    lo, hi = sc.grid[max(i - 1, 0)], sc.grid[min(i + 1, len(sc.grid) - 1)]
    value, nll_all = fit_value(ev, moved, name, (lo, hi))
    at_grid = ev.nll(ev.sim((*moved, make(name, sc.grid[i]))))
    if nll_all > at_grid:
        value, nll_all = float(sc.grid[i]), at_grid
    effects = (*moved, make(name, value))
    if base or len(CATALOGUE[name].PARAMS) > 1:
        effects = joint_fit(ev, effects)                # every parameter of the candidate too, not only its first
        moved, value = effects[:-1], value_of(effects[-1])
        nll_all = ev.nll(ev.sim(effects))
    sens = sensitivity(ev, effects)
    base_sim = ev.sim(base)
    fold_values = []
    gain = 0.0
    mse_b: dict[str, float] = {}
    mse_a: dict[str, float] = {}
    for train in folds:
        test = ~train
        trial = fold_fit(ev, effects, sens, train)
        sim_f = ev.sim(trial)
        fold_values.append(value_of(trial[-1]))
        gain += ev.nll(base_sim, test) - ev.nll(sim_f, test)
        share = test.sum() / len(test)
        for s, m in ev.mse(base_sim, test).items():
            mse_b[s] = mse_b.get(s, 0.0) + m * share
        for s, m in ev.mse(sim_f, test).items():
            mse_a[s] = mse_a.get(s, 0.0) + m * share
    lo, hi = effect_intervals(sens, effects)[-1]
    spread = (max(fold_values) - min(fold_values)) / 2.0
    lo, hi = min(lo, value - spread), max(hi, value + spread)
    return Fit(name=name, parameter=parameter_of(name), value=value, nll=nll_all, interval=(lo, hi),
               fold_values=tuple(fold_values), base=tuple(moved), heldout_mse_before=mse_b,
               heldout_mse_after=mse_a, heldout_nll_gain=gain, fitted=effects[-1])


# a fold's step is halved at most this often before the fit on all samples is kept (a cost bound)
FOLD_STEP_HALVINGS = 2


def fold_fit(ev: Evaluator, effects: tuple[Effect, ...], sens: Sensitivity, train: np.ndarray) -> tuple[Effect, ...]:
    """``effects`` refitted on the ``train`` samples by one joint Gauss-Newton step from their fit on all
    samples (each parameter's move within a trust region), halved while it does not lower the training
    samples' own nll: a fit on half the data ends no worse on that half than where it began (a step
    linearised across a non-smooth effect, a backlash's gap, can land on a worse trajectory)."""
    step, _ = gauss_newton(sens.r0, sens.jac, train)
    start = _nll_of(ev, {s: r[train] for s, r in sens.r0.items()})
    for halving in range(FOLD_STEP_HALVINGS + 1):
        trial = moved_effects(effects, step / 2 ** halving)
        if ev.nll(ev.sim(trial), train) < start:
            return trial
    return effects


def folds_by_cycle(meas: Measurement) -> tuple[np.ndarray, np.ndarray]:
    """Two training masks: alternate full cycles (q1 + q2 phase pairs), so each half holds both
    directions; with fewer than four phases, alternate quarters of the recording."""
    d = meas.dir
    change = np.concatenate([[0], (d[1:] != d[:-1]) & (d[1:] != 0) & (d[:-1] != 0)]).astype(int)
    phase = np.cumsum(change)
    if phase[-1] >= 3:
        a = (phase // 2) % 2 == 0
    else:
        a = (np.arange(meas.n) * 4 // meas.n) % 2 == 0
    return a, ~a
