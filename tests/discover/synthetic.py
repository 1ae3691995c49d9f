"""Recordings for the discovery tests and benchmark.

``rig_kinematics``: the virtual rig (its own reference plant), written as CSV + TOML,
ingested and derived exactly like a user's recording.

``cogging_kinematics``: an effect *outside* the catalogue, a cogging torque on the pinion
(``J dw/dt += Tq sin(2 pi theta / pitch)``), which the rig cannot produce: a small custom
plant integrated by ``solve_ivp`` between samples, seen through the rig's own sensor chain
(``pipeline.rig.sensors``) and derived by the derive stage.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from pipeline.config import RigConfig, default_config
from pipeline.derive.stage import derive_tables
from pipeline.model.effects import Effect
from pipeline.model.simulate import next_dir
from pipeline.rig import sensors


def rig_kinematics(effects: tuple[Effect, ...] = (), *, config: RigConfig | None = None, seed: int = 0,
                   work: Path | None = None, **setup) -> tuple[pd.DataFrame, RigConfig, Path]:
    """(kinematics, resolved rig config, raw CSV path) of a virtual-rig recording with hidden ``effects``."""
    from pipeline.derive.stage import derive_run
    from pipeline.ingest.stage import ingest_recording
    from pipeline.rig.recording import RigSetup, make_recording, write_recording
    from pipeline.runs import load_config

    work = Path(work) if work is not None else Path(tempfile.mkdtemp(prefix="pdr-discover-"))
    cfg = config if config is not None else default_config()
    rec = make_recording(RigSetup(effects=tuple(effects), config=cfg, **setup), seed=seed)
    write_recording(rec, work / "raw", "rec")
    paths = ingest_recording(work / "raw" / "rec.csv", work / "processed").runs[0]
    derive_run(paths)
    return pd.read_parquet(paths.kinematics), load_config(paths), work / "raw" / "rec.csv"


COGGING_PITCH_RAD = 0.1       # one cogging period per 0.1 rad of pinion angle


def cogging_kinematics(torque_nm: float, *, seed: int = 0, noise_v: float = 5.0 / 1024,
                       config: RigConfig | None = None, duration: float = 24.95) -> tuple[pd.DataFrame, RigConfig]:
    """A closed-loop run whose pinion feels ``J dw/dt += torque_nm sin(2 pi theta / pitch)`` (no catalogued effect)."""
    cfg = config if config is not None else default_config()
    spec = cfg.plant_spec()
    p = spec.params
    A, B = p.state_matrices()
    rng = np.random.default_rng(seed)
    n = int(round(duration / spec.period_s)) + 1
    true_ms, t_ms = sensors.loop_instants(n, spec.period_s, 0.6, rng, 0.0)
    t = true_ms / 1000.0
    x = np.zeros(3)
    X = np.empty((n, 3))
    dirs = np.zeros(n, dtype=np.int8)
    d = 1
    for k in range(n):
        X[k] = x
        d = next_dir(d, x[2] / p.R, spec.guard_rad)
        dirs[k] = d
        if k + 1 < n:
            u = d * spec.v_drive

            def rhs(_t, y, u=u):
                cog = torque_nm * np.sin(2.0 * np.pi * (y[2] / p.R) / COGGING_PITCH_RAD) / p.J
                return A @ y + B * u + np.array([0.0, cog, 0.0])
            x = solve_ivp(rhs, (t[k], t[k + 1]), x, method="DOP853", rtol=1e-9, atol=1e-12).y[:, -1]
    cs = cfg.current_sensor
    counts = sensors.encoder_counts(X[:, 2] / p.R, cfg.encoder.counts_per_rev)
    adc = sensors.adc_read(sensors.acs712_volts(X[:, 0], 2.5, cs.sensitivity_v_per_a, noise_v, rng),
                           cs.adc_vref, cs.adc_steps)
    zero = 2.5 - 0.5 * cs.adc_vref / cs.adc_steps     # what a user calibrating at rest writes down
    signals = pd.DataFrame({
        "t_s": (t_ms - t_ms[0]) / 1000.0,
        "theta_rad": 2 * np.pi * counts / cfg.encoder.counts_per_rev,
        "current_a": (adc * cs.adc_vref / cs.adc_steps - zero) / cs.sensitivity_v_per_a,
        "dir": dirs,
    })
    return derive_tables(signals, cfg).kinematics, cfg
