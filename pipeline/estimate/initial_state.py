"""Where a recording starts: the initial state and the commands the motor is under, from the data.

A recording may open anywhere: logging started while the rig ran, a segment after a board
reset, a sketch whose first current reading is three noise sigmas off.  The state
x0 = [I, w, delta] at the first sample, the command in force there and, under a loop delay
Td, the commands decided before the first sample and still on their way to the motor are
nuisance parameters (docs/MODEL.md).  One noisy first sample says little about them; the
first seconds say a lot.  The replayed response of a linear plant is affine in x0 and in
each pre-log command, so superposed simulations (one per unit initial state, one per
pre-log command, one for the logged commands) make the estimate a weighted linear least-
squares problem, as MATLAB's ``findstates`` does, with its covariance.  The commands are
-1, 0 or +1: every plausible pre-log sequence is tried and the most probable kept.  A plant with
Coulomb friction or backlash is not affine; its estimate is refined from the superposed one
by a few Gauss-Newton steps on the full simulation (forward-difference Jacobians), unless one
simulation shows the plant stayed affine over the window (no stick, no dead zone crossed).  Signals are weighted by their own noise (``noise.signal_noise``), or by their misfit
where the model misses by more.

The pre-log commands enter the simulator as samples before the first one: the command
decided at t0 - Td reaches the motor at t0 (the command in force at the first sample),
those decided at t0 - j*T (j*T < Td, T the control period) arrive during the first Td.
Between the first of these instants and t0 nothing has arrived, so the motor is off and
the state there, ``z``, moves freely into x0.  Without a loop delay the command in force
before the first sample acts only before it, and x0 alone is estimated.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from pipeline.estimate.commands_in_flight import InFlight, command_spread, lead_offsets, pinv
from pipeline.estimate.start import Start, first_dir
from pipeline.model.effects import PlantSpec
from pipeline.model.simulate import Prepared, SimResult, with_lost_samples

# Samples the estimate uses: the first 2 s (at least 20 samples).  x0 shows most there (the rig's
# oscillatory mode decays in ~1.2 s) and a model error has had little time to grow.  A model
# missing a constant torque takes it up as an initial current, which a sensor offset may then
# "explain": of six such virtual-rig recordings, one was misnamed with a 1 s window, one with 5 s,
# none with 2 s.  With the right model, 1, 2 and 5 s gave x0 within 0.6 mA and 0.01 rad/s of the
# truth alike.
WINDOW_S = 2.0
WINDOW_MIN_SAMPLES = 20
WINDOW_SAMPLES = 1200
# Typical sizes of [I, w, delta] (A, rad/s, m): the unit responses are simulated at these
# amplitudes so the least-squares columns are of comparable size.
STATE_SCALES = np.array([0.1, 1.0, 0.01])
REWEIGHTS = 3                    # reweightings by the misfit (stopped once the variances settle)
REFINE_STEPS = 3                 # Gauss-Newton steps for a plant that is not affine in x0
REFINE_TOLERANCE = 1e-3         # Gauss-Newton stops once a step gains less than this share of the cost
JACOBIAN_STEP = 1e-3             # of a coefficient (a fraction of the state's typical size)
# name -> (measured values, noise variance); names "theta" [rad] and "current" [A, as the sensor reads]
Observed = dict[str, tuple[np.ndarray, float]]


def _window(t: np.ndarray) -> int:
    n = max(int(np.searchsorted(t, t[0] + WINDOW_S, side="right")), WINDOW_MIN_SAMPLES)
    return min(n, WINDOW_SAMPLES, len(t))


def _state(sim: SimResult, k: int) -> np.ndarray:
    return np.array([sim.current[k], sim.omega[k], sim.delta[k]])


class _Problem:
    """The observations over the window, the model's outputs on them and the weights.

    ``spec`` is the plant without its current-sensor offset; ``I0`` is added to the modelled
    current here, so one set of simulations serves every offset."""

    def __init__(self, spec: PlantSpec, t: np.ndarray, observed: Observed) -> None:
        self.n = n = _window(t)
        self.spec = spec
        self.runs = 0                                   # simulations run (a caller's budget counts them)
        self.I0 = 0.0
        self.offset = 0.0                               # rad: the counter's zero off the springs' rest
        self.lead = lead_offsets(float(spec.Td), float(spec.period_s))
        self.m = len(self.lead)
        # the sketch's own loop instants: a row lost over serial is simulated too (as ``Start.simulate``
        # replays it), its command decided by the sketch's rule on the measured angle (``set_log``)
        t_loop, _, self.kept = with_lost_samples(t[:n], np.zeros(n, dtype=np.int8))
        self.t = np.concatenate([t[0] + self.lead, t_loop])
        self.names = [s for s in ("theta", "current") if s in observed]
        ys, ok, which = [], [], []
        for i, s in enumerate(self.names):
            y = np.asarray(observed[s][0][:n], dtype=float)
            ys.append(np.where(np.isfinite(y), y, 0.0))
            ok.append(np.isfinite(y))
            which.append(np.full(len(y), i))
        self.y = np.concatenate(ys)
        self.ok = np.concatenate(ok)
        self.which = np.concatenate(which)
        # each signal's observed rows (the variances and the score ask after every reweighting)
        self._rows = [np.flatnonzero(self.ok & (self.which == i)) for i in range(len(self.names))]
        self._counts = np.array([len(rows) for rows in self._rows])
        self.noise = np.array([max(float(observed[s][1]), 1e-30) for s in self.names])
        self.current_rows = (np.array(self.names) == "current")[self.which].astype(float)
        self._runs: dict[bytes, SimResult] = {}
        self._prepared: dict[bytes, Prepared] = {}
        self._template: Prepared | None = None          # the plant and instants, checked once
        self.theta_rows = (np.array(self.names) == "theta")[self.which].astype(float)
        self.theta_measured = np.asarray(observed["theta"][0][:n], dtype=float) if "theta" in observed else None
        self.set_log(np.zeros(n, dtype=np.int8))       # the logged command, set per estimate

    def run(self, z, commands, *, logged: bool = True) -> SimResult:
        """Replay from ``z`` under the pre-log ``commands`` and (``logged``) the logged ones, else motor off.

        Remembered by the exact inputs until ``forget_runs``: a Gauss-Newton refinement asks again for
        the state it has just tried or stepped from (its Jacobian's base point, the next call's start)."""
        loop_log = self.loop_log if logged else np.zeros(len(self.t) - self.m, dtype=np.int8)
        log = np.concatenate([np.asarray(commands, dtype=np.int8), loop_log])
        key = np.asarray(z, dtype=float).tobytes() + log.tobytes()
        if key not in self._runs:
            self.runs += 1
            self._runs[key] = self._replay(log).run(tuple(z))
        return self._runs[key]

    def _replay(self, log: np.ndarray) -> Prepared:
        """The replay under ``log``, checked once: the starts tried under one command differ only in x0."""
        key = log.tobytes()
        if key not in self._prepared:
            if len(self._prepared) >= 64:
                self._prepared.clear()
            if self._template is None:
                self._template = Prepared.of(self.spec, self.t, dir0=first_dir(log), dir_log=log, closed_loop=False)
            self._prepared[key] = self._template.under(log, dir0=first_dir(log))
        return self._prepared[key]

    def forget_runs(self) -> None:
        self._runs.clear()

    def set_log(self, log: np.ndarray, shifted: tuple[int, ...] = ()) -> None:
        """The logged commands of this estimate, and on the loop's instants (``with_lost_samples``: a lost
        row's command by the sketch's rule on the measured angle, its own count's frame, or a sample from it
        after the samples ``shifted``), fixed by the data, not by the model's angle, so the replay stays
        affine in x0."""
        self.log = log
        self.loop_log = log if self.kept[-1] + 1 == len(self.kept) else with_lost_samples(
            self.t[self.m:][self.kept], log, self.theta_measured, float(self.spec.guard_rad), shifted)[1]

    def outputs(self, sim: SimResult, measured: bool = True) -> np.ndarray:
        """Model outputs at the real samples (``measured``: the current as the sensor reads it, + I0)."""
        m = self.m
        cols = {"theta": sim.theta[m:][self.kept], "current": sim.current[m:][self.kept]}
        out = np.concatenate([cols[s] for s in self.names])
        return out + self.I0 * self.current_rows + self.offset * self.theta_rows if measured else out

    def weights(self, variances: np.ndarray) -> np.ndarray:
        return np.where(self.ok, 1.0 / np.sqrt(variances[self.which]), 0.0)

    def variances(self, r: np.ndarray) -> np.ndarray:
        """Per signal: its noise, or its mean-square misfit when the model misses by more (a
        model error in the angle then does not buy a wrong current)."""
        out = self.noise.copy()
        for i, rows in enumerate(self._rows):
            if len(rows):
                x = r[rows]
                out[i] = max(out[i], float(np.add.reduce(x * x)) / len(rows))     # np.mean's sum, without its checks
        return out

    def score(self, variances: np.ndarray) -> float:
        """The concentrated negative log-likelihood, sum over signals of n_s log(variance_s)."""
        return float(np.sum(self._counts * np.log(variances)))

    @property
    def dof(self) -> int:
        return int(np.count_nonzero(self.ok))


def _within_tenth(a: np.ndarray, b: np.ndarray) -> bool:
    """``np.allclose(a, b, rtol=0.1)`` on a few numbers, without its ~40 us of array machinery (a start
    estimate asks after every reweighting); an infinite variance (a signal left out) equals only itself."""
    return all(x == y or (math.isfinite(x) and math.isfinite(y) and abs(x - y) <= 1e-8 + 0.1 * abs(y))
               for x, y in zip(a.tolist(), b.tolist()))


def _residual_scale(r: np.ndarray, dof: int) -> float:
    """Variance factor of the weighted residual: its mean square per degree of freedom (model
    error and a misjudged noise widen the interval, never narrow it), times (1 + rho)/(1 - rho)
    for its lag-1 autocorrelation rho (quantisation of a slow signal and model error are not
    white, so neighbouring samples carry less than independent ones)."""
    r = r[r != 0.0]
    if len(r) < 3:
        return 1.0
    rho = float(np.clip(np.dot(r[1:], r[:-1]) / np.dot(r, r), 0.0, 0.95))
    return max(1.0, float(np.dot(r, r)) / max(dof - 3, 1)) * (1.0 + rho) / (1.0 - rho)


def _jacobian(p: _Problem, a: np.ndarray, commands) -> np.ndarray:
    """d(outputs)/d(coefficients) of the full simulation at ``a``, by forward differences."""
    at = p.outputs(p.run(a * STATE_SCALES, commands))
    cols = []
    for i in range(3):
        h = np.zeros(3)
        h[i] = JACOBIAN_STEP
        cols.append((p.outputs(p.run((a + h) * STATE_SCALES, commands)) - at) / JACOBIAN_STEP)
    return np.column_stack(cols)


def _gauss_newton(p: _Problem, a: np.ndarray, commands,
                  w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A few Gauss-Newton steps (the Jacobian taken afresh at each: stick/slip bends the
    response), each halved until the weighted cost drops; returns (a, residual, Jacobian)."""
    residual = p.y - p.outputs(p.run(a * STATE_SCALES, commands))
    cost = float(np.sum((residual * w) ** 2))
    for _ in range(REFINE_STEPS):
        J = _jacobian(p, a, commands)
        Jw = J * w[:, None]
        step = np.linalg.lstsq(Jw, residual * w, rcond=None)[0]
        for _ in range(4):
            trial = a + step
            r = p.y - p.outputs(p.run(trial * STATE_SCALES, commands))
            c = float(np.sum((r * w) ** 2))
            if c < cost:
                break
            step = step / 2.0
        else:
            break
        gain = (cost - c) / max(cost, 1e-300)
        a, residual, cost = trial, r, c
        if gain < REFINE_TOLERANCE:
            break
    return a, residual, _jacobian(p, a, commands)


def _first_weights(p: _Problem) -> list[np.ndarray]:
    """Where the reweighting starts: every signal at its noise, and the angle alone (a model that
    misses the current by far more than its noise must not drag the angle after it)."""
    starts = [p.noise]
    if "current" in p.names and "theta" in p.names:
        starts.append(np.where(np.array(p.names) == "theta", p.noise, np.inf))
    return starts


class StartEstimator:
    """The simulations a start estimate needs, for one plant without its current-sensor offset:
    the responses to unit initial states and to each pre-log command do not depend on the logged
    command, so they are simulated once; each command then costs one replay, and a sensor offset
    none (it only moves the measured current).

    ``angle_offset``: the counter's zero is not where the springs rest (a segment after a board
    reset restarts the count wherever the pinion then is), so a constant in the angle is a fourth
    unknown of the same least squares; it moves no state."""

    def __init__(self, spec: PlantSpec, t: np.ndarray, observed: Observed, angle_offset: bool = False) -> None:
        p = _Problem(spec, np.asarray(t, dtype=float), observed)
        zeros = np.zeros(p.m, dtype=np.int8)
        # The response from rest with the motor off: zero, unless a constant load torque drives the
        # plant.  The base replay holds it once; each unit response holds it too, so it is taken
        # out of them (superposing them otherwise adds it once per unit of each coefficient).
        rest = p.run((0.0, 0.0, 0.0), zeros, logged=False)
        rest_out, rest_state = p.outputs(rest, measured=False), _state(rest, p.m)
        free = []
        for i in range(3):
            z = np.zeros(3)
            z[i] = STATE_SCALES[i]
            free.append(p.run(z, zeros, logged=False))
        self.F = np.column_stack([p.outputs(s, measured=False) - rest_out for s in free])
        self.Phi = np.column_stack([_state(s, p.m) - rest_state for s in free])   # x0 per unit coefficient
        self.rest_state = rest_state                                              # ... about this one
        if angle_offset:
            self.F = np.column_stack([self.F, p.theta_rows])
            self.Phi = np.column_stack([self.Phi, np.zeros(3)])
        pulses = []
        for j in range(p.m):
            c = zeros.copy()
            c[j] = 1
            pulses.append(p.outputs(p.run((0.0, 0.0, 0.0), c, logged=False), measured=False) - rest_out)
        self.P = np.column_stack(pulses) if pulses else np.zeros((len(p.y), 0))
        self.in_flight = InFlight(self.P)
        self.p = p
        self._base: dict[bytes, np.ndarray] = {}
        self._refined: np.ndarray | None = None    # the last Gauss-Newton start (``_warmer``)

    def _nearly_affine(self, a: np.ndarray, commands, predicted: np.ndarray) -> bool:
        """Whether the full simulation from the superposed estimate is the superposition's
        prediction to within one noise variance over the whole window: Coulomb friction that
        never sticks in the window, a dead zone never crossed.  One simulation instead of a
        Gauss-Newton refinement.  Sample by sample and weighted by the noise: a superposed fit
        that misses (a dead zone crossed) inflates its misfit weights, under which a wrong
        start can still look no worse than the prediction."""
        p = self.p
        full = p.y - p.outputs(p.run(a * STATE_SCALES, commands))
        return float(np.sum(((full - predicted) * p.weights(p.noise)) ** 2)) <= 1.0

    def _warmer(self, a: np.ndarray, commands, w: np.ndarray) -> np.ndarray:
        """Where Gauss-Newton starts: the superposed estimate ``a``, or this plant's last refined start
        when it fits better (the next command differs from the last by a sample's onset, so it is
        close and the refinement stops after a step instead of three)."""
        last = self._refined
        if last is None:
            return a
        p = self.p
        cost = [float(np.sum(((p.y - p.outputs(p.run(c * STATE_SCALES, commands))) * w) ** 2)) for c in (a, last)]
        return last if cost[1] < cost[0] else a

    @property
    def runs(self) -> int:
        """Simulations this estimator has run, its unit and pulse responses included."""
        return self.p.runs

    def window(self, dir_log: np.ndarray, shifted: tuple[int, ...] = ()) -> bytes:
        """The part of a command sequence the estimate sees, with the lost rows' reversals moved in it (a cache
        key)."""
        return (np.asarray(dir_log[:self.p.n], dtype=np.int8).tobytes()
                + np.asarray(self._inside(shifted), dtype=np.int64).tobytes())

    def _inside(self, shifted: tuple[int, ...]) -> tuple[int, ...]:
        """The shifted gaps within the window (the others do not change the estimate, nor its cache key)."""
        return tuple(i for i in sorted(shifted) if i + 1 < self.p.n)

    def start(self, dir_log: np.ndarray, I0: float = 0.0, offset: float | None = None,
              shifted: tuple[int, ...] = ()) -> Start:
        """x0, its covariance and the pre-log commands under ``dir_log`` and sensor offset ``I0``
        (and, for an estimator with a free ``angle_offset``, that offset when it is known from elsewhere),
        with the reversals in the gaps of lost rows after the samples ``shifted`` a sample from the rule's.

        Signals are weighted by their noise or their misfit, whichever is larger, reweighted a
        few times from two starts (``_first_weights``); the start with the better concentrated
        likelihood (the measure discovery scores with, one variance per signal) wins.
        """
        p = self.p
        p.forget_runs()
        key = self.window(dir_log, shifted)
        p.set_log(np.asarray(dir_log[:p.n], dtype=np.int8).copy(), self._inside(shifted))
        if key not in self._base:
            self._base[key] = p.y - p.outputs(p.run((0.0, 0.0, 0.0), np.zeros(p.m, dtype=np.int8)), measured=False)
        p.I0 = float(I0)
        r0 = self._base[key] - p.I0 * p.current_rows
        F, P, Phi = self.F, self.P, self.Phi
        if offset is not None and F.shape[1] > 3:
            F, Phi = F[:, :3], Phi[:, :3]
            r0 = r0 - offset * p.theta_rows
        best = None
        for variances in _first_weights(p):
            for _ in range(REWEIGHTS):
                fits = self.in_flight.fit(r0, F, p.weights(variances), int(p.log[0]))
                _, commands, a = fits[0]
                residual = r0 - P @ np.asarray(commands, dtype=float) - F @ a
                previous, variances = variances, p.variances(residual)
                if _within_tenth(variances, previous):
                    break
            score = p.score(variances)
            if best is None or score < best[0]:
                best = (score, fits, variances)
            if np.all(variances <= 4.0 * p.noise):       # the model fits every signal: nothing to guard against
                break
        _, fits, variances = best
        _, commands, a = fits[0]
        p.offset = float(a[3]) if len(a) > 3 else float(offset or 0.0)
        fit_phi = Phi                          # the coefficients of ``fits`` map to x0 by this one
        w = p.weights(variances)
        J = F
        if p.spec.is_linear or self._nearly_affine(a[:3], commands, residual):
            x0 = self.rest_state + Phi @ a
        else:
            # not affine in x0 (Coulomb friction, backlash): Gauss-Newton on the full simulation
            # from the superposed estimate, reweighted by the misfit it leaves
            a, Phi = a[:3], Phi[:, :3]          # the angle offset stays at its superposed estimate
            a = self._warmer(a, commands, w)
            for _ in range(2):
                a, residual, J = _gauss_newton(p, a, commands, w)
                previous, variances = variances, p.variances(residual)
                w = p.weights(variances)
                if _within_tenth(variances, previous):
                    break
            x0 = _state(p.run(a * STATE_SCALES, commands), p.m)
            self._refined = a
        p.forget_runs()
        Jw = J * w[:, None]
        scale = _residual_scale(residual * w, p.dof)
        cov_x = Phi @ (scale * pinv(Jw.T @ Jw)) @ Phi.T + command_spread(fits, fit_phi, scale)
        sigma = np.sqrt(np.clip(np.diag(cov_x), 0.0, None))
        return Start(x0=tuple(float(v) for v in x0), sigma=tuple(float(v) for v in sigma),
                     lead_s=tuple(float(v) for v in p.lead), commands=tuple(int(c) for c in commands),
                     z=tuple(float(v) for v in a[:3] * STATE_SCALES), current_offset=p.I0,
                     angle_offset=p.offset)


def without_offset(spec: PlantSpec) -> PlantSpec:
    """The plant with its current-sensor offset removed (what ``StartEstimator`` simulates)."""
    return replace(spec, I0=0.0)
