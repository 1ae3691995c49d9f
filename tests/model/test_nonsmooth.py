"""Non-smooth effects against the rig's independent reference plant, and the stick mode itself.

Tolerance: 1e-7 (rad, rad/s, A) at every sample.  The reference
(``pipeline.rig.plant.simulate_reference``) integrates the same physics with
DOP853 at rtol 1e-10 / atol 1e-12 and locates each event with its own root
finder, so it carries ~1e-9 of error over a run (observed 1e-10..6e-9 here);
the fast simulator is exact up to rounding.  1e-7 keeps a margin over that and
is still four orders below anything a smeared event would produce: missing a
velocity zero crossing, a break-away or a backlash edge by even 1 ms moves
theta by ~1e-3 rad, and one control period of switching error by ~0.1 rad.
"""

from dataclasses import replace

import math

import numpy as np
import pytest

from pipeline.config import default_config
from pipeline.model.nonsmooth import advance, new_plant, plant_constants, reset
from pipeline.model.simulate import simulate
from pipeline.rig.plant import simulate_reference
from tests.model.ivp_reference import jittered_times

TOL = 1e-7
BASE = default_config().plant_spec()
T = jittered_times(500, seed=11)

CASES = {
    "coulomb_friction": dict(Tc=6e-4),
    "coulomb_friction_sticky": dict(Tc=2e-3),
    "backlash": dict(gap=0.1),
    "backlash_wide": dict(gap=0.3),
    "loop_delay": dict(Td=0.05),
    "all_together": dict(Tc=8e-4, gap=0.15, Td=0.03, I0=0.05, v_drive=5.2,
                         params=BASE.params.with_(b=9e-4, J=BASE.params.J + 5e-4)),
}


def _close(a, b):
    np.testing.assert_array_equal(a.dir, b.dir)
    for f in ("theta", "omega", "current", "current_measured"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=0, atol=TOL, err_msg=f)


@pytest.mark.parametrize("name", list(CASES))
def test_closed_loop_matches_reference_plant(name):
    spec = replace(BASE, **CASES[name])
    _close(simulate(spec, T), simulate_reference(spec, T))


@pytest.mark.parametrize("name", ["coulomb_friction_sticky", "all_together"])
def test_continuous_guard_matches_reference_plant(name):
    spec = replace(BASE, **CASES[name])
    _close(simulate(spec, T, guard="continuous"), simulate_reference(spec, T, guard="continuous"))


def test_replay_with_every_effect_matches_reference_plant():
    spec = replace(BASE, **CASES["all_together"])
    log = simulate(BASE, T).dir.copy()
    log[:5] = 0
    _close(simulate(spec, T, dir_log=log, closed_loop=False),
           simulate_reference(spec, T, dir_log=log, closed_loop=False))


def test_break_away_from_rest_happens_exactly_when_the_motor_torque_reaches_tc():
    # Replay q1 from rest on a 1 ms grid.  Stuck, I(t) = V/Ra (1 - e^{-t Ra/La}) and
    # the pinion may not move before Kt I(t) = Tc: t* = -La/Ra ln(1 - Tc Ra / (Kt V)).
    p = BASE.params
    Tc = 1.767e-3                                        # t* ~ 0.30 s
    spec = replace(BASE, Tc=Tc)
    t = np.arange(0, 601) * 1e-3
    r = simulate(spec, t, dir_log=np.ones(len(t), dtype=int), closed_loop=False)
    t_star = -p.La / p.Ra * math.log(1.0 - Tc * p.Ra / (p.Kt * BASE.v_drive))
    before, after = t <= t_star, t > t_star
    assert 0.29 < t_star < 0.31
    assert np.all(r.omega[before] == 0.0) and np.all(r.theta[before] == 0.0)    # exactly still
    assert np.all(r.omega[after] > 0.0) and np.all(np.diff(r.theta[after]) > 0.0)
    # while stuck the current follows its RL exponential exactly
    i_rl = BASE.v_drive / p.Ra * (1.0 - np.exp(-t[before] * p.Ra / p.La))
    np.testing.assert_allclose(r.current[before], i_rl, rtol=1e-12, atol=1e-15)


def test_stuck_intervals_hold_still_while_the_net_torque_is_within_tc():
    spec = replace(BASE, Tc=2e-3)
    r = simulate(spec, T)
    p = spec.params
    stuck = r.omega == 0.0
    assert stuck.sum() >= 20                              # this Tc parks the pinion at every reversal
    net = p.Kt * r.current - p.spring_torque_per_rad * r.theta
    assert np.all(np.abs(net[stuck]) <= spec.Tc * (1 + 1e-9))
    # each stuck run keeps theta bit-identical and ends with the pinion moving again
    edges = np.flatnonzero(np.diff(stuck.astype(int)))
    runs = np.split(np.arange(len(T)), edges + 1)
    runs = [idx for idx in runs if stuck[idx[0]]]
    assert len(runs) >= 5
    for idx in runs:
        assert np.all(r.theta[idx] == r.theta[idx[0]])
        if idx[-1] + 1 < len(T):
            assert r.omega[idx[-1] + 1] != 0.0


def test_continuous_guard_switches_exactly_at_the_guard():
    spec = replace(BASE, Tc=6e-4, gap=0.1)
    plant = new_plant(*plant_constants(spec))
    x = (0.0, 0.0, 0.0)
    reset(plant, x)
    t, hit = 0.0, False
    while not hit:
        x, t, hit = advance(plant, x, t, t + 0.05, spec.v_drive, 1, spec.guard_rad)
    assert abs(x[2] / spec.params.R - spec.guard_rad) < 1e-12
    assert 0.5 < t < 2.0


def test_continuous_guard_switches_between_samples_not_at_them():
    spec = replace(BASE, Tc=6e-4)
    r = simulate(spec, T, guard="continuous")
    s = simulate(spec, T)
    assert r.switches >= 10
    flips = np.flatnonzero(np.diff(r.dir.astype(int)) != 0) + 1
    # the command has already flipped at the first sample past the crossing...
    assert all(abs(r.theta[k - 1]) < spec.guard_rad for k in flips)
    # ...so the continuous variant overshoots less than the sketch's sampled guard
    assert r.theta.max() < s.theta.max()


@pytest.mark.parametrize("seed", range(6))
def test_random_effect_mixes_and_initial_states_match_reference_plant(seed):
    # any combination discovery may try: effects at random values in their BOUNDS-ish ranges,
    # from a random initial state, either guard
    rng = np.random.default_rng(100 + seed)
    p = BASE.params
    spec = replace(BASE, Tc=float(rng.uniform(0, 4e-3)), gap=float(rng.uniform(0, 0.5)),
                   Td=float(rng.uniform(0, 0.2)), I0=float(rng.uniform(-0.1, 0.1)), v_drive=float(rng.uniform(3, 6)),
                   params=p.with_(b=float(rng.uniform(0, 3e-3)), J=p.J + float(rng.uniform(0, 3e-3)),
                                  K1=p.K1 * float(rng.uniform(0.3, 3)), K2=p.K2 * float(rng.uniform(0.3, 3))))
    t = jittered_times(200, seed=seed)
    # |theta0| < 0.7 rad: inside the guards (started beyond one, the two continuous-guard controllers differ:
    # this one applies the guard condition at once, the reference waits for a crossing)
    x0 = (float(rng.uniform(-0.2, 0.2)), float(rng.uniform(-1, 1)), float(rng.uniform(-0.03, 0.03)))
    guard = ("sampled", "continuous")[seed % 2]
    _close(simulate(spec, t, x0=x0, guard=guard), simulate_reference(spec, t, x0=x0, guard=guard))


def test_more_step_lengths_than_the_cache_keeps_match_reference_plant():
    # 900 distinct spacings, each used twice: more lengths than the plant's step table keeps (STEP_FILL),
    # so the later ones are built at every use
    from pipeline.model.nonsmooth import STEP_FILL
    rng = np.random.default_rng(12)
    spacings = rng.uniform(0.045, 0.055, 900)
    assert len(spacings) > STEP_FILL
    t = np.concatenate([[0.0], np.cumsum(np.tile(spacings, 2))])
    spec = replace(BASE, **CASES["all_together"])
    _close(simulate(spec, t), simulate_reference(spec, t))


def test_a_run_does_not_depend_on_the_runs_before_it():
    # the step table is kept across a plant's runs; a step is taken with the same matrices cached or not,
    # so a run gives the same bits on a fresh plant and after runs on other instants filled the table
    from pipeline.model.nonsmooth import plant_constants
    spec = replace(BASE, **CASES["all_together"], torque=1e-3)
    t = jittered_times(200, seed=3)
    plant_constants.cache_clear()
    fresh = simulate(spec, t, x0=(0.05, 0.3, 0.004))
    for seed in range(4, 8):
        simulate(spec, jittered_times(300, seed=seed))
    again = simulate(spec, t, x0=(0.05, 0.3, 0.004))
    for name in ("theta", "omega", "current", "dir"):
        assert np.array_equal(getattr(fresh, name), getattr(again, name)), name


def test_a_dead_zone_narrower_than_rounding_runs_as_none():
    # a fit at its bound left a backlash of 1.6e-17 rad beside a 5 us loop delay (a start estimate's pulse
    # response, the instants to the bit): the play's edges sit within the closed form's rounding of the
    # state, where the root finder had no bracket left and divided by zero
    p = BASE.params.with_(J=0.0009917283571809839, Ke=1.1459, Kt=0.01819, La=18.138, Ra=2.59, K1=0.8682,
                          K2=0.8682, b=0.00077)
    spec = replace(BASE, params=p, v_drive=6.33, guard_rad=0.9424777960769379, period_s=0.01,
                   gap=1.6164693956261088e-17, Td=5.058621511757213e-06, v_supply=6.33)
    t = np.array([0.0004949413784882423, 0.0004999999999999996, 0.010499999999999999])
    log = np.array([1, 0, 0], dtype=np.int8)
    narrow = simulate(spec, t, dir_log=log, closed_loop=False)
    none = simulate(replace(spec, gap=0.0), t, dir_log=log, closed_loop=False)
    assert np.allclose(narrow.theta, none.theta, rtol=0.0, atol=1e-12)
    assert np.allclose(narrow.current, none.current, rtol=0.0, atol=1e-12)
