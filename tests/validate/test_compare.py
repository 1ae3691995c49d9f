"""Closed loop vs replay, switch slips, oscillation statistics."""

import numpy as np
import pandas as pd
import pytest

from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.validate.compare import (compare, comparison_table, oscillation_stats, simulate_both,
                                       switch_differences, switch_indices)
from pipeline.schemas import load_schema
from tests.validate.synthetic import synthetic_kinematics

SPEC = default_config().plant_spec()


def test_replay_and_closed_loop_agree_when_switches_coincide():
    kin = synthetic_kinematics(SPEC)
    sims = simulate_both(SPEC, kin)
    cl, rp = sims["closed_loop"], sims["replay"]
    assert np.array_equal(cl.dir, kin["dir"].to_numpy())
    assert np.array_equal(cl.dir, rp.dir)
    np.testing.assert_allclose(cl.theta, rp.theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cl.current, rp.current, rtol=0, atol=1e-12)
    result = compare(kin, SPEC, sims)
    assert result["agreement"] == {"same_switches": True, "max_abs_theta_diff_rad": pytest.approx(0.0, abs=1e-12)}
    for way in ("closed_loop", "replay"):
        assert result[way]["switches"]["n_slipped"] == 0
        assert result[way]["signals"]["theta"]["mse"] < 1e-7          # encoder quantisation only


def test_replay_follows_the_log_when_the_log_switches_late():
    kin = synthetic_kinematics(SPEC)
    d = kin["dir"].to_numpy().copy()
    k = switch_indices(d)[2]
    d[k] = d[k - 1]                    # the logged controller switched one sample later
    kin["dir"] = d
    sims = simulate_both(SPEC, kin)
    assert np.array_equal(sims["replay"].dir, d)
    assert not np.array_equal(sims["closed_loop"].dir, d)
    sw = switch_differences(kin["t_s"].to_numpy(), d, sims["closed_loop"].dir)
    assert sw["max_abs_s"] == pytest.approx(0.05)
    assert sw["n_slipped"] >= 1
    result = compare(kin, SPEC, sims)
    assert result["agreement"]["same_switches"] is False
    assert result["agreement"]["max_abs_theta_diff_rad"] > 1e-3


def test_oscillation_stats_show_the_sampled_guard_overshoot():
    kin = synthetic_kinematics(SPEC, quantise=False)
    o = oscillation_stats(kin["t_s"].to_numpy(), kin["theta_rad"].to_numpy(), kin["dir"].to_numpy(), SPEC.guard_rad)
    assert o["n_half_cycles"] >= 10
    assert 3.0 < o["period_s"] < 4.5
    assert 0.0 < o["overshoot_rad"] < 0.2      # the pinion passes the guard before the next 50 ms sample
    assert o["amplitude_rad"] == pytest.approx(SPEC.guard_rad + o["overshoot_rad"])


def test_no_switches_gives_undefined_period_not_zero():
    kin = synthetic_kinematics(SPEC, duration=0.5)
    o = oscillation_stats(kin["t_s"].to_numpy(), kin["theta_rad"].to_numpy(), kin["dir"].to_numpy(), SPEC.guard_rad)
    assert o["n_half_cycles"] == 0 and np.isnan(o["period_s"])


def _with_rest_lead_in(kin: pd.DataFrame, n: int = 20) -> pd.DataFrame:
    """The run preceded by ``n`` samples at rest with the motor off (the sketch not yet driving)."""
    dt = float(kin["t_s"].iloc[1] - kin["t_s"].iloc[0])
    rest = pd.DataFrame({c: np.zeros(n, dtype=kin[c].dtype) for c in kin.columns})
    rest["t_s"] = np.arange(n) * dt
    run = kin.copy()
    run["t_s"] = run["t_s"] + n * dt
    return pd.concat([rest, run], ignore_index=True)


def test_motor_off_pre_roll_is_honoured_in_both_ways():
    kin = _with_rest_lead_in(synthetic_kinematics(SPEC))
    sims = simulate_both(SPEC, kin)
    for sim in sims.values():
        assert np.all(sim.dir[:20] == 0)
        assert np.max(np.abs(sim.theta[:20])) < 1e-3          # at rest: within an encoder count


def test_a_hidden_effect_raises_the_errors_and_the_energy_error():
    truth = default_config().plant_spec((make_effect("driver_voltage_drop", {"Vd": 1.5}),))
    kin = synthetic_kinematics(truth, current_noise_a=0.02)
    clean = compare(synthetic_kinematics(SPEC, current_noise_a=0.02), SPEC)
    biased = compare(kin, SPEC)
    assert biased["replay"]["signals"]["theta"]["mse"] > 100 * clean["replay"]["signals"]["theta"]["mse"]
    assert abs(biased["replay"]["energy_error"]["paper_pct"]) > 5 * abs(clean["replay"]["energy_error"]["paper_pct"])


def test_comparison_table_matches_its_schema():
    kin = synthetic_kinematics(SPEC)
    table = comparison_table(kin, simulate_both(SPEC, kin))
    arrow = load_schema("comparison").to_arrow(table)
    assert arrow.num_rows == len(kin)
    assert arrow.schema.field("theta_replay_rad").metadata[b"unit"] == b"rad"
