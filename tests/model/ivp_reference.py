"""The baseline the fast simulator is checked and benchmarked against: scipy ``solve_ivp``, one call per
control period (split where a delayed command reaches the motor), tight tolerances, the same sampled
controller (``next_dir``).  Linear plant only; the non-smooth effects are checked against the rig's
independent reference plant (``pipeline.rig.plant.simulate_reference``).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from pipeline.model.effects import PlantSpec
from pipeline.model.simulate import SimResult, next_dir


def simulate_ivp(spec: PlantSpec, t: np.ndarray, *, x0=(0.0, 0.0, 0.0), dir0: int = 1,
                 dir_log: np.ndarray | None = None, closed_loop: bool = True,
                 rtol: float = 1e-10, atol: float = 1e-12) -> SimResult:
    assert spec.is_linear, "the per-period solve_ivp baseline covers the linear plant"
    A, B = spec.params.state_matrices()
    R, V, Td, guard = spec.params.R, spec.v_drive, spec.Td, spec.guard_rad
    t = np.asarray(t, dtype=float)
    n = len(t)
    start, first = 0, 0
    if dir_log is not None:
        nz = np.flatnonzero(np.asarray(dir_log) != 0)
        start = int(nz[0]) if len(nz) else n
        first = int(dir_log[start]) if len(nz) else 0
    x = np.array(x0, dtype=float)
    X = np.empty((n, 3))
    dirs = np.zeros(n, dtype=np.int8)
    d = 0
    changes: list[tuple[float, float]] = []       # (instant the motor sees it, voltage)
    motor = 0.0

    def rhs(_t, y, u):
        return A @ y + B * u

    for k in range(n):
        X[k] = x
        if not closed_loop or k < start:
            new = int(dir_log[k])
        elif k == start:
            new = first if first else next_dir(dir0, x[2] / R, guard)
        else:
            new = next_dir(d, x[2] / R, guard)
        if new != d or k == 0:
            changes.append((t[k] + Td, new * V))
        d = new
        dirs[k] = d
        if k + 1 == n:
            break
        a = t[k]
        while True:
            while changes and changes[0][0] <= a + 1e-12:
                motor = changes.pop(0)[1]
            b = changes[0][0] if changes and changes[0][0] < t[k + 1] - 1e-12 else t[k + 1]
            sol = solve_ivp(rhs, (a, b), x, method="DOP853", rtol=rtol, atol=atol, args=(motor,))
            x = sol.y[:, -1]
            if b == t[k + 1]:
                break
            a = b
    return SimResult(t=t, theta=X[:, 2] / R, omega=X[:, 1], current=X[:, 0], current_measured=X[:, 0] + spec.I0,
                     delta=X[:, 2], dir=dirs, u=dirs.astype(float) * V)


def jittered_times(n: int = 500, seed: int = 0) -> np.ndarray:
    """millis()-like instants: 50 or 51 ms apart, as the Arduino logs them."""
    rng = np.random.default_rng(seed)
    steps = rng.choice([0.050, 0.051], n - 1)
    return np.concatenate([[0.0], np.cumsum(steps)])
