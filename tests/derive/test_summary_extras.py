"""summary.json's additions against the virtual rig's truth: energy uncertainty, the paper's motor-on
window, current RMS and noise, a stuck sensor, the motor logged off while moving, frequency, decrement."""

import numpy as np
import pytest

from pipeline.derive.cycles import log_decrement
from pipeline.derive.energy import run_energy
from pipeline.derive.current import CURRENT_ORDER, CURRENT_WINDOW
from pipeline.derive.stage import derive_tables
from pipeline.derive.phases import phase_bounds
from pipeline.derive.velocity import smooth_by_phase
from pipeline.rig.recording import RigSetup
from tests.derive.rigdata import rig_run
from tests.derive.test_stage import true_energy

ADC_STEP_A = 5.0 / 1024 / 0.185          # 26.4 mA


def test_current_noise_and_rms_against_the_sensor_and_the_true_current():
    sig, cfg, rec = rig_run(seed=4)
    s = derive_tables(sig, cfg).summary
    # the rig's noise is one ADC step (sigma) plus the ADC's rounding: sqrt(1 + 1/12) steps
    assert s["current"]["noise_a"] == pytest.approx(ADC_STEP_A * np.sqrt(1 + 1 / 12), rel=0.15)
    tr = rec.truth[(rec.truth["status"] == "ok") & (rec.truth["segment"] == 1)]
    on = tr["dir"].to_numpy() != 0
    true_rms = np.sqrt(np.mean(tr["current_a"].to_numpy()[on] ** 2))
    assert s["current"]["rms_a"] == pytest.approx(true_rms, rel=0.03)
    assert s["current"]["stuck"] is None and s["current"]["longest_repeat_samples"] < 10


def test_energy_uncertainty_matches_a_monte_carlo_of_the_same_noise_and_covers_the_truth():
    """Redraw the sensor noise on the true current 100 times and rerun the stage's own smoothing and
    energy: the spread matches the propagated sigma; the measured figures sit within 3 sigma of the truth."""
    sig, cfg, rec = rig_run(seed=6)
    d = derive_tables(sig, cfg)
    sigma = d.summary["energy_uncertainty_j"]
    noise = d.summary["current"]["noise_a"]
    tr = rec.truth[(rec.truth["status"] == "ok") & (rec.truth["segment"] == 1)]
    t = d.kinematics["t_s"].to_numpy()
    dirs, omega, theta = (d.kinematics[c].to_numpy() for c in ("dir", "omega_rad_s", "theta_rad"))
    spec = cfg.plant_spec()
    rng = np.random.default_rng(0)
    draws = []
    for _ in range(100):
        noisy = tr["current_a"].to_numpy() + noise * rng.standard_normal(len(t))
        smooth = smooth_by_phase(t, noisy, phase_bounds(dirs), CURRENT_WINDOW, CURRENT_ORDER)
        draws.append(run_energy(t, smooth, omega, theta, dirs, spec))
    for key in ("energy_paper_j", "input_energy_j", "balance_residual_j"):
        spread = np.std([e[key] for e in draws], ddof=1)
        assert sigma[key] == pytest.approx(spread, rel=0.25), key           # 100 draws: ~7 % on a std
    assert 0.1 < sigma["balance_residual_j"] < 0.4                          # the +/-0.36 J swing, as one sigma
    want = true_energy(rec, cfg)
    got = d.summary["energy"]
    for key in ("energy_paper_j", "input_energy_j"):
        assert abs(got[key] - want[key]) < 3 * sigma[key], key
    assert abs(got["balance_residual_j"]) < 3 * sigma["balance_residual_j"]    # exact model: zero within noise


def test_paper_estimate_over_the_motor_on_window():
    """Logging starts 20 samples before the sketch drives the motor: the paper's N = 500 is the motor-on run."""
    sig, cfg, rec = rig_run(RigSetup(noise_v=0.0), seed=0)
    s = derive_tables(sig, cfg).summary
    first_on = int(np.flatnonzero(sig["dir"].to_numpy() != 0)[0])
    assert first_on == rec.truth_meta["segments"][0]["pre_roll_samples"] == 20
    assert s["energy_paper_window"]["first_sample"] == first_on
    assert s["energy_paper_window"]["samples"] == len(sig) - first_on == 500
    i = np.asarray(derive_tables(sig, cfg).kinematics["current_smooth_a"])[first_on:]
    assert s["energy"]["energy_paper_j"] == pytest.approx(6.0 * 0.05 * np.sum(np.abs(i[:-1] + i[1:])) / 2, rel=1e-12)


def test_a_stuck_current_sensor_is_flagged_with_where():
    sig, cfg, _ = rig_run(seed=2)
    stuck = sig.copy()
    stuck.loc[150:199, "current_a"] = stuck.loc[150, "current_a"]
    s = derive_tables(stuck, cfg).summary
    assert s["current"]["longest_repeat_samples"] == 50
    assert s["current"]["stuck"].startswith("current sensor stuck") and "for 50 samples from sample 150" in \
        s["current"]["stuck"]
    assert s["current"]["stuck"] in s["notes"]


def test_motor_logged_off_while_moving_is_said_as_such_not_blamed_on_the_encoder():
    sig, cfg, _ = rig_run(seed=1)
    off = sig.assign(dir=np.zeros(len(sig), dtype=np.int8), mode=np.zeros(len(sig), dtype=np.int8))
    s = derive_tables(off, cfg).summary
    assert any("the motor is logged off (dir = 0) while the pinion moves" in n for n in s["notes"])
    assert not any("counts_per_rev" in n for n in s["notes"])
    assert s["not_computed"]["overshoot"].startswith("the motor is logged off (dir = 0) for the whole run")
    s = derive_tables(sig, cfg).summary                         # the same run as logged: nothing said
    assert not any("logged off" in n for n in s["notes"])


def test_frequency_decrement_and_trends_null_with_a_reason():
    sig, cfg, _ = rig_run(seed=3)
    s = derive_tables(sig, cfg).summary
    c = s["cycles"]
    assert c["frequency_hz"] == pytest.approx(1.0 / c["steady_period_s"]["mean"])
    assert 0.2 < c["frequency_hz"] < 0.35                               # the paper's rig: ~3.7 s per cycle
    delta, zeta, why = log_decrement(np.array([1.2, 1.0, 1.0]))
    assert delta == pytest.approx(np.log(1.2) / 2) and zeta == pytest.approx(delta / np.hypot(2 * np.pi, delta))
    assert why is None and log_decrement(np.array([1.0]))[0] is None
    assert s["overshoot"]["directions"]["upper"]["trend_not_computed"] is None
    short = derive_tables(sig.iloc[:120], cfg).summary                 # 6 s: a turn or two per guard
    upper = short["overshoot"]["directions"]["upper"]
    assert upper["trend_rad"] is None and "a trend needs 3" in upper["trend_not_computed"]
    assert short["overshoot"]["centre_drift_rad"] is None
    assert "a trend needs 3" in short["overshoot"]["centre_drift_not_computed"]
    assert short["cycles"]["log_decrement"] is None and short["cycles"]["log_decrement_not_computed"]
    steady = s["overshoot"]["directions"]["upper"]["steady_overshoot_rad"]
    assert steady["n"] == s["overshoot"]["directions"]["upper"]["overshoot_rad"]["n"] - 1
