"""What discovery works on: one recording's measured signals, its rig, and the two ways to simulate it.

A ``Measurement`` is built from the derive stage's kinematics table (t_s,
theta_rad, omega_rad_s, current_a, dir, dir_inferred) and the rig configuration
resolved at ingest.  Fitting uses *replay* (the logged command drives the
motor), which is smooth in the parameters; the verdict is confirmed in *closed
loop* (the model's own sampled guard decides), the paper's free-run measure,
whose error jumps whenever a simulated switch slips by one control period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.config import RigConfig
from pipeline.errors import PdrError
from pipeline.model.effects import Effect, PlantSpec
from pipeline.model.simulate import SimResult, simulate
from pipeline.validate.compare import initial_state


@dataclass(frozen=True)
class Measurement:
    """One recording, as arrays; ``current`` is None when the sketch does not log it."""

    name: str
    config: RigConfig
    kinematics: pd.DataFrame        # derive stage table, one row per sample (for validate.metrics)
    t: np.ndarray                   # s
    theta: np.ndarray               # rad
    omega: np.ndarray               # rad/s (derive's default estimator; NaN where undefined)
    current: np.ndarray | None      # A, as the sensor reads it
    dir: np.ndarray                 # int8 command after each sample (logged, else inferred)
    dir_source: str                 # "logged" or "inferred"

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def signals(self) -> dict[str, np.ndarray]:
        """The signals the fit scores: the angle and, when logged, the current.

        omega is left out of the likelihood: it is differentiated from theta,
        so counting it again would count the encoder twice.
        """
        out = {"theta": self.theta}
        if self.current is not None:
            out["current"] = self.current
        return out

    def spec(self, effects: tuple[Effect, ...] = ()) -> PlantSpec:
        """The rig's model ([model] + [effects] of its TOML) plus ``effects``."""
        return self.config.plant_spec(tuple(effects))

    def x0(self, spec: PlantSpec) -> tuple[float, float, float]:
        """[I, w, delta] at the first sample, as validation takes it (the current read through the
        model's sensor offset, so an offset candidate also corrects a misread initial current)."""
        return initial_state(self.kinematics, spec)

    def replay(self, spec: PlantSpec, x0: tuple[float, float, float] | None = None) -> SimResult:
        """The logged command drives the model (smooth in the parameters)."""
        return simulate(spec, self.t, x0=self.x0(spec) if x0 is None else x0, dir0=_first_dir(self.dir),
                        dir_log=self.dir, closed_loop=False)


def _first_dir(d: np.ndarray) -> int:
    nz = np.flatnonzero(d != 0)
    return int(d[nz[0]]) if len(nz) else 1


def _column(kin: pd.DataFrame, name: str) -> np.ndarray | None:
    if name not in kin.columns:
        return None
    return kin[name].to_numpy(dtype=float, na_value=np.nan)


def measurement_from_kinematics(kin: pd.DataFrame, config: RigConfig, name: str) -> Measurement:
    """Arrays for fitting from a kinematics table; refuses tables discovery cannot use."""
    for col in ("t_s", "theta_rad"):
        if col not in kin.columns:
            raise PdrError(f"kinematics table lacks column '{col}', which discovery needs", path=name)
    kin = kin.reset_index(drop=True)
    if len(kin) < 20:
        raise PdrError(f"only {len(kin)} samples; discovery needs at least 20 to fit and hold out", path=name)
    t = _column(kin, "t_s")
    theta = _column(kin, "theta_rad")
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)):
        raise PdrError("sample times must be finite and strictly increasing", path=name)
    if not np.all(np.isfinite(theta)):
        raise PdrError("theta_rad has missing values", path=name)
    omega = _column(kin, "omega_rad_s")
    if omega is None:
        omega = np.full_like(theta, np.nan)
    current = _column(kin, "current_a")
    if current is not None and not np.all(np.isfinite(current)):
        current = None
    d, source = _command(kin)
    if d is None:
        raise PdrError("neither a logged 'dir' nor an inferred 'dir_inferred' column; "
                       "replay needs the command sequence", path=name)
    return Measurement(name=name, config=config, kinematics=kin, t=t, theta=theta, omega=omega,
                       current=current, dir=d, dir_source=source)


def _command(kin: pd.DataFrame) -> tuple[np.ndarray | None, str]:
    for col, source in (("dir", "logged"), ("dir_inferred", "inferred")):
        if col in kin.columns:
            values = kin[col].to_numpy(dtype=float, na_value=np.nan)
            if np.all(np.isfinite(values)) and np.all(np.isin(values, (-1, 0, 1))):
                return values.astype(np.int8), source
    return None, ""
