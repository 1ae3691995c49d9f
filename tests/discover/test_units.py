"""The pieces discovery's evidence rests on: the noise floor, the held-out folds, the localisation."""

import numpy as np
import pandas as pd
import pytest

from pipeline.config import default_config
from pipeline.discover.candidates import folds_by_cycle
from pipeline.estimate import autocorrelation_time
from pipeline.discover.measurement import measurement_from_kinematics
from pipeline.discover.residuals import describe, noise_floor, signatures
from pipeline.errors import PdrError
from pipeline.model.simulate import simulate
from pipeline.estimate.noise import difference_noise


def test_difference_noise_sees_white_noise_through_a_smooth_signal():
    rng = np.random.default_rng(0)
    t = np.arange(500) * 0.05
    for sigma in (0.001, 0.03):
        r = 0.5 * np.sin(3.0 * t) + rng.normal(0, sigma, len(t))
        assert difference_noise(r) == pytest.approx(sigma ** 2, rel=0.2)


def test_autocorrelation_time_is_one_for_white_and_large_for_smooth():
    rng = np.random.default_rng(1)
    assert autocorrelation_time(rng.normal(size=2000)) < 1.3
    assert autocorrelation_time(np.sin(np.arange(2000) * 0.01)) > 20


def _kinematics(spec, current_offset=0.0, counts_per_rev=None):
    t = np.arange(500) * 0.05
    sim = simulate(spec, t)
    theta = sim.theta
    if counts_per_rev is not None:          # what an encoder reports
        theta = np.round(theta * counts_per_rev / (2 * np.pi)) * 2 * np.pi / counts_per_rev
    return pd.DataFrame({"t_s": t, "theta_rad": theta, "omega_rad_s": sim.omega,
                         "current_a": sim.current + current_offset, "dir": sim.dir,
                         "dir_inferred": np.zeros(len(t), dtype=bool)})


def test_folds_hold_both_directions_and_cover_every_sample():
    cfg = default_config()
    meas = measurement_from_kinematics(_kinematics(cfg.plant_spec()), cfg, "x")
    a, b = folds_by_cycle(meas)
    assert np.all(a ^ b)
    for fold in (a, b):
        assert {1, -1} <= set(np.unique(meas.dir[fold]))


def test_floor_is_at_least_the_quantisation_and_localisation_names_a_current_bias():
    cfg = default_config()
    kin = _kinematics(cfg.plant_spec(), current_offset=0.06, counts_per_rev=cfg.encoder.counts_per_rev)
    meas = measurement_from_kinematics(kin, cfg, "x")
    sim = meas.replay(meas.spec())
    floor = noise_floor(meas, sim)
    q = 2 * np.pi / cfg.encoder.counts_per_rev
    assert floor["theta"] >= q * q / 12
    text = " ".join(describe(signatures(meas, sim, floor), floor))
    assert "the current residual has a mean of +0.06 A (in both modes" in text
    assert "theta residual is at the noise floor" in text


def test_refuses_tables_it_cannot_use():
    cfg = default_config()
    kin = _kinematics(cfg.plant_spec())
    with pytest.raises(PdrError, match="at least 20"):
        measurement_from_kinematics(kin.head(5), cfg, "short")
    with pytest.raises(PdrError, match="dir"):
        measurement_from_kinematics(kin.drop(columns=["dir"]), cfg, "nodir")


def test_an_evaluators_work_counts_the_start_estimates_of_the_models_it_replays():
    """A Coulomb plant is not affine in its start: each start estimate runs a Gauss-Newton refinement, ~20
    simulations of the first seconds, which cost more than the replay itself.  The budget must see them."""
    from pipeline.discover.candidates import START_RUN_COST, Evaluator, make, replay_cost
    from pipeline.discover.residuals import noise_floor

    spec = default_config().plant_spec()
    meas = measurement_from_kinematics(_kinematics(spec, counts_per_rev=1440), default_config(), "k")
    ev = Evaluator(meas, noise_floor(meas, meas.replay(meas.spec())))
    before, runs = ev.work, meas.start_runs
    coulomb = (make("coulomb_friction", 2e-3),)
    ev.sim(coulomb)
    assert meas.start_runs - runs >= 8                  # its unit responses and a refinement
    assert ev.work - before == replay_cost(meas.spec(coulomb), meas.n) + START_RUN_COST * (meas.start_runs - runs)
    assert replay_cost(meas.spec(coulomb), meas.n) > replay_cost(meas.spec(), meas.n)    # events located
    again = ev.work
    ev.sim(coulomb)                                     # remembered: nothing more to pay
    assert ev.work == again


def test_a_plant_whose_start_cannot_be_simulated_scores_as_a_failure_not_a_crash():
    """A backlash of 2e-17 rad beside a loop delay of 3e-11 s (values a fit stepped to on a used draw) makes the
    nonsmooth stepper refuse the start estimate's unit responses (zero-length events without end).  The
    search must see an infinitely bad model, as it does when the replay itself fails."""
    from pipeline.discover.candidates import Evaluator, make

    spec = default_config().plant_spec()
    meas = measurement_from_kinematics(_kinematics(spec, counts_per_rev=1440), default_config(), "k")
    ev = Evaluator(meas, noise_floor(meas))
    degenerate = (make("rack_inertia", 0.0009917792825006498 - 0.0004857), make("backlash", 2.127927196729481e-17),
                  make("loop_delay", 2.8760977835846235e-11))
    with pytest.raises(RuntimeError, match="chattering"):
        meas.x0(meas.spec(degenerate))
    assert not np.isfinite(ev.nll(ev.sim(degenerate))) or ev.nll(ev.sim(degenerate)) >= 1e12
    assert any("start" in f and "chattering" in f for f in ev.failures)
    assert np.isfinite(ev.nll(ev.sim(())))                   # the plain model still replays
