"""Derive stage: speed, and the accuracy figures the issue asks for.

Speed baseline measured in the same run: the obvious Savitzky-Golay on an
uneven time axis, one ``np.polyfit`` per sample, against the batched normal
equations of ``pipeline.derive.velocity``; and the whole stage
(``derive_tables``) on the paper's 24.95 s run and on one hour of samples.
Accuracy on virtual-rig recordings: RMS velocity error per estimator, turning
points against the truth, energies against the same formulas on the true samples.
Run: python -m benchmarks.bench_derive
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from benchmarks.bench_rig import best_of
from pipeline.config import default_config
from pipeline.derive.energy import energy_terms
from pipeline.derive.stage import derive_tables
from pipeline.derive.velocity import SAVGOL_ORDER, SAVGOL_WINDOW, backward_difference, savgol_velocity
from pipeline.model.simulate import simulate
from pipeline.rig.recording import RigSetup
from tests.derive.rigdata import rig_run

COUNT = 2 * math.pi / 6533.12


def polyfit_per_sample(t: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Baseline: the same local cubic, one np.polyfit call per sample."""
    n, w = len(t), SAVGOL_WINDOW
    out = np.empty(n)
    for k in range(n):
        a = min(max(k - w // 2, 0), n - w)
        out[k] = np.polyfit(t[a:a + w] - t[k], theta[a:a + w], SAVGOL_ORDER)[-2]
    return out


def signals_for(duration: float) -> pd.DataFrame:
    spec = default_config().plant_spec()
    r = simulate(spec, duration=duration)
    counts = np.round(r.theta / COUNT)
    return pd.DataFrame({"t_s": r.t, "theta_rad": counts * COUNT, "current_a": r.current, "dir": r.dir})


def speed() -> None:
    cfg = default_config()
    for label, duration in (("24.95 s (500 samples)", 24.95), ("1 h (72001 samples)", 3600.0)):
        sig = signals_for(duration)
        t, th = sig["t_s"].to_numpy(), sig["theta_rad"].to_numpy()
        base = best_of(lambda: polyfit_per_sample(t, th), repeat=1 if duration > 100 else 3)
        fast = best_of(lambda: savgol_velocity(t, th))
        stage = best_of(lambda: derive_tables(sig, cfg), repeat=1 if duration > 100 else 3)
        print(f"{label}: savgol batched {fast * 1e3:.1f} ms vs polyfit per sample {base * 1e3:.1f} ms "
              f"(x{base / fast:.0f}); whole derive_tables {stage * 1e3:.1f} ms "
              f"({len(sig) / stage / 1e3:.0f} k samples/s)")


def accuracy(seeds=range(6)) -> None:
    rms = {"backward": [], "savgol": []}
    turn_dt, turn_dth, energy = [], [], {"noise": [], "no noise": []}
    for seed in seeds:
        for label, setup in (("noise", RigSetup()), ("no noise", RigSetup(noise_v=0.0))):
            sig, cfg, rec = rig_run(setup, seed=seed)
            tr = rec.truth
            d = derive_tables(sig, cfg)
            spec = cfg.plant_spec()
            want = energy_terms(tr["t_s"].to_numpy(), tr["current_a"].to_numpy(), tr["omega_rad_s"].to_numpy(),
                                tr["theta_rad"].to_numpy(), tr["dir"].to_numpy() * spec.v_drive, spec,
                                spec.v_drive, spec.period_s)
            energy[label].append([d.summary["energy"][k] / want[k] - 1
                                  for k in ("energy_paper_j", "input_energy_j", "copper_loss_j", "friction_loss_j")])
            if label != "noise":
                continue
            t, th, w = sig["t_s"].to_numpy(), sig["theta_rad"].to_numpy(), tr["omega_rad_s"].to_numpy()
            rms["backward"].append(np.sqrt(np.mean((backward_difference(t, th) - w) ** 2)))
            rms["savgol"].append(np.sqrt(np.mean((savgol_velocity(t, th) - w) ** 2)))
            tp = pd.DataFrame(rec.truth_meta["turning_points"])
            tp = tp[tp["theta_rad"].abs() > 0.5]
            for _, row in d.overshoot[d.overshoot["turned"]].iterrows():
                j = int(np.argmin(np.abs(tp["t_s"].to_numpy() - row["turn_t_s"])))
                turn_dt.append(row["turn_t_s"] - tp["t_s"].to_numpy()[j])
                turn_dth.append((row["turn_theta_rad"] - tp["theta_rad"].to_numpy()[j]) / COUNT)
    print(f"velocity RMS error vs truth ({len(rms['savgol'])} rig runs): backward {np.mean(rms['backward']):.4f} rad/s, "
          f"savgol {np.mean(rms['savgol']):.4f} rad/s (x{np.mean(rms['backward']) / np.mean(rms['savgol']):.0f} lower)")
    print(f"turning points ({len(turn_dt)}): max |dt| {np.max(np.abs(turn_dt)) * 1e3:.1f} ms, "
          f"max |dtheta| {np.max(np.abs(turn_dth)):.2f} counts")
    for label, errs in energy.items():
        e = np.array(errs) * 100
        print(f"energy error vs truth, {label} [%] (paper, input, copper, friction): "
              f"mean {np.round(e.mean(0), 2).tolist()}, max |.| {np.round(np.abs(e).max(0), 2).tolist()}")


def main() -> None:
    speed()
    accuracy()


if __name__ == "__main__":
    main()
