"""Virtual-rig recordings as the derive stage sees them, without going through ingest.

The sample table is built from the rig's own truth rows (what the board printed:
millis(), counts, ADC, dir) with the conversions of docs/MODEL.md, so these
tests depend on the virtual rig but not on the ingest stage's parser.
"""

from __future__ import annotations


import numpy as np
import pandas as pd

from pipeline.config import RigConfig, resolve_config
from pipeline.rig.recording import Recording, RigSetup, make_recording


def rig_run(setup: RigSetup = RigSetup(), seed: int = 0, *, log_dir: bool = True,
            log_current: bool = True) -> tuple[pd.DataFrame, RigConfig, Recording]:
    rec = make_recording(setup, seed)
    cfg = _config(rec.toml_text)
    tr = rec.truth[(rec.truth["status"] == "ok") & (rec.truth["segment"] == 1)].reset_index(drop=True)
    cs = cfg.current_sensor
    t_ms = tr["t_ms"].to_numpy(np.int64)
    sig = {"t_s": (t_ms - t_ms[0]) / 1000.0, "t_raw": t_ms.astype(float), "line": tr["line"].to_numpy(np.int64),
           "segment": np.zeros(len(tr), dtype=np.int32), "counts": tr["counts"].to_numpy(np.int64),
           "theta_rad": 2 * np.pi * tr["counts"].to_numpy(float) / cfg.encoder.counts_per_rev}
    if log_current:
        v = tr["adc"].to_numpy(float) * cs.adc_vref / cs.adc_steps
        sig |= {"adc": tr["adc"].to_numpy(np.int32), "current_v": v,
                "current_a": (v - float(cs.zero_v)) / cs.sensitivity_v_per_a}
    if log_dir:
        d = tr["dir"].to_numpy(np.int8)
        sig |= {"dir": d, "mode": np.where(d == 1, 1, np.where(d == -1, 2, 0)).astype(np.int8)}
    return pd.DataFrame(sig), cfg, rec


def _config(toml_text: str) -> RigConfig:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "rig.toml"
        path.write_text(toml_text, encoding="utf-8")
        return resolve_config([path])
