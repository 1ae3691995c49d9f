"""Synthetic recordings with known truth, from the fast simulator (until/besides the virtual rig).

Sample instants jitter like millis(); the angle is quantised to encoder counts and
the current goes through the ACS712 + 10-bit ADC with sensor noise, as MODEL.md
describes.  The truth (angle, velocity, current, command at the samples, and the
turning points of a 1 ms replay of the same commands) comes with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.config import RigConfig, default_config
from pipeline.model.effects import PlantSpec
from pipeline.model.simulate import simulate


@dataclass(frozen=True)
class Synthetic:
    signals: pd.DataFrame          # what ingest would write (schemas/signals.json)
    truth: pd.DataFrame            # t_s, theta_rad, omega_rad_s, current_a, dir at the samples
    turns: pd.DataFrame            # t_s, theta_rad of each true turning point after a guard crossing
    spec: PlantSpec
    cfg: RigConfig


def make_synthetic(duration: float = 24.95, seed: int = 0, *, cfg: RigConfig | None = None,
                   jitter_ms: int = 2, noise_v: float = 0.005, log_dir: bool = True,
                   log_current: bool = True, spec: PlantSpec | None = None) -> Synthetic:
    cfg = cfg or default_config()
    spec = spec or cfg.plant_spec()
    rng = np.random.default_rng(seed)
    n = int(round(duration / spec.period_s)) + 1
    t_ms = np.arange(n) * int(round(spec.period_s * 1000)) + rng.integers(0, jitter_ms + 1, n)
    t_ms[0] = 0
    t = t_ms / 1000.0
    # millis() truncates: the true instant lies up to 1 ms after the logged one
    t_true = t + rng.uniform(0.0, 0.001, n) * (jitter_ms > 0)
    cpr = cfg.encoder.counts_per_rev
    r = simulate(spec, t_true)
    for _ in range(50):
        # the sketch decides on counts, not on the true angle: replay until its decisions are self-consistent
        # (each pass fixes at least the earliest decision that differed)
        counts = np.round(r.theta * cpr / (2 * np.pi)).astype(np.int64)
        decided = sketch_decisions(2 * np.pi * counts / cpr, spec.guard_rad)
        if np.array_equal(decided, r.dir):
            break
        r = simulate(spec, t_true, dir_log=decided, closed_loop=False)
    else:
        raise RuntimeError("synthetic recording: the sketch's decisions did not settle")
    cs = cfg.current_sensor
    v = cs.zero_v + cs.sensitivity_v_per_a * r.current_measured + rng.normal(0.0, noise_v, n)
    adc = np.clip(np.round(v / cs.adc_vref * cs.adc_steps), 0, cs.adc_steps - 1).astype(np.int32)
    current_v = adc * cs.adc_vref / cs.adc_steps
    sig = {
        "t_s": t, "t_raw": t_ms.astype(np.int64), "line": np.arange(n, dtype=np.int64) + 2,
        "segment": np.zeros(n, dtype=np.int32), "counts": counts,
        "theta_rad": 2 * np.pi * counts / cpr,
    }
    if log_current:
        sig |= {"adc": adc, "current_v": current_v, "current_a": (current_v - cs.zero_v) / cs.sensitivity_v_per_a}
    if log_dir:
        sig |= {"dir": r.dir.astype(np.int8), "mode": np.where(r.dir == 1, 1, np.where(r.dir == -1, 2, 0)).astype(np.int8)}
    truth = pd.DataFrame({"t_s": t_true, "theta_rad": r.theta, "omega_rad_s": r.omega,
                          "current_a": r.current, "dir": r.dir})
    return Synthetic(pd.DataFrame(sig), truth, true_turns(spec, t_true, r.dir), spec, cfg)


def sketch_decisions(theta: np.ndarray, guard: float) -> np.ndarray:
    """The Arduino's rule written out independently of the code under test: start in q1, reverse past a guard."""
    out = np.empty(len(theta), dtype=np.int8)
    d = 1
    for k, th in enumerate(theta):
        if d == 1 and th >= guard:
            d = -1
        elif d == -1 and th <= -guard:
            d = 1
        out[k] = d
    return out


def true_turns(spec: PlantSpec, t: np.ndarray, dirs: np.ndarray) -> pd.DataFrame:
    """Turning points of a 1 ms replay of the logged commands: one per reversal of the command."""
    fine = np.union1d(np.arange(0.0, t[-1], 0.001), t)
    held = dirs[np.searchsorted(t, fine, side="right") - 1]
    r = simulate(spec, fine, dir_log=held, closed_loop=False)
    switch = np.flatnonzero((dirs[1:] != dirs[:-1]) & (dirs[:-1] != 0)) + 1
    rows = []
    for j, k in enumerate(switch):
        end = t[switch[j + 1]] if j + 1 < len(switch) else t[-1]
        sel = (fine >= t[k]) & (fine <= end)
        d = int(dirs[k - 1])
        i = np.flatnonzero(sel)[np.argmax(d * r.theta[sel])]
        rows.append({"t_s": fine[i], "theta_rad": r.theta[i], "direction": d})
    return pd.DataFrame(rows, columns=["t_s", "theta_rad", "direction"])
