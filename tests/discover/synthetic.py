"""Development recordings for discovery tests: the model simulator, closed loop, plus the rig's
sensor chain (integer encoder counts, 10-bit ADC of an ACS712 with noise, millis() jitter).

Used where a whole virtual-rig recording would only add time; the end-to-end tests use
``pipeline.rig`` through ingest and derive.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.config import RigConfig, default_config
from pipeline.model.effects import Effect
from pipeline.model.simulate import simulate


def synthetic_kinematics(effects: tuple[Effect, ...] = (), *, seed: int = 0, current_noise_a: float = 0.02,
                         config: RigConfig | None = None, duration: float = 24.95,
                         plant=None) -> tuple[pd.DataFrame, RigConfig]:
    """A kinematics table (derive layout) of a rig that has ``effects`` on top of ``config``'s model.

    ``plant``, when given, replaces the simulator (for effects outside the catalogue).
    """
    cfg = config if config is not None else default_config()
    rng = np.random.default_rng(seed)
    n = int(round(duration / cfg.controller.period_s)) + 1
    t_true = np.cumsum(np.concatenate([[0.0], cfg.controller.period_s + rng.uniform(0, 0.0015, n - 1)]))
    spec = cfg.plant_spec(tuple(effects))
    sim = (plant or simulate)(spec, t_true)
    counts = np.round(sim.theta / (2 * np.pi) * cfg.encoder.counts_per_rev)
    theta = 2 * np.pi * counts / cfg.encoder.counts_per_rev
    cs = cfg.current_sensor
    v = 2.5 + cs.sensitivity_v_per_a * (sim.current_measured + rng.normal(0, current_noise_a, n))
    adc = np.clip(np.round(v / cs.adc_vref * cs.adc_steps), 0, cs.adc_steps - 1)
    current = (adc * cs.adc_vref / cs.adc_steps - 2.5) / cs.sensitivity_v_per_a
    t_ms = np.floor(t_true * 1000.0)
    t = (t_ms - t_ms[0]) / 1000.0
    omega = np.gradient(theta, t)
    kin = pd.DataFrame({"t_s": t, "theta_rad": theta, "omega_rad_s": omega, "current_a": current,
                        "dir": sim.dir.astype(np.int8), "dir_inferred": np.zeros(n, dtype=bool)})
    return kin, cfg


def constant_torque_plant(torque_nm: float):
    """A plant outside the catalogue: a constant torque on the pinion (unequal racks' weight),
    ``J dw/dt`` gains ``+torque_nm``; closed loop with the sketch's sampled guard."""
    from scipy.linalg import expm

    from pipeline.model.simulate import SimResult, next_dir

    def plant(spec, t):
        p = spec.params
        A, B = p.state_matrices()
        n = len(t)
        x = np.zeros(3)
        X = np.empty((n, 3))
        dirs = np.zeros(n, dtype=np.int8)
        d = 1
        for k in range(n):
            X[k] = x
            d = next_dir(d, x[2] / p.R, spec.guard_rad)
            dirs[k] = d
            if k + 1 < n:
                h = t[k + 1] - t[k]
                M = np.zeros((4, 4))
                M[:3, :3] = A * h
                M[:3, 3] = (B * d * spec.v_drive + np.array([0.0, torque_nm / p.J, 0.0])) * h
                x = expm(M)[:3, :] @ np.append(x, 1.0)
        return SimResult(t=t, theta=X[:, 2] / p.R, omega=X[:, 1], current=X[:, 0],
                         current_measured=X[:, 0] + spec.I0, delta=X[:, 2], dir=dirs,
                         u=dirs.astype(float) * spec.v_drive)

    return plant
