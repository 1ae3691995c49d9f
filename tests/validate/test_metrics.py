"""signal_errors: the numbers gate and discovery share."""

import numpy as np
import pandas as pd
import pytest

from pipeline.config import default_config
from pipeline.model.simulate import simulate
from pipeline.validate.metrics import error_measures, mse_only, signal_errors


def _measured_from(sim, noise=0.0, seed=0, current=True):
    rng = np.random.default_rng(seed)
    df = pd.DataFrame({"t_s": sim.t, "theta_rad": sim.theta + noise * rng.standard_normal(len(sim.t)),
                       "omega_rad_s": sim.omega.copy()})
    if current:
        df["current_a"] = sim.current_measured + noise * rng.standard_normal(len(sim.t))
    return df


def test_perfect_model_has_zero_error_and_full_fit():
    sim = simulate(default_config().plant_spec())
    err = signal_errors(_measured_from(sim), sim)
    assert set(err) == {"theta", "omega", "current"}
    for e in err.values():
        assert e["mse"] == 0.0 and e["rmse"] == 0.0 and e["fit_pct"] == pytest.approx(100.0)


def test_white_noise_gives_its_variance_as_mse():
    sim = simulate(default_config().plant_spec(), duration=200.0)
    err = signal_errors(_measured_from(sim, noise=0.01, seed=3), sim)
    assert err["theta"]["mse"] == pytest.approx(1e-4, rel=0.1)
    assert err["theta"]["rmse"] == pytest.approx(0.01, rel=0.05)
    assert 95.0 < err["theta"]["fit_pct"] < 100.0


def test_fit_matches_matlab_compare_definition():
    y = np.array([0.0, 1.0, 2.0, 3.0])
    yhat = np.array([0.0, 1.0, 2.0, 2.0])
    e = error_measures(y, yhat)
    assert e["mse"] == pytest.approx(0.25)
    assert e["fit_pct"] == pytest.approx(100 * (1 - 1.0 / np.sqrt(5.0)))
    assert error_measures(y, np.full(4, y.mean()))["fit_pct"] == pytest.approx(0.0)


def test_current_omitted_when_not_logged_and_nan_samples_skipped():
    sim = simulate(default_config().plant_spec())
    df = _measured_from(sim, current=False)
    df.loc[0, "omega_rad_s"] = np.nan
    err = signal_errors(df, sim)
    assert "current" not in err
    assert err["omega"]["n"] == len(sim.t) - 1
    assert mse_only(err) == {"theta": 0.0, "omega": 0.0}


def test_length_mismatch_is_refused():
    sim = simulate(default_config().plant_spec())
    with pytest.raises(ValueError, match="rows"):
        signal_errors(_measured_from(sim).iloc[:-1], sim)
