"""Synthetic kinematics tables made with the fast simulator and the rig's sensor chain.

Used where a test needs a measured table with known truth without going
through the raw CSV (the end-to-end tests use the virtual rig instead).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.config import default_config
from pipeline.model.simulate import sample_times, simulate

COUNTS_PER_REV = 6533.12
AMPS_PER_STEP = 5.0 / 1024 / 0.185     # one ADC step of an ACS712-05B on a 5 V, 10-bit UNO: 26.4 mA


def synthetic_kinematics(spec=None, *, duration: float = 24.95, quantise: bool = True,
                         current_noise_a: float = 0.0, seed: int = 0, current: bool = True) -> pd.DataFrame:
    """A derive-stage kinematics table of a closed-loop run of ``spec`` seen through the sensors."""
    spec = spec if spec is not None else default_config().plant_spec()
    t = sample_times(duration, spec.period_s)
    sim = simulate(spec, t)
    rng = np.random.default_rng(seed)
    theta = sim.theta
    if quantise:
        theta = np.round(theta * COUNTS_PER_REV / (2 * np.pi)) * 2 * np.pi / COUNTS_PER_REV
    omega = np.concatenate([[0.0], np.diff(theta) / np.diff(t)])
    df = pd.DataFrame({"t_s": t, "theta_rad": theta, "omega_rad_s": omega})
    if current:
        i = sim.current_measured + current_noise_a * rng.standard_normal(len(t))
        df["current_a"] = np.round(i / AMPS_PER_STEP) * AMPS_PER_STEP if quantise else i
    df["dir"] = sim.dir.astype(np.int8)
    df["dir_inferred"] = False
    return df


def synthetic_run(processed, name: str = "synth", kin: pd.DataFrame | None = None, cfg=None):
    """A processed run folder as ingest + derive leave it (rig.json + kinematics.parquet)."""
    from pipeline.io.atomic import write_json
    from pipeline.runs import run_paths

    cfg = cfg if cfg is not None else default_config()
    paths = run_paths(processed, name)
    paths.root.mkdir(parents=True, exist_ok=True)
    kin = kin if kin is not None else synthetic_kinematics(cfg.plant_spec(), current_noise_a=0.02)
    kin.to_parquet(paths.kinematics)
    write_json(paths.rig_config, {"config": cfg.to_dict(), "sources": {}})
    return paths
