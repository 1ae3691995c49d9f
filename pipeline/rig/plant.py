"""The reference plant: the hybrid model integrated independently of the fast simulator.

The fast simulator (``pipeline.model.simulate``) advances each mode with a
matrix exponential; this module integrates the same physics (docs/MODEL.md)
with scipy's ``solve_ivp`` (DOP853, tight tolerances) and locates every
non-smooth instant with events, so the two can be compared without either
being the other's oracle:

* velocity zero crossings (the true turning points, with theta there);
* Coulomb friction with a real stick mode: at w = 0 the pinion sticks while
  |Kt*I - Ks*dz(theta)| <= Tc and slips again when that torque exceeds Tc;
* backlash: the spring torque Ks*dz(theta), dz a dead zone of total width
  ``gap`` centred on 0; each edge crossing restarts the integrator;
* the sampled controller (zero-order hold, ``next_dir`` at each sample
  instant, uneven spacing allowed) or the exact continuous guard;
* loop delay: a command decided at t_k reaches the motor at t_k + Td.  Before
  the first decision has arrived the motor is off (the sketch has not driven it).

Between two instants at which something can change the input is constant and
the integrator runs with dense output; sample values come from it.  Segments
end early only where a decision may flip (the guard is reached, or the angle is
already beyond the guard so the next sample may flip), so a 500-sample run is a
few dozen solver calls, not 500.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from pipeline.model.effects import PlantSpec
from pipeline.model.simulate import SimResult, next_dir, sample_times

_EPS_T = 1e-12          # s   instants closer than this are the same instant


@dataclass(frozen=True)
class TurningPoint:
    """An instant where the pinion velocity reaches zero (a reversal or a stop)."""

    t: float            # s    plant time
    theta: float        # rad  true pinion angle there
    kind: str           # "reversal" (w changes sign) or "stick" (Coulomb friction holds it)


@dataclass(frozen=True)
class ReferenceRun:
    """A reference integration: the sampled result plus what only the plant knows."""

    result: SimResult
    turning_points: tuple[TurningPoint, ...]
    final_state: np.ndarray            # [I, w, delta] at t[-1] (same as the last row)
    n_segments: int                    # solver calls made (a cost figure for benchmarks)
    stuck: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # per sample: in stick mode


def dead_zone(theta: float, gap: float) -> float:
    """dz(theta): the angle the springs see through a play of total width gap centred on 0."""
    half = 0.5 * gap
    if theta > half:
        return theta - half
    if theta < -half:
        return theta + half
    return 0.0


class _Plant:
    """The right-hand side of eqs. (2), (4)/(8), (5) with the non-smooth terms held fixed.

    ``slip`` is the sign used for Coulomb friction (0 = stick mode), ``region``
    the backlash side (-1, 0, +1): inside one segment both are constants, so
    the integrand is smooth and the events mark where they change.
    """

    def __init__(self, spec: PlantSpec) -> None:
        p = spec.params
        self.La, self.Ra, self.Ke, self.Kt = p.La, p.Ra, p.Ke, p.Kt
        self.J, self.b, self.R = p.J, p.b, p.R
        self.Ks = p.R * p.R * (p.K1 + p.K2)          # N m/rad: R*(K1+K2)*delta = Ks*theta (eq. 4)
        self.Tc, self.half_gap = spec.Tc, 0.5 * spec.gap
        self.tau = spec.torque                        # N m  constant external torque (towards +theta)

    def spring_torque(self, theta: float, region: int) -> float:
        if self.half_gap == 0.0:
            return self.Ks * theta
        return 0.0 if region == 0 else self.Ks * (theta - region * self.half_gap)

    def region_of(self, theta: float, moving: float) -> int:
        if self.half_gap == 0.0:
            return 0
        if theta > self.half_gap or (theta == self.half_gap and moving > 0):
            return 1
        if theta < -self.half_gap or (theta == -self.half_gap and moving < 0):
            return -1
        return 0

    def net_torque(self, x: np.ndarray, region: int) -> float:
        """Kt*I - Ks*dz(theta) + tau: what Coulomb friction has to hold at w = 0."""
        return self.Kt * x[0] - self.spring_torque(x[2] / self.R, region) + self.tau

    def rhs(self, u: float, slip: int, region: int):
        La, Ra, Ke, Kt, J, b, R = self.La, self.Ra, self.Ke, self.Kt, self.J, self.b, self.R
        if slip == 0 and self.Tc > 0.0:
            def stuck(t: float, x: np.ndarray) -> list[float]:
                return [(u - Ra * x[0]) / La, 0.0, 0.0]     # w = 0: no back-EMF, no motion
            return stuck
        coulomb = self.Tc * slip
        Ks, hg, tau = self.Ks, self.half_gap, self.tau
        if hg == 0.0:
            def f(t: float, x: np.ndarray) -> list[float]:
                I, w, d = x
                return [(u - Ra * I - Ke * w) / La,                          # (2)
                        (Kt * I - b * w - Ks * d / R - coulomb + tau) / J,   # (4), (8) + Coulomb, torque
                        R * w]                                               # (5)
            return f
        off = region * hg
        k = 0.0 if region == 0 else Ks

        def g(t: float, x: np.ndarray) -> list[float]:
            I, w, d = x
            return [(u - Ra * I - Ke * w) / La,
                    (Kt * I - b * w - k * (d / R - off) - coulomb + tau) / J,  # springs on dz(theta)
                    R * w]
        return g


def _event(fn, direction: float, terminal: bool):
    fn.terminal = terminal
    fn.direction = direction
    return fn


def run_reference(spec: PlantSpec, t: np.ndarray | None = None, *,
                  x0: tuple[float, float, float] = (0.0, 0.0, 0.0), dir0: int = 1,
                  dir_log: np.ndarray | None = None, closed_loop: bool = True, guard: str = "sampled",
                  rtol: float = 1e-10, atol: float = 1e-12, theta_ref: float = 0.0) -> ReferenceRun:
    """Integrate the plant under the sketch's controller; see ``simulate_reference``.

    ``theta_ref`` is the angle the encoder counter reads as zero (a board that
    restarted away from the spring centre): the controller sees theta - theta_ref.
    """
    if guard not in ("sampled", "continuous"):
        raise ValueError(f"guard must be 'sampled' or 'continuous', got {guard!r}")
    t = sample_times(24.95, spec.period_s) if t is None else np.asarray(t, dtype=float)
    n = len(t)
    if n == 0:
        raise ValueError("no sample instants")
    if np.any(np.diff(t) <= 0):
        raise ValueError("sample instants must be strictly increasing")
    if dir_log is not None:
        dir_log = np.asarray(dir_log).astype(int)
        if len(dir_log) != n:
            raise ValueError(f"dir_log has {len(dir_log)} entries for {n} sample instants")
    if not closed_loop and dir_log is None:
        raise ValueError("replay (closed_loop=False) needs dir_log")

    plant = _Plant(spec)
    R, g_rad, Td, V = spec.params.R, spec.guard_rad, spec.Td, spec.v_drive

    # which samples the controller decides itself, and which are forced by dir_log
    if closed_loop and dir_log is not None:
        nz = np.flatnonzero(dir_log != 0)
        start = int(nz[0]) if len(nz) else n
    else:
        start = 0
    forced = np.zeros(n, dtype=bool)
    if not closed_loop:
        forced[:] = True
    elif dir_log is not None:
        forced[: min(start + 1, n)] = True          # leading motor-off samples, then the first command
    change_idx = [k for k in range(n) if forced[k] and (k == 0 or dir_log[k] != dir_log[k - 1])]

    x = np.array(x0, dtype=float)
    t_now = float(t[0])
    region = plant.region_of(x[2] / R, x[1])
    slip = _initial_slip(plant, x, region)
    X = np.empty((n, 3))
    dirs = np.zeros(n, dtype=np.int8)
    stuck = np.zeros(n, dtype=bool)
    d = int(dir0) if (closed_loop and dir_log is None) else 0   # the controller's last decision
    applied = 0                                                  # the command the motor currently sees
    pending: list[tuple[float, int]] = []                        # (instant it reaches the motor, command)
    turns: list[TurningPoint] = []
    k = 0
    segments = 0
    at_guard = False                                             # a sampled-guard event just ended a segment

    def decide(k: int, theta: float, d: int) -> int:
        if forced[k]:
            return int(dir_log[k])
        if guard == "continuous":
            return d if d != 0 else next_dir(d, theta, g_rad)
        return next_dir(d, theta, g_rad)

    def commit(k: int, xk: np.ndarray, d_new: int, d_old: int) -> None:
        X[k] = xk
        dirs[k] = d_new
        stuck[k] = spec.Tc > 0.0 and slip == 0
        if d_new != d_old or k == 0:
            _schedule(pending, t[k] + Td, d_new)

    while True:
        # 1. samples at this instant: record, decide
        while k < n and t[k] <= t_now + _EPS_T:
            d_new = decide(k, x[2] / R - theta_ref, d)
            commit(k, x.copy(), d_new, d)
            d = d_new
            k += 1
        # 2. commands that reach the motor now
        while pending and pending[0][0] <= t_now + _EPS_T:
            applied = pending.pop(0)[1]
        if k >= n:
            break
        # 3. integrate to the next instant where the input or a decision can change
        t_stop = float(t[-1])
        if pending:
            t_stop = min(t_stop, pending[0][0])
        nxt = bisect.bisect_left(change_idx, k)
        if nxt < len(change_idx):
            t_stop = min(t_stop, float(t[change_idx[nxt]]))
        # at the guard (or beyond it) a sampled controller may flip at the very next sample
        armed = (not forced[k] and guard == "sampled"
                 and (at_guard or d * (x[2] / R - theta_ref) >= g_rad))
        if armed:
            t_stop = min(t_stop, float(t[k]))
        events, kinds = _events(plant, slip, region, d, forced[k] or armed, guard, g_rad, theta_ref, R)
        at_guard = False
        sol = solve_ivp(plant.rhs(applied * V, slip, region), (t_now, t_stop), x, method="DOP853",
                        rtol=rtol, atol=atol, dense_output=True, events=events or None)
        segments += 1
        if segments > 100 * n + 10_000:          # events chattering without progress: a bug, not a result
            raise RuntimeError(f"reference plant stalled at t = {t_now:.6f} s after {segments} segments")
        t_end = float(sol.t[-1])
        x_end = sol.y[:, -1].copy()
        hit = None
        if sol.status == 1:
            for i, kind in enumerate(kinds):
                if kind != "reversal" and len(sol.t_events[i]):
                    hit = kind
                    x_end = sol.y_events[i][-1].copy()
                    t_end = float(sol.t_events[i][-1])
                    break
        for i, kind in enumerate(kinds):                 # non-terminal: reversals without Coulomb friction
            if kind == "reversal":
                for te, ye in zip(sol.t_events[i], sol.y_events[i]):
                    if te > t_now + _EPS_T:
                        turns.append(TurningPoint(float(te), float(ye[2] / R), "reversal"))
        # 4. samples strictly inside the segment: from the dense output; a flip there truncates
        truncated = False
        inside = k + int(np.searchsorted(t[k:], t_end - _EPS_T))
        states = sol.sol(t[k:inside]).T if inside > k else None    # one vectorised dense-output call
        first = k
        while k < inside:
            xk = states[k - first]
            d_new = decide(k, xk[2] / R - theta_ref, d)
            if d_new != d and not forced[k]:
                t_end, x_end, hit, truncated = float(t[k]), xk, None, True
                break
            commit(k, xk, d_new, d)
            d = d_new
            k += 1
        t_now, x = t_end, x_end
        if truncated:
            continue
        # 5. the event that ended the segment changes the mode
        if hit == "stop":
            x[1] = 0.0
            F = plant.net_torque(x, region)
            if abs(F) <= spec.Tc:
                slip = 0
                turns.append(TurningPoint(t_now, float(x[2] / R), "stick"))
            else:
                turns.append(TurningPoint(t_now, float(x[2] / R), "reversal"))
                slip = 1 if F > 0 else -1
        elif hit == "unstick":
            slip = 1 if plant.net_torque(x, region) > 0 else -1
        elif hit in ("gap_up", "gap_down"):
            region += 1 if hit == "gap_up" else -1
        elif hit == "guard":
            at_guard = True
            if guard == "continuous":
                at_guard = False
                d = -d
                _schedule(pending, t_now + Td, d)
    res = SimResult(t=t, theta=X[:, 2] / R, omega=X[:, 1], current=X[:, 0],
                    current_measured=X[:, 0] + spec.I0, delta=X[:, 2], dir=dirs,
                    u=dirs.astype(float) * V)
    return ReferenceRun(result=res, turning_points=tuple(turns), final_state=X[-1].copy(),
                        n_segments=segments, stuck=stuck)


def _schedule(pending: list[tuple[float, int]], when: float, command: int) -> None:
    """Queue a command for the motor; a later decision overrides any queued for the same instant or later."""
    while pending and pending[-1][0] >= when - _EPS_T:
        pending.pop()
    pending.append((when, command))


def _initial_slip(plant: _Plant, x: np.ndarray, region: int) -> int:
    if plant.Tc == 0.0:
        return 1 if x[1] >= 0 else -1
    if x[1] != 0.0:
        return 1 if x[1] > 0 else -1
    F = plant.net_torque(x, region)
    if abs(F) <= plant.Tc:
        return 0
    return 1 if F > 0 else -1


def _events(plant: _Plant, slip: int, region: int, d: int, forced: bool, guard: str,
            g_rad: float, theta_ref: float, R: float) -> tuple[list, list[str]]:
    events: list = []
    kinds: list[str] = []
    coulomb = plant.Tc > 0.0
    if coulomb and slip == 0:
        events.append(_event(lambda t, x: plant.Tc - plant.net_torque(x, region), -1, True))
        kinds.append("unstick")
        events.append(_event(lambda t, x: plant.Tc + plant.net_torque(x, region), -1, True))
        kinds.append("unstick")
    elif coulomb:
        events.append(_event(lambda t, x, s=slip: s * x[1], -1, True))
        kinds.append("stop")
    else:
        events.append(_event(lambda t, x: x[1], 0, False))
        kinds.append("reversal")
    if plant.half_gap > 0.0 and not (coulomb and slip == 0):
        hg = plant.half_gap
        if region <= 0:
            edge = hg if region == 0 else -hg
            events.append(_event(lambda t, x, e=edge: x[2] / R - e, 1, True))
            kinds.append("gap_up")
        if region >= 0:
            edge = -hg if region == 0 else hg
            events.append(_event(lambda t, x, e=edge: x[2] / R - e, -1, True))
            kinds.append("gap_down")
    if not forced and d != 0:
        # sampled: the first instant a flip becomes possible; continuous: the switch itself
        events.append(_event(lambda t, x, s=d: s * (x[2] / R - theta_ref) - g_rad, 1, True))
        kinds.append("guard")
    return events, kinds


def simulate_reference(spec: PlantSpec, t: np.ndarray | None = None, *,
                       x0: tuple[float, float, float] = (0.0, 0.0, 0.0), dir0: int = 1,
                       dir_log: np.ndarray | None = None, closed_loop: bool = True,
                       guard: str = "sampled", rtol: float = 1e-10, atol: float = 1e-12) -> SimResult:
    """The reference plant with the fast simulator's signature and result.

    closed_loop=True: the sketch's sampled guard (``next_dir`` at each instant
    of ``t``) decides, starting in mode ``dir0``; the leading ``dir == 0``
    samples of ``dir_log`` keep the motor off and the controller starts in the
    mode of its first non-zero entry.  closed_loop=False replays ``dir_log``.
    guard="continuous" switches exactly when the angle reaches the guard.
    """
    return run_reference(spec, t, x0=x0, dir0=dir0, dir_log=dir_log, closed_loop=closed_loop,
                         guard=guard, rtol=rtol, atol=atol).result
