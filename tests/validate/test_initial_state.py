"""The start of a recording, estimated from the data: x0 with its uncertainty, and the pre-log commands."""

import json

import numpy as np
import pandas as pd
import pytest

from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.model.simulate import sample_times, simulate
from pipeline.validate.compare import initial_state, simulate_both
from pipeline.estimate.commands_in_flight import command_sequences, lead_offsets
from pipeline.estimate.start import Start
from tests.validate.synthetic import AMPS_PER_STEP, COUNTS_PER_REV, synthetic_run

CFG = default_config()
COUNT = 2 * np.pi / COUNTS_PER_REV


def _opened_at(spec, cut: int, *, noise_a: float = AMPS_PER_STEP, seed: int = 0):
    """A closed-loop run from rest, seen through the encoder and a noisy 10-bit current sensor,
    whose log opens at sample ``cut``: (kinematics, true x0 there, the true run)."""
    t = sample_times(24.95, spec.period_s)
    sim = simulate(spec, t)
    rng = np.random.default_rng(seed)
    theta = np.round(sim.theta / COUNT) * COUNT
    current = np.round((sim.current_measured + noise_a * rng.standard_normal(len(t))) / AMPS_PER_STEP) * AMPS_PER_STEP
    omega = np.concatenate([[0.0], np.diff(theta) / np.diff(t)])
    kin = pd.DataFrame({"t_s": t, "theta_rad": theta, "omega_rad_s": omega, "current_a": current,
                        "dir": sim.dir.astype(np.int8), "dir_inferred": False}).iloc[cut:].reset_index(drop=True)
    kin["t_s"] -= kin["t_s"].iloc[0]
    return kin, np.array([sim.current[cut], sim.omega[cut], sim.delta[cut]]), sim


def _switches(d: np.ndarray) -> np.ndarray:
    return np.flatnonzero((d[1:] != d[:-1]) & (d[:-1] != 0)) + 1


def test_a_recording_opened_mid_motion_starts_where_the_rig_was():
    spec = CFG.plant_spec()
    kin, truth, _ = _opened_at(spec, 137)
    assert abs(kin["current_a"].iloc[0]) > 0.08 or abs(kin["omega_rad_s"].iloc[0]) > 0.1   # not at rest
    start = initial_state(kin, spec)
    err = np.abs(np.array(start.x0) - truth)
    assert np.all(err <= np.array([3e-3, 0.02, 2e-5]))              # 3 mA, 0.02 rad/s, a fifth of a count
    assert np.all(np.array(start.sigma) > 0)
    assert np.all(err <= 3 * np.array(start.sigma) + np.array([1e-4, 1e-3, 1e-6]))
    assert start.commands == ()                                      # no loop delay: nothing in flight


def test_a_noisy_first_current_reading_does_not_become_the_initial_current():
    spec = CFG.plant_spec()
    kin, truth, _ = _opened_at(spec, 0, noise_a=3 * AMPS_PER_STEP, seed=2)
    kin.loc[0, "current_a"] = 0.25                                   # three sigmas of 3x the sensor noise
    start = initial_state(kin, spec)
    assert truth[0] == 0.0
    assert abs(start.x0[0]) < 0.02
    replay = simulate_both(spec, kin, start)["replay"]
    assert np.sqrt(np.mean((replay.theta - kin["theta_rad"]) ** 2)) < 2 * COUNT


def test_pre_log_commands_fill_the_loop_delay():
    assert lead_offsets(0.0, 0.05).size == 0
    np.testing.assert_allclose(lead_offsets(0.1, 0.05), [-0.1, -0.05])
    np.testing.assert_allclose(lead_offsets(0.13, 0.05), [-0.13, -0.1, -0.05])
    assert len(command_sequences(2)) == 9 and len(command_sequences(0)) == 1
    assert all(sum(a != b for a, b in zip(c[:-1], c[1:])) <= 1 for c in command_sequences(5))


@pytest.mark.parametrize("after", [1, 3])
def test_commands_in_flight_under_a_loop_delay_are_estimated(after):
    spec = CFG.plant_spec((make_effect("loop_delay", {"Td": 0.1}),))
    t = sample_times(24.95, spec.period_s)
    d = simulate(spec, t).dir
    cut = int(_switches(d)[3] + after)
    kin, truth, sim = _opened_at(spec, cut, seed=5)
    start = initial_state(kin, spec)
    in_flight = tuple(int(v) for v in sim.dir[cut - 2:cut])
    if after == 3:                                                   # nothing reversed in flight: unambiguous
        assert start.commands == in_flight
        assert np.all(np.abs(np.array(start.x0) - truth) <= np.array([3e-3, 0.02, 2e-5]))
    # a reversal in flight and a different initial current explain the first samples almost
    # equally well: whichever is chosen, the interval covers the truth and both ways fit
    assert np.all(np.abs(np.array(start.x0) - truth) <= 3 * np.array(start.sigma) + np.array([1e-3, 0.01, 1e-5]))
    sims = simulate_both(spec, kin, start)
    first = slice(0, 40)                                             # two seconds
    for way in ("replay", "closed_loop"):
        assert np.sqrt(np.mean((sims[way].theta[first] - kin["theta_rad"][first]) ** 2)) < 2 * COUNT
    at_rest = Start.given((0.0, 0.0, float(kin["theta_rad"].iloc[0]) * spec.params.R))
    naive = at_rest.simulate(spec, kin["t_s"].to_numpy(), kin["dir"].to_numpy(), closed_loop=False)
    assert np.sqrt(np.mean((naive.theta[first] - kin["theta_rad"][first]) ** 2)) > 20 * COUNT


@pytest.mark.parametrize("delay", [0.0, 0.1])
def test_a_constant_load_torque_is_counted_once_in_the_superposition(delay):
    """At rest with the motor off, a plant under a constant torque still moves: the unit responses
    are taken relative to that motion, else each one carries the torque again and the start lands
    far from the rig (an 0.0019 N m load once left a randomised recording's first 2 s 0.6 rad off)."""
    effects = (make_effect("constant_load_torque", {"Tl": 1.9e-3}),)
    if delay:
        effects += (make_effect("loop_delay", {"Td": delay}),)
    spec = CFG.plant_spec(effects)
    kin, truth, _ = _opened_at(spec, 137, seed=4)
    start = initial_state(kin, spec)
    assert np.all(np.abs(np.array(start.x0) - truth) <= np.array([3e-3, 0.02, 2e-5]))
    replay = simulate_both(spec, kin, start)["replay"]
    assert np.sqrt(np.mean((replay.theta[:40] - kin["theta_rad"][:40]) ** 2)) < 2 * COUNT


def test_a_coulomb_plant_is_refined_on_the_full_simulation():
    spec = CFG.plant_spec((make_effect("coulomb_friction", {"Tc": 1.5e-3}),))
    assert not spec.is_linear
    kin, truth, _ = _opened_at(spec, 150, seed=3)
    start = initial_state(kin, spec)
    assert np.all(np.abs(np.array(start.x0) - truth) <= np.array([0.01, 0.1, 1e-4]))


def test_validation_json_reports_the_estimated_start_with_its_uncertainty(tmp_path):
    from pipeline.validate.stage import validate_run

    spec = CFG.plant_spec()
    kin, truth, _ = _opened_at(spec, 137)
    paths = synthetic_run(tmp_path / "processed", kin=kin, cfg=CFG)
    validate_run(paths, rrd=False, png=False)
    doc = json.loads(paths.validation.read_text())["initial_state"]
    x0 = [doc[k] for k in ("current_a", "omega_rad_s", "delta_m")]
    assert np.all(np.abs(np.array(x0) - truth) <= np.array([3e-3, 0.02, 2e-5]))
    assert all(doc["sigma"][k] > 0 for k in ("current_a", "omega_rad_s", "delta_m"))
    assert doc["pre_log_commands"] == []


@pytest.mark.parametrize("cut", [137, 170])
def test_a_backlash_plant_opened_mid_motion_starts_where_the_rig_was(cut):
    """Unit responses superposed through a dead zone miss, and inflate their own misfit weights;
    the full simulation must be checked against the superposition sample by sample, at the noise."""
    spec = CFG.plant_spec((make_effect("backlash", {"gap": 0.07}),))
    kin, truth, _ = _opened_at(spec, cut, seed=4)
    start = initial_state(kin, spec)
    assert np.all(np.abs(np.array(start.x0) - truth) <= np.array([0.01, 0.1, 1e-4]))


def test_a_constant_load_torque_is_not_superposed_once_per_unit_state():
    """The load torque drives the plant even from rest with the motor off; the unit responses must not
    each carry that forced response, or the superposed start is off by amperes."""
    spec = CFG.plant_spec((make_effect("constant_load_torque", {"Tl": -1.7e-3}),))
    kin, truth, _ = _opened_at(spec, 137, seed=5)
    start = initial_state(kin, spec)
    assert np.all(np.abs(np.array(start.x0) - truth) <= np.array([3e-3, 0.02, 2e-5]))


def test_a_row_lost_at_a_reversal_in_the_first_seconds_does_not_bend_the_start():
    """The sketch reversed at a row lost over serial: the estimate simulates the lost instant with the
    command the sketch's rule gives on the measured angle, as the replay does, not the old command held
    across the gap (a recording opened mid-run was 0.08 rad and 0.07 A off and decayed over 40 s)."""
    spec = CFG.plant_spec()
    kin, truth, _ = _opened_at(spec, 137)
    first = _switches(kin["dir"].to_numpy())[0]
    assert kin["t_s"].iloc[first] < 2.0                              # inside the estimate's window
    lossy = kin.drop(index=first).reset_index(drop=True)
    start = initial_state(lossy, spec)
    err = np.abs(np.array(start.x0) - truth)
    assert np.all(err <= np.array([3e-3, 0.02, 6e-5]))              # 3 mA, 0.02 rad/s, half a count
    replay = simulate_both(spec, lossy, start)["replay"]
    window = lossy["t_s"].to_numpy() < 2.0
    assert np.sqrt(np.mean((replay.theta - lossy["theta_rad"])[window] ** 2)) < 1.5 * COUNT


def test_a_lost_row_between_agreeing_commands_held_that_command():
    """A row lost over serial: when the commands logged on both sides agree the sketch held it (a
    reversal and back needs both guards); without the measured angle, only a gap at a reversal is left
    to the model's controller."""
    from pipeline.model import loop
    from pipeline.model.simulate import with_lost_samples

    t = np.array([0.0, 0.05, 0.15, 0.2, 0.3, 0.35, 0.4])
    d = np.array([1, 1, 1, -1, -1, -1, -1], dtype=np.int8)
    _, held, kept = with_lost_samples(t, d)
    assert held.tolist() == [1, 1, 1, 1, -1, -1, -1, -1, -1]      # the gap 0.05-0.15 held +1, 0.2-0.3 held -1
    gap_at_reversal = np.array([1, 1, -1, -1, -1, -1, -1], dtype=np.int8)
    still = with_lost_samples(t, gap_at_reversal)[1]
    assert still[2] == loop.UNKNOWN and still[5] == -1           # 0.05 -> 0.15 reversed: the model decides


def test_a_reversal_at_a_lost_row_is_decided_on_the_measured_angle():
    """A lost row across a reversal: the sketch reversed where its own count reached the guard, which
    the measured angle either side tells (interpolated), whatever frame the model's angle is in."""
    from pipeline.model.simulate import with_lost_samples

    t = np.array([0.0, 0.1, 0.2, 0.4, 0.5, 0.6])              # the row at 0.3 lost
    d = np.array([1, 1, 1, -1, -1, -1], dtype=np.int8)
    rising = 0.5 + 2.0 * t                                    # 1.1 at the lost row: past a 1.0 guard
    assert with_lost_samples(t, d, rising, 1.0)[1][3] == -1
    late = 0.2 + 2.0 * t                                      # 0.8 there: it reversed only at 0.4
    assert with_lost_samples(t, d, late, 1.0)[1][3] == 1
