"""Hybrid automaton simulator (shared/MODEL.md): sampled bang-bang guard, ZOH input, every effect.

The automaton: modes q1 (u = +v_drive) and q2 (u = -v_drive) share one flow
matrix (eqs. 2, 4/8, 5); the controller samples theta at the recording's own
instants (uneven spacing allowed), reverses at +/- guard_rad and holds the
command until the next sample; the reset is the identity.  The command decided
at sample k reaches the motor at t_k + Td (loop delay; 0 by default), and the
motor is off until the first command arrives.

Two exact integrators behind one ``simulate``:

- linear plant (no Coulomb friction, no backlash) with the sampled guard:
  ``pipeline.model.linear`` -- one cached matrix exponential per distinct
  step length, then plain float arithmetic per sample (500 samples in ~0.5 ms);
- otherwise ``pipeline.model.nonsmooth``: event-driven, stick/slip, velocity
  zero crossings, backlash edges and (``guard="continuous"``) the guard
  crossing itself located on the closed-form solution.

``I0`` only touches the output: ``current_measured = current + I0``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from pipeline.errors import PdrError
from pipeline.model.effects import PlantSpec
from pipeline.model.kernels import TIME_EPS, linear_outputs, next_dir, run_linear_batch
from pipeline.model.linear import KEY_DECIMALS
from pipeline.model.nonsmooth import NonsmoothPlant

GUARDS = ("sampled", "continuous")
_NO_LOG = np.zeros(0, dtype=np.int8)


@dataclass(frozen=True)
class SimResult:
    """Simulated signals at the sample instants ``t`` (what the Arduino would have logged)."""

    t: np.ndarray                  # s    sample instants
    theta: np.ndarray              # rad  pinion angle  (eq. 7: delta / R)
    omega: np.ndarray              # rad/s
    current: np.ndarray            # A    true armature current
    current_measured: np.ndarray   # A    what the current sensor reads (current + I0)
    delta: np.ndarray              # m    rack displacement
    dir: np.ndarray                # int8 command decided at each sample: +1 (q1), -1 (q2), 0 (off)
    u: np.ndarray                  # V    voltage commanded after each sample (before any loop delay)

    @property
    def switch_times(self) -> np.ndarray:
        """Sample instants at which the command reversed."""
        d = self.dir
        idx = np.flatnonzero((d[1:] != d[:-1]) & (d[1:] != 0) & (d[:-1] != 0)) + 1
        return self.t[idx]

    @property
    def switches(self) -> int:
        return int(len(self.switch_times))


def sample_times(duration: float, period: float) -> np.ndarray:
    """Nominal sample instants 0, T, 2T, ... up to ``duration`` (24.95 s at 50 ms: 500 samples)."""
    n = int(np.floor(duration / period + 1e-9)) + 1
    return np.arange(n) * period


@dataclass(frozen=True)
class _Plan:
    """The controller's schedule: which samples follow a log, where the sampled guard takes over."""

    t: np.ndarray
    dir_log: np.ndarray | None
    closed_loop: bool
    start: int             # first sample decided by the controller (closed loop)
    first: int             # its mode at ``start`` (0: decide by next_dir from dir0)
    dir0: int

    @property
    def log(self) -> np.ndarray:
        """The logged commands as the kernels take them (int8; empty when there is no log)."""
        return _NO_LOG if self.dir_log is None else self.dir_log

    def decide(self, k: int, d_prev: int, theta: float, guard: float) -> int:
        if not self.closed_loop or k < self.start:
            return int(self.dir_log[k])
        if k == self.start:
            return self.first if self.first else next_dir(self.dir0, theta, guard)
        return next_dir(d_prev, theta, guard)


class _Controller:
    """The sketch's decision at each sample and the commands on their way to the motor.

    A command decided at sample k reaches the motor at t_k + Td (``loop_delay``);
    ``pending`` holds (arrival time, voltage) for the integrators to apply.
    """

    def __init__(self, plan: _Plan, t: list[float], guard: float, v_drive: float, Td: float) -> None:
        self.plan, self.t, self.guard, self.v_drive, self.Td = plan, t, guard, v_drive, Td
        self.pending: deque[tuple[float, float]] = deque()
        self.d = 0

    def step(self, k: int, theta: float) -> int:
        d = self.plan.decide(k, self.d, theta, self.guard)
        if d != self.d or k == 0:
            self.pending.append((self.t[k] + self.Td, d * self.v_drive))
        self.d = d
        return d

    def reverse_at(self, time: float) -> int:
        """The continuous-guard variant: reverse the instant theta reaches the guard, between samples."""
        self.d = -self.d
        self.pending.append((time + self.Td, self.d * self.v_drive))
        return self.d


def _plan(spec: PlantSpec, t, duration: float, dir0: int, dir_log, closed_loop: bool, guard: str) -> _Plan:
    if guard not in GUARDS:
        raise PdrError(f"unknown guard '{guard}', expected one of {', '.join(GUARDS)}", key="guard")
    t = sample_times(duration, spec.period_s) if t is None else np.asarray(t, dtype=float)
    if t.ndim != 1 or len(t) == 0 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0.0):
        raise PdrError("expected a non-empty, finite, non-decreasing array of sample instants", key="t")
    if dir0 not in (-1, 1):
        raise PdrError(f"expected dir0 = 1 or -1, got {dir0!r}", key="dir0")
    t = np.ascontiguousarray(t)                # the kernels take contiguous arrays
    if dir_log is None:
        if not closed_loop:
            raise PdrError("replay (closed_loop=False) needs the logged command", key="dir_log")
        return _Plan(t, None, closed_loop, 0, 0, int(dir0))
    dir_log = np.asarray(dir_log)
    if dir_log.shape != t.shape:
        raise PdrError(f"expected one command per sample ({len(t)}), got {dir_log.shape}", key="dir_log")
    if not np.all(np.isin(dir_log, (-1, 0, 1))):
        raise PdrError("expected commands -1, 0 or 1", key="dir_log")
    nz = np.flatnonzero(dir_log != 0)
    start = int(nz[0]) if len(nz) else len(t)
    first = int(dir_log[start]) if len(nz) else 0
    return _Plan(t, dir_log.astype(np.int8), closed_loop, start, first, int(dir0))


def simulate(spec: PlantSpec, t: np.ndarray | None = None, *, duration: float = 24.95,
             x0: tuple[float, float, float] = (0.0, 0.0, 0.0), dir0: int = 1,
             dir_log: np.ndarray | None = None, closed_loop: bool = True,
             guard: str = "sampled") -> SimResult:
    """Run the automaton at sample instants ``t`` (default: every ``period_s`` for ``duration``).

    closed_loop=True: the controller decides from theta at each sample, starting
    in mode ``dir0``; if ``dir_log`` is given, its leading zeros (motor off
    before the sketch starts) are honoured and the controller starts in the
    mode of its first non-zero entry.  closed_loop=False (replay): ``dir_log``
    (-1/0/1) drives the motor.  ``guard="continuous"`` switches the instant
    theta crosses the guard instead of at the next sample (for comparison).
    Either way the motor sees a command ``Td`` after it is decided.
    """
    plan = _plan(spec, t, duration, dir0, dir_log, closed_loop, guard)
    x = np.array(x0, dtype=float)
    if spec.is_linear and (guard == "sampled" or not closed_loop):
        return _run_linear(spec, plan, x)
    X, dirs = _run_events(spec, plan, x, continuous=guard == "continuous" and closed_loop)
    return result_from_states(spec, plan.t, X, dirs)


def result_from_states(spec: PlantSpec, t: np.ndarray, X: np.ndarray, dirs: np.ndarray) -> SimResult:
    """Package states [I, w, delta] per sample (..., n, 3) and commands as a ``SimResult``."""
    current = X[..., 0]
    return SimResult(t=t, theta=X[..., 2] / spec.params.R, omega=X[..., 1], current=current,
                     current_measured=current + spec.I0, delta=X[..., 2], dir=dirs,
                     u=dirs.astype(float) * spec.v_drive)


def _run_linear(spec: PlantSpec, plan: _Plan, x: np.ndarray) -> SimResult:
    """Exact ZOH stepping in the compiled kernel (``kernels.run_linear_batch`` with one set)."""
    A, B = spec.params.state_matrices()
    current, omega, delta, theta, dirs = linear_outputs(1, len(plan.t))
    run_linear_batch(plan.t, A[None], B[None], np.array([spec.params.R], dtype=float),
                     np.array([spec.guard_rad], dtype=float), np.array([spec.v_drive], dtype=float),
                     np.array([spec.Td], dtype=float), x, plan.log, plan.closed_loop, plan.start, plan.first,
                     plan.dir0, current, omega, delta, theta, dirs)
    return SimResult(t=plan.t, theta=theta[0], omega=omega[0], current=current[0],
                     current_measured=current[0] + spec.I0, delta=delta[0], dir=dirs[0],
                     u=dirs[0] * float(spec.v_drive))


def _run_events(spec: PlantSpec, plan: _Plan, x: np.ndarray, *, continuous: bool) -> tuple[np.ndarray, np.ndarray]:
    """Event-driven exact integration (stick/slip, backlash edges, continuous guard, delayed commands)."""
    plant = NonsmoothPlant(spec)
    x = tuple(float(v) for v in x)
    plant.reset(x)
    t = plan.t.tolist()
    n = len(t)
    R, guard, V, Td = spec.params.R, spec.guard_rad, spec.v_drive, spec.Td
    hs = np.round(np.diff(plan.t), KEY_DECIMALS).tolist()
    out = []
    dirs = []
    controller = _Controller(plan, t, guard, V, Td)
    pending = controller.pending
    u_m = 0.0
    by_regime: dict[tuple, dict[float, tuple]] = {}    # (z, s, u, armed) -> step length -> quick entry
    last_regime = None
    by_length: dict[float, tuple] = {}
    for k in range(n):
        out.append(x)
        d = controller.step(k, x[2] / R)
        dirs.append(d)
        if k + 1 == n:
            break
        tk, t_next = t[k], t[k + 1]
        armed = d if continuous and k >= plan.start else 0
        while True:
            while pending and pending[0][0] <= tk + TIME_EPS:
                u_m = pending.popleft()[1]
            if pending and pending[0][0] < t_next - TIME_EPS:
                stop = pending[0][0]                  # a delayed command lands inside this step
            else:
                stop = t_next
            # lengths rounded like the step caches' keys, so repeated spacings hit the same entry
            L = hs[k] if stop == t_next and tk == t[k] else round(stop - tk, KEY_DECIMALS)
            # the common case, inlined: a cached whole step with no event (see NonsmoothPlant.quick_entry)
            regime = (plant.z, plant.s, u_m, armed)
            if regime != last_regime:
                by_length = by_regime.setdefault(regime, {})
                last_regime = regime
            e = by_length.get(L)
            if e is None:
                e = plant.quick_entry(u_m, L, armed, guard)
                if e is not None:
                    by_length[L] = e
            if e is not None:
                p0, p1, p2, p3, p4, p5, p6, p7, p8, q0, q1, q2, lo, hi, sl, k0, k1, k2, k3 = e
                I, w, dl = x
                Ie = p0 * I + p1 * w + p2 * dl + q0
                we = p3 * I + p4 * w + p5 * dl + q1
                de = p6 * I + p7 * w + p8 * dl + q2
                if regime[1] == 0:
                    net = plant.Kt * Ie - plant.spring_torque(dl)
                    ok = -plant.Tc <= net <= plant.Tc
                else:
                    ok = lo <= de <= hi and ((w > 0.0) == (we > 0.0) or (lo == -math.inf and hi == math.inf))
                    if ok and sl:
                        ok = sl * we >= 0.0 and not (
                            sl * (k0 * I + k1 * w + k2 * dl + k3) < 0.0 < sl * (k0 * Ie + k1 * we + k2 * de + k3))
                if ok:
                    x, tk = (Ie, we, de), stop
                    if stop == t_next:
                        break
                    continue
            x, tk, hit = plant.advance(x, tk, stop, u_m, armed, guard)
            if hit:
                # the continuous controller reverses the instant theta reaches the guard
                d = armed = controller.reverse_at(tk)
            elif stop == t_next:
                break
    return np.array(out), np.array(dirs, dtype=np.int8)
