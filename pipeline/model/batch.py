"""Many parameter sets at once (what fitting needs): one recording's instants, one controller, m plants.

For linear plants (viscous friction, driver drop, rack inertia, spring scale,
loop delay and sensor offset -- everything but Coulomb friction and backlash)
the m closed loops advance together: per distinct step length one batched
matrix exponential (``linear.expm_batch`` on the stacked augmented matrices),
then per sample one stacked matrix-vector product and a vectorised ``next_dir``.
A delayed command that reaches the motor inside a step adds
``Gamma(h - a) * du`` for the sets concerned (same superposition as
``simulate``), so the batch equals m single calls to rounding.
Non-smooth specs (Tc, gap) or the continuous guard fall back to a loop of
``simulate`` calls.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pipeline.errors import PdrError
from pipeline.model.effects import PlantSpec
from pipeline.model.linear import KEY_DECIMALS, augmented_batch, step_key
from pipeline.model.simulate import TIME_EPS, SimResult, _plan, simulate


@dataclass(frozen=True)
class BatchResult:
    """Signals at the sample instants, one row per parameter set: arrays shaped (n_sets, n_samples)."""

    t: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    current: np.ndarray
    current_measured: np.ndarray
    delta: np.ndarray
    dir: np.ndarray
    u: np.ndarray

    def __len__(self) -> int:
        return self.theta.shape[0]

    def result(self, i: int) -> SimResult:
        """Set ``i`` as a ``SimResult`` (what ``simulate`` would have returned)."""
        return SimResult(t=self.t, theta=self.theta[i], omega=self.omega[i], current=self.current[i],
                         current_measured=self.current_measured[i], delta=self.delta[i], dir=self.dir[i],
                         u=self.u[i])


def simulate_batch(specs: Sequence[PlantSpec], t: np.ndarray | None = None, *, duration: float = 24.95,
                   x0: tuple[float, float, float] = (0.0, 0.0, 0.0), dir0: int = 1,
                   dir_log: np.ndarray | None = None, closed_loop: bool = True,
                   guard: str = "sampled") -> BatchResult:
    """``simulate`` for every spec at the same instants and controller settings (see ``simulate``)."""
    specs = list(specs)
    if not specs:
        raise PdrError("expected at least one parameter set", key="specs")
    plan = _plan(specs[0], t, duration, dir0, dir_log, closed_loop, guard)
    vectorised = all(s.is_linear for s in specs) and (guard == "sampled" or not closed_loop)
    if not vectorised:
        runs = [simulate(s, plan.t, x0=x0, dir0=dir0, dir_log=dir_log, closed_loop=closed_loop, guard=guard)
                for s in specs]
        return _stack(plan.t, runs)
    return _run_linear_batch(specs, plan, np.asarray(x0, dtype=float))


def _stack(t: np.ndarray, runs: list[SimResult]) -> BatchResult:
    return BatchResult(t=t, **{f: np.stack([getattr(r, f) for r in runs])
                               for f in ("theta", "omega", "current", "current_measured", "delta", "dir", "u")})


def _next_dir(d: np.ndarray, theta: np.ndarray, guard: np.ndarray) -> np.ndarray:
    """``simulate.next_dir`` for arrays."""
    down = (d >= 0) & (theta >= guard)
    up = (d <= 0) & (theta <= -guard)
    if not (down.any() or up.any() or (d == 0).any()):
        return d
    return np.where(down, -1, np.where(up, 1, np.where(d == 0, 1, d))).astype(np.int64)


def _run_linear_batch(specs: list[PlantSpec], plan, x0: np.ndarray) -> BatchResult:
    m = len(specs)
    t = plan.t
    n = len(t)
    AB = [s.params.state_matrices() for s in specs]
    A = np.stack([a for a, _ in AB])
    B = np.stack([b for _, b in AB])
    R = np.array([s.params.R for s in specs])
    guard = np.array([s.guard_rad for s in specs])
    V = np.array([s.v_drive for s in specs])
    Td = np.array([s.Td for s in specs])
    I0 = np.array([s.I0 for s in specs])
    delayed = bool(np.any(Td > 0.0))
    # per step length: Phi as (3, 3, m) and Gamma as (3, m), so a step is two whole-array operations
    cache: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    X = np.tile(x0[:, None], (1, m))              # (3, m): I, w, delta of every set
    out = np.empty((n, 3, m))
    dirs = np.zeros((n, m), dtype=np.int8)
    ucmd = np.zeros((n, m))                       # voltage commanded at each sample
    u_m = np.zeros(m)                             # voltage the motor sees (delayed path)
    applied = np.full(m, -1)                      # last command index that reached the motor
    d = np.zeros(m, dtype=np.int64)
    rows = np.arange(m)
    for k in range(n):
        out[k] = X
        if not plan.closed_loop or k < plan.start:
            d = np.full(m, int(plan.dir_log[k]), dtype=np.int64)
        elif k == plan.start:
            d = (np.full(m, plan.first, dtype=np.int64) if plan.first
                 else _next_dir(np.full(m, plan.dir0), X[2] / R, guard))
        else:
            d = _next_dir(d, X[2] / R, guard)
        dirs[k] = d
        ucmd[k] = d * V
        if k + 1 == n:
            break
        tk, t_next = t[k], t[k + 1]
        h = t_next - tk
        entry = cache.get(h)
        if entry is None:
            key = step_key(h)
            entry = cache.get(key)
            if entry is None:
                Phi, Gam = augmented_batch(A, B, key)
                entry = (np.ascontiguousarray(Phi.transpose(1, 2, 0)), np.ascontiguousarray(Gam.T), Gam)
                cache[key] = entry
            cache[h] = entry
        Phi_t, Gam_t, Gam = entry
        if not delayed:
            X = (Phi_t * X[None, :, :]).sum(axis=1) + Gam_t * ucmd[k]
            continue
        acc = Gam_t * u_m
        while True:
            j = np.minimum(applied + 1, k)
            at = t[j] + Td
            due = (applied + 1 <= k) & (at < t_next - TIME_EPS)
            if not due.any():
                break
            idx = rows[due]
            jj = j[idx]
            du = ucmd[jj, idx] - u_m[idx]
            changed = du != 0.0
            if changed.any():
                ii, a, dv = idx[changed], at[idx][changed] - tk, du[changed]
                G = Gam[ii].copy()
                inside = a > TIME_EPS
                if inside.any():
                    G[inside] = augmented_batch(A[ii[inside]], B[ii[inside]],
                                                np.round(h - a[inside], KEY_DECIMALS))[1]
                acc[:, ii] += (G * dv[:, None]).T
            u_m[idx] = ucmd[jj, idx]
            applied[idx] += 1
        X = (Phi_t * X[None, :, :]).sum(axis=1) + acc
    current = out[:, 0, :].T
    dirs_t = dirs.T
    return BatchResult(t=t, theta=(out[:, 2, :] / R).T, omega=out[:, 1, :].T, current=current,
                       current_measured=current + I0[:, None], delta=out[:, 2, :].T, dir=dirs_t,
                       u=dirs_t.astype(float) * V[:, None])
