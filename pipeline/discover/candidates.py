"""Fit each catalogued effect for its parameter, within bounds, with an interval.

The fit is on *replay* (the logged command drives the model), which is smooth
in the parameters; the closed-loop free run is only used to confirm.  The
objective is the Gaussian likelihood with an unknown variance per signal,
concentrated: nll = sum_s n_s/2 * log(mean(r_s^2)).  It needs no weights
between rad and A, and it is what BIC charges parameters against.

Every catalogue effect has one parameter, so a fit is a bounded 1-D search: a
coarse scan over the effect's physical range (geometric, since magnitudes span
decades), then Brent's method between the best scan point's neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize_scalar

from pipeline.discover.measurement import Measurement
from pipeline.errors import PdrError
from pipeline.discover.residuals import residuals
from pipeline.model.effects import CATALOGUE, Effect, PlantSpec
from pipeline.model.simulate import SimResult

# The value at which each effect is absent: the interval must exclude it.
NULL_VALUE: dict[str, float] = {
    "viscous_friction": 0.0, "coulomb_friction": 0.0, "driver_voltage_drop": 0.0, "backlash": 0.0,
    "loop_delay": 0.0, "current_sensor_offset": 0.0, "rack_inertia": 0.0, "spring_stiffness": 1.0,
}


def _scan(name: str) -> np.ndarray:
    """Coarse scan points inside the effect's BOUNDS (the null value included)."""
    lo, hi = next(iter(CATALOGUE[name].BOUNDS.values()))
    if name == "current_sensor_offset":        # costs no simulation (see Evaluator)
        return np.linspace(-0.6, 0.6, 121)
    if name == "spring_stiffness":
        return np.unique(np.concatenate([np.geomspace(0.25, 4.0, 17), [0.9, 0.95, 0.98, 1.0, 1.02, 1.05, 1.1]]))
    top = {"coulomb_friction": 5e-3, "driver_voltage_drop": 5.0, "loop_delay": 0.3, "backlash": 0.4}.get(name, hi)
    return np.concatenate([[lo], np.geomspace(top * 2e-3, top, 15)])


def parameter_of(name: str) -> str:
    return next(iter(CATALOGUE[name].UNITS))


def make(name: str, value: float) -> Effect:
    """The effect at ``value`` (no range check: the scan stays inside BOUNDS)."""
    return CATALOGUE[name](**{parameter_of(name): float(value)})


class Evaluator:
    """Replays a measurement under many models, caching by plant (I0 applied afterwards).

    A sensor offset changes nothing but the measured current, so the plant is
    simulated once and the offset added: scanning it costs no simulation.
    """

    def __init__(self, meas: Measurement, floor: dict[str, float]) -> None:
        self.meas = meas
        self.floor = floor
        self._cache: dict[PlantSpec, SimResult] = {}
        self.simulations = 0
        self.failures: list[str] = []

    def sim(self, effects: tuple[Effect, ...]) -> SimResult:
        spec = self.meas.spec(effects)
        key = replace(spec, I0=0.0)
        if key not in self._cache:
            self.simulations += 1
            try:
                self._cache[key] = self.meas.replay(key)
            except (RuntimeError, FloatingPointError, ValueError, PdrError) as err:
                # a parameter value the simulator cannot run counts as infinitely bad, not as a crash
                self.failures.append(f"{key}: {err}")
                self._cache[key] = _failed(self.meas.t)
        base = self._cache[key]
        if spec.I0 == 0.0:
            return base
        return replace(base, current_measured=base.current + spec.I0)

    def nll(self, sim: SimResult, mask: np.ndarray | None = None) -> float:
        """Concentrated Gaussian negative log-likelihood over the fitted signals (on ``mask``)."""
        total = 0.0
        for s, r in residuals(self.meas, sim).items():
            rm = r if mask is None else r[mask]
            # a thousandth of the noise floor keeps the log finite on noiseless test data
            total += 0.5 * len(rm) * np.log(np.mean(rm * rm) + 1e-3 * self.floor[s])
        return float(total) if np.isfinite(total) else FAILED_NLL

    def mse(self, sim: SimResult, mask: np.ndarray | None = None) -> dict[str, float]:
        return {s: float(np.mean((r if mask is None else r[mask]) ** 2))
                for s, r in residuals(self.meas, sim).items()}


# what a model the simulator cannot run scores: finite (Brent's method does arithmetic on it), huge
FAILED_NLL = 1e12


def _failed(t: np.ndarray) -> SimResult:
    nan = np.full(len(t), np.nan)
    return SimResult(t=t, theta=nan, omega=nan, current=nan, current_measured=nan, delta=nan,
                     dir=np.zeros(len(t), dtype=np.int8), u=nan)


@dataclass
class Fit:
    """One candidate effect fitted on top of the current model."""

    name: str
    parameter: str
    value: float
    nll: float                        # on all samples
    interval: tuple[float, float]     # ~95 %, Jacobian with an autocorrelation correction, widened by fold spread
    fold_values: tuple[float, ...]    # the estimate from each held-out fold's training half
    heldout_mse_before: dict[str, float] = field(default_factory=dict)
    heldout_mse_after: dict[str, float] = field(default_factory=dict)
    heldout_nll_gain: float = 0.0     # nll decrease on held-out samples (> 0: better)

    @property
    def effect(self) -> Effect:
        return make(self.name, self.value)

    @property
    def excludes_null(self) -> bool:
        lo, hi = self.interval
        null = NULL_VALUE[self.name]
        return not (lo <= null <= hi)


def scan(ev: Evaluator, base: tuple[Effect, ...], name: str) -> tuple[np.ndarray, np.ndarray]:
    """The coarse scan: scan points and their nll on all samples."""
    grid = _scan(name)
    return grid, np.array([ev.nll(ev.sim((*base, make(name, v)))) for v in grid])


def fit_value(ev: Evaluator, base: tuple[Effect, ...], name: str, mask: np.ndarray | None = None,
              bracket: tuple[float, float] | None = None,
              scanned: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[float, float]:
    """Best value of ``name``'s parameter on top of ``base`` (and its nll on ``mask``).

    Without a bracket the coarse scan (reused when given) picks the basin first.
    """
    def loss(v: float) -> float:
        return ev.nll(ev.sim((*base, make(name, v))), mask)

    if bracket is None:
        grid, losses = scanned if scanned is not None else scan(ev, base, name)
        i = int(np.argmin(losses))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        best_v, best_l = float(grid[i]), float(losses[i])
    else:
        lo, hi = bracket
        best_v, best_l = float("nan"), float("inf")
    scale = max(abs(lo), abs(hi), 1e-12)
    res = minimize_scalar(loss, bounds=(lo, hi), method="bounded", options={"xatol": 2e-4 * scale, "maxiter": 30})
    if res.fun < best_l:
        best_v, best_l = float(res.x), float(res.fun)
    return best_v, best_l


def bracket_around(name: str, v: float, width: float = 0.3) -> tuple[float, float]:
    """A search range around an estimate, inside the effect's bounds.

    Narrow on purpose: the replayed loss of an oscillator has side minima
    (a model far off drifts out of phase with the logged command), so refits
    stay in the basin the full scan found.
    """
    lo_b, hi_b = next(iter(CATALOGUE[name].BOUNDS.values()))
    if name == "current_sensor_offset":
        half = max(abs(v) * width, 0.02)
        return max(v - half, lo_b), min(v + half, hi_b)
    if v <= lo_b:
        return lo_b, float(_scan(name)[1])
    return max(v * (1.0 - width), lo_b), min(v * (1.0 + width), hi_b)


def autocorrelation_time(r: np.ndarray, max_lag: int = 50) -> float:
    """1 + 2 sum rho_k (to the first negative rho): how many samples one independent one is worth."""
    r = r - r.mean()
    den = float(np.dot(r, r))
    if den == 0:
        return 1.0
    tau = 1.0
    for k in range(1, min(max_lag, len(r) // 4)):
        rho = float(np.dot(r[:-k], r[k:])) / den
        if rho <= 0:
            break
        tau += 2.0 * rho
    return tau


@dataclass
class Sensitivity:
    """Residuals at the estimate and their derivative with respect to the parameter, per signal."""

    r0: dict[str, np.ndarray]
    jac: dict[str, np.ndarray]


def sensitivity(ev: Evaluator, base: tuple[Effect, ...], name: str, v: float) -> Sensitivity:
    lo_b, hi_b = next(iter(CATALOGUE[name].BOUNDS.values()))
    h = max(abs(v) * 1e-3, (hi_b - lo_b) * 1e-6)
    v2 = v + h if v + h <= hi_b else v - h
    r0 = residuals(ev.meas, ev.sim((*base, make(name, v))))
    r1 = residuals(ev.meas, ev.sim((*base, make(name, v2))))
    if not all(np.all(np.isfinite(r)) for r in r1.values()) and v - h >= lo_b:
        v2 = v - h
        r1 = residuals(ev.meas, ev.sim((*base, make(name, v2))))
    return Sensitivity(r0=r0, jac={s: (r1[s] - r0[s]) / (v2 - v) for s in r0})


def interval(ev: Evaluator, sens: Sensitivity, v: float) -> tuple[float, float]:
    """~95 % interval from the sensitivity of the residuals (Gauss-Newton), per signal's residual
    variance, with the sample count divided by the residual's autocorrelation time."""
    info = 0.0
    for s, r in sens.r0.items():
        jac = sens.jac[s]
        var = float(np.mean(r ** 2)) + 1e-3 * ev.floor[s]
        info += float(np.dot(jac, jac)) / (var * autocorrelation_time(r))
    half = 1.96 / np.sqrt(info) if info > 0 else float("inf")
    return v - half, v + half


def gauss_newton_step(sens: Sensitivity, v: float, mask: np.ndarray, name: str) -> float:
    """The estimate on ``mask`` alone, one Gauss-Newton step from the all-sample estimate
    (the concentrated likelihood weights each signal by its residual variance)."""
    num = den = 0.0
    for s, r in sens.r0.items():
        rm, jm = r[mask], sens.jac[s][mask]
        w = 1.0 / (float(np.mean(rm ** 2)) + 1e-12)
        num += w * float(np.dot(jm, rm))
        den += w * float(np.dot(jm, jm))
    lo_b, hi_b = next(iter(CATALOGUE[name].BOUNDS.values()))
    step = -num / den if den > 0 else 0.0
    return float(np.clip(v + step, lo_b, hi_b))


def fit_candidate(ev: Evaluator, base: tuple[Effect, ...], name: str,
                  folds: tuple[np.ndarray, np.ndarray],
                  scanned: tuple[np.ndarray, np.ndarray] | None = None) -> Fit:
    """Fit on all samples; estimate on each fold's training half and score on the other half."""
    value, nll_all = fit_value(ev, base, name, scanned=scanned)
    sens = sensitivity(ev, base, name, value)
    base_sim = ev.sim(base)
    fold_values = []
    gain = 0.0
    mse_b: dict[str, float] = {}
    mse_a: dict[str, float] = {}
    for train in folds:
        test = ~train
        v_f = gauss_newton_step(sens, value, train, name)
        sim_f = ev.sim((*base, make(name, v_f)))
        if ev.nll(sim_f) >= FAILED_NLL:           # the step landed where the simulator fails
            v_f = value
            sim_f = ev.sim((*base, make(name, v_f)))
        fold_values.append(v_f)
        gain += ev.nll(base_sim, test) - ev.nll(sim_f, test)
        share = test.sum() / len(test)
        for s, m in ev.mse(base_sim, test).items():
            mse_b[s] = mse_b.get(s, 0.0) + m * share
        for s, m in ev.mse(sim_f, test).items():
            mse_a[s] = mse_a.get(s, 0.0) + m * share
    lo, hi = interval(ev, sens, value)
    spread = (max(fold_values) - min(fold_values)) / 2.0
    lo, hi = min(lo, value - spread), max(hi, value + spread)
    return Fit(name=name, parameter=parameter_of(name), value=value, nll=nll_all, interval=(lo, hi),
               fold_values=tuple(fold_values), heldout_mse_before=mse_b, heldout_mse_after=mse_a,
               heldout_nll_gain=gain)


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
