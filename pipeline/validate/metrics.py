"""Measured vs simulated: the error measures validation and discovery share.

One function, ``signal_errors``, so the MSEs that ``pdr gate`` thresholds and
the MSEs that ``pdr discover`` reports before/after an effect are the same
numbers (ARCHITECTURE.md, "Measured vs simulated").  The paper's measure is the
MSE (Sec. IV); RMSE is the same in the signal's unit; ``fit_pct`` is MATLAB
``compare``'s normalised fit, 100 * (1 - ||y - yhat|| / ||y - mean(y)||), which
is 100 for a perfect model, 0 for one no better than the mean, negative below.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.model.simulate import SimResult

# signal -> (measured kinematics column, SimResult field, unit)
SIGNALS: dict[str, tuple[str, str, str]] = {
    "theta": ("theta_rad", "theta", "rad"),
    "omega": ("omega_rad_s", "omega", "rad/s"),
    "current": ("current_a", "current_measured", "A"),
}


def error_measures(y: np.ndarray, yhat: np.ndarray) -> dict[str, float]:
    """MSE, RMSE and normalised fit % over the samples where both are finite."""
    y = np.asarray(y, dtype=float)
    yhat = np.asarray(yhat, dtype=float)
    ok = np.isfinite(y) & np.isfinite(yhat)
    y, yhat = y[ok], yhat[ok]
    if len(y) == 0:
        return {"mse": float("nan"), "rmse": float("nan"), "fit_pct": float("nan"), "n": 0}
    r = y - yhat
    mse = float(np.mean(r * r))
    spread = float(np.linalg.norm(y - y.mean()))
    # A flat measured signal has no spread to normalise by: the fit is undefined.
    fit = 100.0 * (1.0 - float(np.linalg.norm(r)) / spread) if spread > 0 else float("nan")
    return {"mse": mse, "rmse": float(np.sqrt(mse)), "fit_pct": fit, "n": int(len(y))}


def signal_errors(measured: pd.DataFrame, sim: SimResult) -> dict[str, dict[str, float]]:
    """Per signal (theta rad, omega rad/s, current A): ``mse``, ``rmse``, ``fit_pct``, ``n``.

    ``measured`` is a kinematics table (derive stage) sampled at ``sim.t``;
    current is compared as the sensor sees it (``sim.current_measured``, which
    includes a sensor offset effect) and omitted when the recording has none.
    Samples where either side is not finite (e.g. the first velocity sample)
    are left out rather than counted as zero error.
    """
    if len(measured) != len(sim.t):
        raise ValueError(f"measured table has {len(measured)} rows, simulation {len(sim.t)} samples")
    out: dict[str, dict[str, float]] = {}
    for name, (col, field, _unit) in SIGNALS.items():
        if col not in measured.columns:
            continue
        out[name] = error_measures(column(measured, col, dtype=float, na_value=np.nan),
                                   getattr(sim, field))
    return out


def mse_only(errors: dict[str, dict[str, float]]) -> dict[str, float]:
    """``{"theta": mse, ...}``: the form of ``mse_before``/``mse_after`` in ``pdr discover --json``."""
    return {name: e["mse"] for name, e in errors.items()}
