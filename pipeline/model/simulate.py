"""Hybrid automaton simulator (shared/MODEL.md): sampled bang-bang guard, ZOH input.

FIRST CUT (linear plant only, sampled guard).  The model helper extends this file
with the non-smooth effects, the continuous-guard variant and the batch API; the
public signature of ``simulate`` and the fields of ``SimResult`` are the contract
other stages code against.

Within a mode the plant is linear, x' = A x + B u (eqs. 2, 4/8, 5), so between
two samples it is advanced exactly with the matrix exponential of the augmented
system [[A, B u], [0, 0]] -- no ODE solver stepping blindly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from pipeline.model.effects import PlantSpec


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


def sample_times(duration: float, period: float) -> np.ndarray:
    """Nominal sample instants 0, T, 2T, ... up to ``duration`` (24.95 s at 50 ms: 500 samples)."""
    n = int(np.floor(duration / period + 1e-9)) + 1
    return np.arange(n) * period


def next_dir(current_dir: int, theta: float, guard: float) -> int:
    """The sketch's rule: reverse when the angle has reached the guard in the direction of motion."""
    if current_dir >= 0 and theta >= guard:
        return -1
    if current_dir <= 0 and theta <= -guard:
        return 1
    return current_dir if current_dir != 0 else 1


def _step_matrices(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    M = np.zeros((4, 4))
    M[:3, :3] = A * h
    M[:3, 3] = B * h
    E = expm(M)
    return E[:3, :3], E[:3, 3]


def simulate(spec: PlantSpec, t: np.ndarray | None = None, *, duration: float = 24.95,
             x0: tuple[float, float, float] = (0.0, 0.0, 0.0), dir0: int = 1,
             dir_log: np.ndarray | None = None, closed_loop: bool = True) -> SimResult:
    """Run the automaton at sample instants ``t`` (uneven spacing allowed).

    closed_loop=True: the simulator's own sampled guard decides the switches,
    starting in mode ``dir0`` (if ``dir_log`` is given, its leading zeros --
    motor off before the sketch starts -- are honoured and the controller
    starts in the mode of its first non-zero entry).
    closed_loop=False (replay): ``dir_log`` drives the motor sample by sample.
    """
    if not spec.is_linear or spec.Td:
        raise ValueError("first-cut simulator: linear plant without loop delay only")
    t = sample_times(duration, spec.period_s) if t is None else np.asarray(t, dtype=float)
    n = len(t)
    A, B = spec.params.state_matrices()
    cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    x = np.array(x0, dtype=float)
    X = np.empty((n, 3))
    dirs = np.zeros(n, dtype=np.int8)
    if dir_log is not None:
        dir_log = np.asarray(dir_log)
        nz = np.flatnonzero(dir_log != 0)
        start = int(nz[0]) if len(nz) else n
        d = int(dir_log[start]) if len(nz) else 0
    else:
        start, d = 0, dir0
    guard = spec.guard_rad
    for k in range(n):
        X[k] = x
        if not closed_loop:
            d = int(dir_log[k])
        elif k < start:
            d = int(dir_log[k])
        elif k > start or dir_log is None:
            d = next_dir(d, x[2] / spec.params.R, guard)
        dirs[k] = d
        if k + 1 < n:
            h = float(t[k + 1] - t[k])
            key = round(h, 9)
            if key not in cache:
                cache[key] = _step_matrices(A, B, h)
            Ad, Bd = cache[key]
            x = Ad @ x + Bd * (d * spec.v_drive)
    return SimResult(t=t, theta=X[:, 2] / spec.params.R, omega=X[:, 1], current=X[:, 0],
                     current_measured=X[:, 0] + spec.I0, delta=X[:, 2], dir=dirs,
                     u=dirs.astype(float) * spec.v_drive)


def paper_energy(t: np.ndarray, current: np.ndarray, v_rms: float = 6.0, period: float | None = None) -> float:
    """The paper's estimate (Sec. IV-C): V_RMS * T_s * sum_k |y[k-1] + y[k]| / 2."""
    ts = period if period is not None else float(np.median(np.diff(t)))
    y = np.asarray(current)
    return float(v_rms * ts * np.sum(np.abs(y[:-1] + y[1:]) / 2.0))
