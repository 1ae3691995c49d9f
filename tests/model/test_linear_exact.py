"""The linear plant's exact discretisation against scipy solve_ivp, per control period, to 1e-8.

Both integrate the same automaton (same sampled controller, same loop-delay
schedule); the baseline uses DOP853 at rtol 1e-10 / atol 1e-12 over each
period, so agreement to 1e-8 rad, rad/s and A over 500 samples says the
matrix-exponential stepping (and its splitting of a step where a delayed
command arrives) is exact, not merely close.
"""

from dataclasses import replace

import numpy as np
import pytest

from pipeline.config import default_config
from pipeline.errors import PdrError
from pipeline.model.simulate import next_dir, sample_times, simulate
from tests.model.ivp_reference import jittered_times, simulate_ivp

TOL = 1e-8


def _close(a, b, tol=TOL):
    assert np.array_equal(a.dir, b.dir)
    for f in ("theta", "omega", "current", "current_measured"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=0, atol=tol, err_msg=f)


@pytest.fixture(scope="module")
def spec():
    return default_config().plant_spec()


@pytest.fixture(scope="module")
def t():
    return jittered_times(500, seed=3)


def test_closed_loop_uneven_spacing_matches_solve_ivp(spec, t):
    fast = simulate(spec, t)
    ref = simulate_ivp(spec, t)
    assert fast.switches >= 12
    _close(fast, ref)


def test_replay_with_loop_delay_and_offset_matches_solve_ivp(spec, t):
    d = simulate(spec, t).dir.copy()
    d[:7] = 0                                           # motor off before the sketch starts
    s = replace(spec, Td=0.037, I0=0.04)
    fast = simulate(s, t, dir_log=d, closed_loop=False)
    ref = simulate_ivp(s, t, dir_log=d, closed_loop=False)
    _close(fast, ref)
    assert np.all(fast.theta[:7] == 0.0)
    np.testing.assert_allclose(fast.current_measured - fast.current, 0.04)


def test_closed_loop_with_delay_longer_than_a_period_matches_solve_ivp(spec):
    t = jittered_times(120, seed=5)
    s = replace(spec, Td=0.12, params=spec.params.with_(b=1e-3))
    _close(simulate(s, t), simulate_ivp(s, t))


def test_leading_zeros_keep_the_motor_off_then_the_controller_takes_over(spec):
    t = sample_times(6.0, 0.05)
    log = np.zeros(len(t), dtype=int)
    log[10:] = -1                                        # first command at sample 10, in q2
    r = simulate(spec, t, dir_log=log, closed_loop=True)
    assert np.all(r.theta[:11] == 0.0) and np.all(r.dir[:10] == 0)
    assert r.dir[10] == -1 and r.theta[12] < 0.0
    _close(r, simulate_ivp(spec, t, dir_log=log, closed_loop=True))


def test_repeated_instants_are_a_zero_length_step(spec):
    t = np.array([0.0, 0.05, 0.05, 0.1])
    for s in (spec, replace(spec, Tc=6e-4, gap=0.1)):
        r = simulate(s, t)
        assert r.theta[1] == r.theta[2] and r.current[1] == r.current[2]
        assert r.current[3] > r.current[2] > 0.0


def test_next_dir_is_the_sketch_rule():
    g = 0.9
    assert next_dir(1, 0.95, g) == -1 and next_dir(1, 0.5, g) == 1
    assert next_dir(-1, -0.95, g) == 1 and next_dir(-1, 0.95, g) == -1
    assert next_dir(0, 0.0, g) == 1 and next_dir(0, 1.0, g) == -1


@pytest.mark.parametrize("kwargs, key", [
    ({"t": np.array([0.0, 0.05, 0.04])}, "t"),
    ({"t": np.array([0.0, np.nan])}, "t"),
    ({"guard": "sometimes"}, "guard"),
    ({"dir_log": np.zeros(3), "t": np.array([0.0, 0.05])}, "dir_log"),
    ({"closed_loop": False}, "dir_log"),
    ({"dir_log": np.array([0, 3]), "t": np.array([0.0, 0.05])}, "dir_log"),
])
def test_bad_arguments_are_refused_by_name(spec, kwargs, key):
    with pytest.raises(PdrError, match=key):
        simulate(spec, **kwargs)


def test_step_lengths_are_the_rounded_spacings_shared_by_index():
    from pipeline.model.linear import MAX_DISTINCT_LENGTHS, step_key, step_lengths
    t = jittered_times(300, seed=7)
    lengths, idx = step_lengths(t)
    assert len(lengths) == 2                              # 50 and 51 ms, float noise rounded away
    np.testing.assert_array_equal(lengths[idx], [step_key(h) for h in np.diff(t)])
    # more distinct spacings than the search keeps: one length per step, still each step's own
    rng = np.random.default_rng(8)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.04, 0.06, 3 * MAX_DISTINCT_LENGTHS))])
    lengths, idx = step_lengths(t)
    assert len(lengths) == len(t) - 1
    np.testing.assert_array_equal(lengths[idx], [step_key(h) for h in np.diff(t)])


def test_many_distinct_spacings_match_solve_ivp(spec):
    rng = np.random.default_rng(9)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.04, 0.06, 150))])
    _close(simulate(spec, t), simulate_ivp(spec, t))
    s = replace(spec, Td=0.03)
    _close(simulate(s, t), simulate_ivp(s, t))
