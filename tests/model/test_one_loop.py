"""The controller loop is written once: replaying the commands a closed-loop run decided is the same
computation as that run, so the two agree to the last bit, on either plant stepper, with or without a
loop delay (before the loop was unified, replay and closed loop differed by ~1e-15)."""

import numpy as np
import pytest

from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.model.simulate import simulate

EFFECTS = {
    "linear": (),
    "linear, loop delay": (make_effect("loop_delay", {"Td": 0.037}),),
    "event-driven, delay": (make_effect("coulomb_friction", {"Tc": 8e-4}), make_effect("loop_delay", {"Td": 0.05})),
    "event-driven, load": (make_effect("backlash", {"gap": 0.06}), make_effect("constant_load_torque", {"Tl": 1e-3})),
}


@pytest.mark.parametrize("case", list(EFFECTS))
def test_replaying_the_closed_loops_commands_is_the_closed_loop_to_the_last_bit(case):
    spec = default_config().plant_spec(EFFECTS[case])
    t = np.cumsum(np.where(np.arange(400) % 3 == 0, 0.051, 0.050))
    x0 = (0.02, -0.3, 0.01)
    closed = simulate(spec, t, x0=x0)
    replay = simulate(spec, t, x0=x0, dir_log=closed.dir, closed_loop=False)
    assert closed.switches >= 5
    for f in ("theta", "omega", "current", "current_measured", "dir"):
        assert np.array_equal(getattr(closed, f), getattr(replay, f)), f


def test_lost_rows_are_simulated_and_decided_by_the_sketchs_rule():
    """A recording missing rows (one lost at a switch among them): replay on the logged samples with the
    lost instants put back and decided by the guard (on the model's angle, or on the measured one
    interpolated) equals the full closed-loop run at those samples."""
    from pipeline.model.loop import UNKNOWN
    from pipeline.model.simulate import with_lost_samples

    spec = default_config().plant_spec()
    t = np.arange(400) * 0.05
    full = simulate(spec, t)
    switch = int(np.flatnonzero(np.diff(full.dir) != 0)[2]) + 1       # the sample that decided a reversal
    lost = np.array([switch, 120, 121, 300])
    keep = np.setdiff1d(np.arange(len(t)), lost)
    t_loop, d_loop, kept = with_lost_samples(t[keep], full.dir[keep])
    assert np.allclose(t_loop, t) and np.array_equal(kept, keep)
    assert d_loop[switch] == UNKNOWN and np.array_equal(d_loop[keep], full.dir[keep])
    held_rows = lost[lost != switch]                                  # between equal commands: that one held
    assert np.array_equal(d_loop[held_rows], full.dir[held_rows])
    # with the measured angle, the sketch's rule on it decides the reversal, as the closed loop did
    _, by_angle, _ = with_lost_samples(t[keep], full.dir[keep], full.theta[keep], spec.guard_rad)
    assert np.array_equal(by_angle, full.dir)
    replay = simulate(spec, t_loop, dir_log=d_loop, closed_loop=False)
    assert np.array_equal(replay.dir, full.dir)                      # the lost reversal decided where it was
    np.testing.assert_allclose(replay.theta[kept], full.theta[keep], rtol=0, atol=1e-12)
    held = simulate(spec, t[keep], dir_log=full.dir[keep], closed_loop=False)   # the old way: hold over the gap
    assert np.max(np.abs(held.theta - full.theta[keep])) > 1e-3


def test_a_lost_reversal_on_the_guard_is_found_and_shifted_a_sample():
    """Where the angle interpolated at a lost instant lies within a band of the guard, the rule may be a
    sample off: the gap is reported, and ``shifted`` moves its reversal one instant (later, or earlier
    where the rule put it at the next logged sample); gaps between equal commands never move."""
    from pipeline.model.simulate import lost_reversals_on_guard, with_lost_samples

    spec = default_config().plant_spec()
    t = np.arange(400) * 0.05
    full = simulate(spec, t)
    switch = int(np.flatnonzero(np.diff(full.dir) != 0)[2]) + 1
    lost = np.array([switch, 120])
    keep = np.setdiff1d(np.arange(len(t)), lost)
    args = (t[keep], full.dir[keep], full.theta[keep], spec.guard_rad)
    gap = int(np.searchsorted(keep, switch)) - 1                     # the logged sample before the lost switch
    assert lost_reversals_on_guard(*args, band=0.05) == [gap]          # the reversal's gap, not the held one
    assert lost_reversals_on_guard(*args, band=1e-9) == []
    _, rule, _ = with_lost_samples(*args)
    _, moved, _ = with_lost_samples(*args, shifted=(gap,))
    assert rule[switch] == full.dir[switch] != full.dir[switch - 1]   # the rule reversed at the lost instant
    assert moved[switch] == full.dir[switch - 1]                      # shifted: a sample later, at the next logged one
    assert np.array_equal(np.delete(moved, switch), np.delete(rule, switch))
    held = int(np.searchsorted(keep, 120)) - 1
    assert np.array_equal(with_lost_samples(*args, shifted=(held,))[1], rule)


def test_a_lost_reversal_is_open_within_the_error_the_logged_angles_carry_into_the_interpolation():
    """The angle at a lost instant is interpolated through four logged ones, each off by up to ``band``
    (a count's rounding): mid-way through one lost row that moves it by up to 5/3 of ``band``, so a
    reversal is open while the interpolated angle is within that of the guard, and only then."""
    from pipeline.model.simulate import _angle_at, _lost_instants, lost_reversals_on_guard

    spec = default_config().plant_spec()
    t = np.arange(400) * 0.05
    full = simulate(spec, t)
    switch = int(np.flatnonzero(np.diff(full.dir) != 0)[2]) + 1
    keep = np.setdiff1d(np.arange(len(t)), [switch])
    args = (t[keep], full.dir[keep], full.theta[keep], spec.guard_rad)
    gap = int(np.searchsorted(keep, switch)) - 1
    at = _angle_at(t[keep], full.theta[keep], gap, _lost_instants(t[keep], gap, 1))
    off = abs(abs(float(at[0])) - spec.guard_rad)
    assert lost_reversals_on_guard(*args, band=off / 1.6) == [gap]
    assert lost_reversals_on_guard(*args, band=off / 1.7) == []


def test_without_gaps_the_instants_are_the_logged_ones():
    from pipeline.model.simulate import with_lost_samples

    t = np.cumsum(np.where(np.arange(200) % 3 == 0, 0.051, 0.050))
    d = np.ones(200, dtype=np.int8)
    t_loop, d_loop, kept = with_lost_samples(t, d)
    assert t_loop is t or np.array_equal(t_loop, t)
    assert np.array_equal(d_loop, d) and np.array_equal(kept, np.arange(200))


def test_filled_gaps_are_remembered_read_only_and_keyed_by_every_input():
    """A fit replays one recording hundreds of times; the gaps are filled once.  The shared result is
    read-only (a caller writing into it would change every later replay), and a different angle,
    command or guard is a different entry."""
    from pipeline.model.simulate import lost_samples_filled, with_lost_samples

    spec = default_config().plant_spec()
    t = np.arange(300) * 0.05
    full = simulate(spec, t)
    keep = np.setdiff1d(np.arange(len(t)), [40, 41, 150, 151, 152])
    args = (t[keep], full.dir[keep], full.theta[keep], spec.guard_rad)
    first, again = with_lost_samples(*args), with_lost_samples(*(np.copy(a) for a in args[:3]), args[3])
    assert all(a is b for a, b in zip(first, again))
    for got, want in zip(first, lost_samples_filled(*args)):
        assert np.array_equal(got, want) and not got.flags.writeable
    other_guard = with_lost_samples(*args[:3], 0.5 * spec.guard_rad)
    assert other_guard[1] is not first[1]
    assert with_lost_samples(*args[:2])[1] is not first[1]        # no angle: undecided reversals, another entry


@pytest.mark.parametrize("case", list(EFFECTS))
def test_a_prepared_replay_run_from_several_starts_is_each_start_simulated_alone(case):
    """``Prepared`` checks the arguments and builds the controller once (a start estimate tries a dozen
    starts under one command): each run is the same computation as ``simulate`` from that start, and a run
    leaves nothing behind for the next."""
    from pipeline.model.simulate import Prepared

    spec = default_config().plant_spec(EFFECTS[case])
    t = np.cumsum(np.where(np.arange(200) % 3 == 0, 0.051, 0.050))
    log = simulate(spec, t).dir
    prepared = Prepared.of(spec, t, dir_log=log, closed_loop=False)
    for x0 in ((0.0, 0.0, 0.0), (0.02, -0.3, 0.01), (0.0, 0.0, 0.0)):
        alone = simulate(spec, t, x0=x0, dir_log=log, closed_loop=False)
        run = prepared.run(x0)
        for f in ("t", "theta", "omega", "current", "current_measured", "dir"):
            assert np.array_equal(getattr(run, f), getattr(alone, f)), f


@pytest.mark.parametrize("case", list(EFFECTS))
def test_a_prepared_replay_under_another_command_is_that_command_simulated_alone(case):
    """``Prepared.under`` keeps the plant and the checked instants and swaps the command replayed (a start
    estimate tries several pre-log sequences on one window): the same computation as ``simulate`` under
    that command, and a command it cannot replay is refused as ``simulate`` refuses it."""
    from pipeline.errors import PdrError
    from pipeline.model.simulate import Prepared

    spec = default_config().plant_spec(EFFECTS[case])
    t = np.cumsum(np.where(np.arange(200) % 3 == 0, 0.051, 0.050))
    log = simulate(spec, t).dir
    other = -log
    other[:7] = 0                                    # the motor off for the first samples
    prepared = Prepared.of(spec, t, dir_log=log, closed_loop=False)
    for d, dir0 in ((other, -1), (log, 1)):
        alone = simulate(spec, t, x0=(0.01, 0.2, 0.0), dir0=dir0, dir_log=d, closed_loop=False)
        run = prepared.under(d, dir0=dir0).run((0.01, 0.2, 0.0))
        for f in ("t", "theta", "omega", "current", "current_measured", "dir"):
            assert np.array_equal(getattr(run, f), getattr(alone, f)), f
    with pytest.raises(PdrError, match="one command per sample"):
        prepared.under(log[:-1])
    with pytest.raises(ValueError, match="replay"):
        Prepared.of(spec, t, dir_log=log).under(log)        # a closed loop is not a replay


def test_a_motor_started_in_a_gap_of_lost_rows_is_found_and_started_a_sample_earlier():
    """Off before a gap, on after it: the motor started at the lost instant or at the next logged sample,
    and no rule of the sketch's says which.  The gap is reported; by default the start is the next logged
    sample's, and ``shifted`` starts it at the lost instant, which replays the rig exactly when it did."""
    from pipeline.model.simulate import lost_starts, with_lost_samples

    spec = default_config().plant_spec()
    t = np.arange(80) * 0.05
    d = np.zeros(len(t), dtype=np.int8)
    d[10:] = 1
    full = simulate(spec, t, dir_log=d, closed_loop=False)
    keep = np.setdiff1d(np.arange(len(t)), [10, 50])                  # the start's row lost, and one later
    args = (t[keep], d[keep], full.theta[keep], spec.guard_rad)
    assert lost_starts(t[keep], d[keep]) == [9]                        # the gap after sample 9, not the held one
    t_loop, rule, kept = with_lost_samples(*args)
    _, moved, _ = with_lost_samples(*args, shifted=(9,))
    assert rule[10] == 0 and moved[10] == 1
    assert np.array_equal(np.delete(moved, 10), np.delete(rule, 10))
    started_there = simulate(spec, t_loop, dir_log=moved, closed_loop=False)
    np.testing.assert_allclose(started_there.theta[kept], full.theta[keep], rtol=0, atol=1e-12)
    started_later = simulate(spec, t_loop, dir_log=rule, closed_loop=False)
    assert np.max(np.abs(started_later.theta[kept] - full.theta[keep])) > 1e-3
