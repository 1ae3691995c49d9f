"""Calibration: the base model fitted to recordings of one rig, with Table I (or the declared
``[model]``) as prior, and what the recordings can and cannot pin down (``structure``).

Pure core (``calibrate``: measurements -> ``Calibration``); the shell (``cli``) loads recordings and
writes the report.  The fit is the estimation core's (``pipeline.estimate``): one likelihood over
every recording, each recording's start and commands in flight solved as nuisances.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.calibrate.structure import (COMBINATIONS, CONVENTION, FITTED, IDENTIFIABLE, SPRINGS, UNITS,
                                          base_unknowns, scaled_interval)
from pipeline.discover.measurement import Measurement
from pipeline.discover.residuals import target_of
from pipeline.errors import PdrError
from pipeline.estimate import FitResult, Model, Problem
from pipeline.model.params import ModelParams
from pipeline.model.simulate import SimResult
from pipeline.validate.metrics import mse_only, signal_errors
from pipeline.validate.stage import finite_or_none

MODEL_KEYS = ModelParams.names()


@dataclass
class Calibration:
    recordings: list[str]
    prior: ModelParams
    calibrated: ModelParams
    declared: bool                  # the prior is the rig's declared [model], not Table I
    fit: FitResult
    intervals: dict[str, tuple[float, float]]        # fitted unknowns, profile likelihood ~95 %
    mse_before: dict[str, float]
    mse_after: dict[str, float]
    replays_before: list[SimResult]
    replays_after: list[SimResult]

    @property
    def identifiable(self) -> dict[str, bool]:
        return {k: k in IDENTIFIABLE for k in MODEL_KEYS}

    def combinations(self) -> list[dict]:
        out = []
        for c in COMBINATIONS:
            span = self.intervals.get(c.numerator)
            factor = (self.calibrated.R ** 2 * 2.0 if c.numerator == SPRINGS else 1.0) / self.calibrated.J
            out.append({"name": c.name, "value": c.value(self.calibrated), "unit": c.unit,
                        "interval": scaled_interval(span, factor)})
        return out

    def to_json(self) -> dict:
        return finite_or_none({
            "recordings": self.recordings,
            "parameters": {k: float(getattr(self.calibrated, k)) for k in MODEL_KEYS},
            "identifiable": self.identifiable,
            "intervals": {k: (list(self.intervals[k]) if k in IDENTIFIABLE else None) for k in MODEL_KEYS},
            "combinations": self.combinations(),
            "mse_before": self.mse_before,
            "mse_after": self.mse_after,
            "prior": {"parameters": {k: float(getattr(self.prior, k)) for k in MODEL_KEYS},
                      "source": "the rig's declared [model]" if self.declared else "Table I (built-in defaults)"},
            "units": {k: UNITS[k] for k in MODEL_KEYS},
            "convention": CONVENTION,
            "fit": {"chi2": self.fit.data_chi2, "samples": self.fit.n_data, "free_parameters": self.fit.k,
                    "aic": self.fit.aic, "bic": self.fit.bic,
                    "inflation": [float(f) for f in self.fit.factors],
                    "converged": self.fit.success, "evaluations": self.fit.nfev},
        })


def check_usable(meas: Measurement) -> None:
    """Refuse a recording that cannot pin anything: without the current the electrical equation is
    blind, and without the motor driven both ways the input never excites the plant."""
    if meas.current is None:
        raise PdrError("calibration needs the current: this recording has no current column", path=meas.name)
    on = meas.dir[meas.dir != 0]
    if len(on) == 0:
        raise PdrError("the motor is never on in this recording (every dir is 0): nothing to calibrate on",
                       path=meas.name)
    if not np.any(on[1:] != on[:-1]):
        raise PdrError("the controller never reverses the motor in this recording (no switch at a guard): "
                       "the plant's response is not excited enough to calibrate on", path=meas.name)


def _mse(measurements: list[Measurement], replays: list[SimResult]) -> dict[str, float]:
    """Validation's replay MSE per signal, pooled over the recordings (weighted by their samples)."""
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    for meas, sim in zip(measurements, replays):
        errors = signal_errors(meas.kinematics, sim)
        for s, mse in mse_only(errors).items():
            n = int(errors[s]["n"])
            sums[s] = sums.get(s, 0.0) + mse * n
            counts[s] = counts.get(s, 0) + n
    return {s: sums[s] / counts[s] for s in sums if counts[s]}


def _replays(measurements: list[Measurement], base: ModelParams) -> list[SimResult]:
    return [m.simulate_ways(replace(m.config, model=base).plant_spec(), m.dir)["replay"] for m in measurements]


def calibrate(measurements: list[Measurement], prior: ModelParams, declared: bool, max_nfev: int = 200) -> Calibration:
    """Fit ``FITTED`` under the convention to every recording at once; intervals by profile likelihood."""
    if not measurements:
        raise PdrError("calibration needs at least one recording")
    for meas in measurements:
        check_usable(meas)
    unknowns = tuple(base_unknowns(prior, declared))
    problem = Problem(tuple(target_of(m) for m in measurements), Model(base=prior), unknowns)
    result = problem.fit(max_nfev=max_nfev)
    calibrated = problem.model_at(result.x).base
    intervals = {name: result.profile_interval(name) for name in FITTED}
    before, after = _replays(measurements, prior), _replays(measurements, calibrated)
    return Calibration(recordings=[m.name for m in measurements], prior=prior, calibrated=calibrated,
                       declared=declared, fit=result, intervals=intervals,
                       mse_before=_mse(measurements, before), mse_after=_mse(measurements, after),
                       replays_before=before, replays_after=after)
