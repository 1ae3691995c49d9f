"""simulate_batch equals one simulate call per parameter set."""

from dataclasses import replace

import numpy as np
import pytest

from pipeline.config import default_config
from pipeline.errors import PdrError
from pipeline.model.batch import simulate_batch, spec_columns
from pipeline.model.params import state_matrices_of
from pipeline.model.simulate import simulate
from tests.model.ivp_reference import jittered_times

BASE = default_config().plant_spec()
T = jittered_times(300, seed=21)
FIELDS = ("theta", "omega", "current", "current_measured", "delta", "u")


def _linear_sets(n=24, seed=0):
    rng = np.random.default_rng(seed)
    return [replace(BASE, params=BASE.params.with_(b=float(b), J=float(j), K1=float(k), K2=float(k)),
                    v_drive=float(v), Td=float(td), I0=float(i0))
            for b, j, k, v, td, i0 in zip(rng.uniform(3e-4, 2e-3, n), rng.uniform(4e-4, 2.5e-3, n),
                                          rng.uniform(0.6, 1.4, n), rng.uniform(4.5, 6.0, n),
                                          rng.choice([0.0, 0.0, 0.02, 0.05, 0.13], n), rng.uniform(-0.1, 0.1, n))]


def _equal(batch, singles):
    assert batch.theta.shape == (len(singles), len(T)) and len(batch) == len(singles)
    for i, r in enumerate(singles):
        np.testing.assert_array_equal(batch.dir[i], r.dir)
        for f in FIELDS:
            np.testing.assert_allclose(getattr(batch, f)[i], getattr(r, f), rtol=0, atol=1e-11, err_msg=f)
        assert np.array_equal(batch.result(i).dir, r.dir)


def _same_bits(specs, t, **kw):
    """simulate_batch equals one simulate call per set in every signal, to the last bit."""
    batch = simulate_batch(specs, t, **kw)
    for i, s in enumerate(specs):
        r = simulate(s, t, **kw)
        for f in FIELDS + ("dir",):
            assert np.array_equal(getattr(batch, f)[i], getattr(r, f)), f
    return batch


def test_closed_loop_batch_equals_single_calls():
    specs = _linear_sets()
    batch = simulate_batch(specs, T)
    _equal(batch, [simulate(s, T) for s in specs])
    assert len({int(np.sum(np.diff(batch.dir[i]) != 0)) for i in range(len(specs))}) > 1   # sets really differ


def test_replay_batch_with_leading_zeros_equals_single_calls():
    specs = _linear_sets(seed=1)
    log = simulate(BASE, T).dir.copy()
    log[:4] = 0
    for closed in (False, True):
        batch = simulate_batch(specs, T, dir_log=log, closed_loop=closed, x0=(0.01, 0.2, 0.003))
        _equal(batch, [simulate(s, T, dir_log=log, closed_loop=closed, x0=(0.01, 0.2, 0.003)) for s in specs])


def test_nonsmooth_sets_fall_back_to_single_calls():
    specs = [replace(BASE, Tc=6e-4), replace(BASE, gap=0.1, Td=0.05), BASE]
    _equal(simulate_batch(specs, T), [simulate(s, T) for s in specs])
    _equal(simulate_batch(specs, T, guard="continuous"), [simulate(s, T, guard="continuous") for s in specs])


@pytest.mark.parametrize("where", [5, 120])
def test_one_nonsmooth_set_in_any_threads_share_sends_the_batch_to_single_calls(where):
    # three blocks, two threads: a Coulomb set in the first block or the last (where each thread starts) sends
    # the whole batch down the single-call path
    specs = _linear_sets(n=130, seed=4)
    specs[where] = replace(specs[where], Tc=6e-4)
    batch = simulate_batch(specs, T, threads=2)
    _equal(batch, [simulate(s, T) for s in specs])
    assert batch.I0[where] == specs[where].I0 and batch.v_drive[-1] == specs[-1].v_drive


def test_empty_batch_is_refused():
    with pytest.raises(PdrError, match="specs"):
        simulate_batch([], T)


def _stacked_state_matrices(specs):
    return state_matrices_of(*spec_columns(specs)[:9])


def test_stacked_state_matrices_are_the_per_set_matrices():
    # spec_columns reads the parameters in MATRIX_PARAMS order: the stacked A, B are each set's own
    specs = _linear_sets(n=5, seed=3)
    A, B = _stacked_state_matrices(specs)
    for i, s in enumerate(specs):
        a, b = s.params.state_matrices()
        np.testing.assert_array_equal(A[i], a)
        np.testing.assert_array_equal(B[i], b)


def test_delay_longer_than_several_steps_and_a_repeated_instant_equal_single_calls():
    t = np.concatenate([T[:40], T[39:80]])                 # one zero-length step
    specs = [replace(s, Td=td) for s, td in zip(_linear_sets(n=4, seed=4), (0.0, 0.03, 0.26, 0.5))]
    _same_bits(specs, t)


def test_step_matrices_match_scipy_expm():
    from scipy.linalg import expm

    from pipeline.model.linear import phi_gamma
    specs = _linear_sets(n=6, seed=5)
    A, B = _stacked_state_matrices(specs)
    h = np.array([0.05, 0.051, 0.0, 0.013, 0.2, 0.05])
    for i in range(len(specs)):
        P = phi_gamma(A[i], B[i], h[i])
        M = np.zeros((4, 4))
        M[:3, :3], M[:3, 3] = A[i] * h[i], B[i] * h[i]
        E = expm(M)
        np.testing.assert_allclose(P[:9].reshape(3, 3), E[:3, :3], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(P[9:], E[:3, 3], rtol=1e-12, atol=1e-14)


def test_batch_is_the_single_call_to_the_last_bit():
    # both run the same compiled automaton, so not even rounding may differ
    specs = _linear_sets(seed=6)
    log = simulate(BASE, T).dir.copy()
    for kw in ({}, {"dir_log": log, "closed_loop": False}):
        _same_bits(specs, T, **kw)


def test_undelayed_closed_loop_lanes_are_the_single_call_to_the_last_bit():
    # all sets without loop delay, closed loop: the lanes kernel (sets side by side, vectorised) runs them;
    # 23 sets leave a remainder after the 4-wide vectors, the log's leading zeros a stretch before the guard
    specs = [replace(s, Td=0.0) for s in _linear_sets(n=23, seed=7)]
    log = simulate(BASE, T).dir.copy()
    log[:5] = 0
    for kw in ({}, {"dir_log": log, "x0": (0.01, 0.2, 0.003)}, {"dir0": -1}):
        batch = _same_bits(specs, T, **kw)
        assert batch.dir.dtype == np.int8
        for i, s in enumerate(specs):
            assert np.array_equal(batch.result(i).theta, simulate(s, T, **kw).theta)
    assert len({int(np.sum(np.diff(batch.dir[i]) != 0)) for i in range(len(specs))}) > 1


def test_guard_threshold_is_the_least_delta_reaching_the_guard():
    # the lanes decide by d * delta >= threshold instead of d * (delta / R) >= guard: the same answer always
    from pipeline.model.lanes import guard_threshold
    rng = np.random.default_rng(8)
    for R, g in zip(rng.uniform(1e-3, 5e-2, 300), rng.uniform(0.1, 3.0, 300)):
        x = guard_threshold(R, g)
        assert x / R >= g and np.nextafter(x, -np.inf) / R < g
        for dl in x + np.arange(-40, 41) * np.spacing(x):
            assert (dl / R >= g) == (dl >= x) and (-dl / R <= -g) == (-(-dl) >= x)


def test_irregular_instants_with_many_split_lengths_are_the_single_call_to_the_last_bit():
    # spacings of 40-60 ms: each set meets more split lengths than its cache holds (computed again on a miss),
    # delays from none to several steps, more sets than one chunk of side-by-side exponentials
    rng = np.random.default_rng(9)
    t = np.cumsum(rng.integers(40, 61, 200)) / 1000.0
    delays = rng.choice([0.0, 0.013, 0.07, 0.21], 70)
    specs = [replace(s, Td=float(td)) for s, td in zip(_linear_sets(n=70, seed=10), delays)]
    log = simulate(BASE, t).dir.copy()
    for kw in ({}, {"dir_log": log, "closed_loop": False}):
        _same_bits(specs, t, **kw)


def test_side_by_side_exponentials_are_phi_gamma_to_the_last_bit():
    # lanes needing different numbers of squarings share a chunk; more lanes than one chunk
    from pipeline.model.linear import LANE_CHUNK, phi_gamma, phi_gamma_lanes
    specs = _linear_sets(n=50, seed=11)
    A, B = _stacked_state_matrices(specs)
    rng = np.random.default_rng(12)
    sets = rng.integers(0, len(specs), 3 * LANE_CHUNK + 5)
    h = rng.choice([0.0, 1e-4, 0.013, 0.05, 0.051, 0.3, 2.0], len(sets))
    out = np.empty((12, len(sets)))
    phi_gamma_lanes(A, B, sets, h, out)
    for i, (q, hh) in enumerate(zip(sets, h)):
        assert np.array_equal(out[:, i], phi_gamma(A[q], B[q], hh))


def test_short_recordings_a_dead_drive_and_repeated_instants_are_the_single_call_to_the_last_bit():
    specs = [replace(BASE, Td=td, v_drive=v) for td, v in ((0.0, 6.0), (0.03, 5.0), (0.2, 0.0), (0.05, 6.0))]
    for t in (np.array([0.0]), np.array([0.0, 0.05]), np.array([0.0, 0.0, 0.0, 0.05, 0.05, 0.1])):
        alternating = np.where(np.arange(len(t)) % 3 == 0, 1, -1).astype(np.int8)
        for kw in ({}, {"dir_log": alternating, "closed_loop": False}, {"dir_log": np.zeros(len(t), np.int8)}):
            _same_bits(specs, t, **kw)


def test_a_command_decided_while_another_is_on_its_way_is_the_single_call_to_the_last_bit():
    # the controller starts at sample 1 with the pinion past the guard, so it reverses at once while the
    # first command is still travelling: two commands on their way (the ring), in and past the start
    specs = [replace(s, Td=td) for s, td in zip(_linear_sets(n=12, seed=14), (0.13, 0.3, 0.02, 0.0) * 3)]
    log = np.zeros(len(T), np.int8)
    log[1] = 1
    x0 = (0.0, 0.0, 2.0 * BASE.params.R * BASE.guard_rad)
    batch = _same_bits(specs, T, dir_log=log, x0=x0)
    assert all(batch.dir[i][2] == -1 for i in range(len(specs)))        # reversed one sample after the start


def test_blocks_of_undelayed_delayed_and_mixed_sets_are_the_single_call_to_the_last_bit():
    # the batch runs 64 sets at a time: a block with no loop delay, one where every set has one, and a
    # last block of three sets (the rest of it padding)
    sets = _linear_sets(n=131, seed=15)
    specs = ([replace(s, Td=0.0) for s in sets[:64]] + [replace(s, Td=0.03 + 0.001 * i) for i, s in
                                                         enumerate(sets[64:128])] + sets[128:])
    _same_bits(specs, T)


def test_a_result_kept_is_not_overwritten_by_the_next_batch():
    # the output memory of a batch is handed out again only once nothing refers to its result
    first_specs, second_specs = _linear_sets(n=10, seed=16), _linear_sets(n=10, seed=17)
    first = simulate_batch(first_specs, T)
    omega = first.omega.copy()
    second = simulate_batch(second_specs, T)
    assert not np.shares_memory(first.omega, second.omega)
    np.testing.assert_array_equal(first.omega, omega)
    for i, s in enumerate(first_specs):
        assert np.array_equal(first.delta[i], simulate(s, T).delta)


def test_a_dropped_result_leaves_its_memory_to_the_next_batch():
    specs = _linear_sets(n=10, seed=18)
    address = simulate_batch(specs, T).omega.__array_interface__["data"][0]
    again = simulate_batch(specs, T)                  # the first result was dropped at once
    assert again.omega.__array_interface__["data"][0] == address
    for i, s in enumerate(specs):
        assert np.array_equal(again.omega[i], simulate(s, T).omega)


def test_the_result_does_not_depend_on_the_threads():
    # each thread takes whole blocks of 64 sets and writes its own output columns; a thread count that is
    # not a whole number of at least 1 is refused by name
    sets = _linear_sets(n=200, seed=19)
    specs = [replace(s, Td=td) for s, td in zip(sets, np.tile([0.0, 0.03, 0.07, 0.0, 0.13], 40))]
    one = simulate_batch(specs, T, threads=1)
    omega, delta, dirs = one.omega.copy(), one.delta.copy(), one.dir.copy()
    del one
    for threads in (2, 3, 7):
        many = simulate_batch(specs, T, threads=threads)
        assert np.array_equal(many.omega, omega) and np.array_equal(many.delta, delta)
        assert np.array_equal(many.dir, dirs)
    for bad in (0, -2, 1.5, "2", True):
        with pytest.raises(PdrError, match="threads"):
            simulate_batch(specs, T, threads=bad)


def _lanes_call(specs, Y, dirs, counters, from_front):
    from pipeline.model.batch import ROW_GUARD, ROW_R, ROW_TD, ROW_V_DRIVE
    from pipeline.model.lanes import run_linear_lanes
    from pipeline.model.simulate import _plan
    columns = spec_columns(specs)
    A, B = state_matrices_of(*columns[:9])
    plan = _plan(specs[0], T, 24.95, 1, None, True, "sampled")
    run_linear_lanes(plan.t, A, B, columns[ROW_R], columns[ROW_GUARD], columns[ROW_V_DRIVE], columns[ROW_TD],
                     np.zeros(3), plan.log, plan.closed_loop, plan.start, plan.first, plan.dir0, Y, dirs, counters,
                     from_front)


def test_a_thread_takes_only_the_blocks_left_from_its_end():
    # threads share three counters (claimed, from the front, from the back): one thread alone from either end
    # runs every block the same; one arriving when all are claimed writes nothing.  150 sets: 3 blocks, and
    # each thread's last look at the claimed counter also counts
    from pipeline.model.lanes import lane_outputs
    specs = [replace(s, Td=td) for s, td in zip(_linear_sets(n=150, seed=23), np.tile([0.0, 0.05, 0.11], 50))]
    results = []
    for from_front in (True, False):
        Y, dirs = lane_outputs(len(specs), len(T))
        counters = np.zeros(3, dtype=np.int64)
        _lanes_call(specs, Y, dirs, counters, from_front)
        assert counters[0] == 4 and counters[1 if from_front else 2] == 3 and counters[2 if from_front else 1] == 0
        results.append((Y[:, :, :150].copy(), dirs[:, :150].copy()))
    assert np.array_equal(results[0][0], results[1][0]) and np.array_equal(results[0][1], results[1][1])
    assert np.array_equal(results[0][0][:, 2, :].T, simulate_batch(specs, T, threads=1).delta)
    Y, dirs = lane_outputs(len(specs), len(T))
    Y[:] = np.nan
    _lanes_call(specs, Y, dirs, np.array([3, 2, 1]), True)
    assert np.isnan(Y).all()


def test_the_default_threads_leave_out_a_core_another_task_is_running_on():
    # idle_cores counts the runnable tasks (/proc/loadavg): this test's own thread and a busy process
    import subprocess
    import sys
    import time

    from pipeline.model.batch import idle_cores, usable_cores
    cores = usable_cores()
    assert 1 <= idle_cores() <= cores
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.2)
        assert idle_cores() <= max(1, cores - 1)
    finally:
        busy.kill()
        busy.wait()
