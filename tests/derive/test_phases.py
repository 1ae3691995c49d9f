"""Phases and the inferred command, against the virtual rig's true mode sequence."""

import math

import numpy as np
import pytest

from pipeline.derive.phases import infer_dir, motor_onset, phase_bounds, phase_table, reversal_indices
from pipeline.derive.velocity import savgol_velocity
from tests.derive.rigdata import rig_run

GUARD = 2 * math.pi * 0.15
COUNT = 2 * math.pi / 6533.12


def modes(dirs):
    return [int(dirs[s]) for s in phase_bounds(dirs)]


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_inferred_phases_match_the_true_mode_sequence(seed):
    sig, cfg, rec = rig_run(seed=seed, log_dir=False)
    t, theta = sig["t_s"].to_numpy(), sig["theta_rad"].to_numpy()
    true = rec.truth["dir"].to_numpy()
    got = infer_dir(t, theta, cfg.controller.guard_rad)
    assert got.dtype == np.int8
    assert modes(got) == modes(true)                   # off (pre-roll), q1, q2, q1, ...
    assert modes(true)[:2] == [0, 1]
    # boundaries: exact, except where the rig's true angle was within one count of the guard at a
    # sample (the virtual rig decides on the true angle, a sketch and this inference on counts)
    diff = np.flatnonzero(got != true)
    true_theta = rec.truth["theta_rad"].to_numpy()
    assert all(abs(abs(true_theta[k]) - GUARD) < COUNT for k in diff)
    assert len(diff) <= 1


def test_logged_dir_gives_the_true_phases_exactly():
    sig, cfg, rec = rig_run(seed=2)
    t, theta = sig["t_s"].to_numpy(), sig["theta_rad"].to_numpy()
    dirs = sig["dir"].to_numpy()
    table = phase_table(t, theta, savgol_velocity(t, theta), None, dirs, cfg.controller.guard_rad)
    true = rec.truth["dir"].to_numpy()
    assert table["first_sample"].tolist() == phase_bounds(true).tolist()
    assert table["dir"].tolist() == modes(true)
    assert table["mode"].tolist() == [{1: 1, -1: 2, 0: 0}[d] for d in modes(true)]
    assert table["end_reason"].iloc[0] == "motor on" and table["end_reason"].iloc[-1] == "end of recording"
    guarded = table[table["end_reason"] == "guard"]
    assert len(guarded) == len(table) - 2 and guarded["ended_at_guard"].all()
    # a phase driving towards a guard reaches it; durations tile the recording
    assert (guarded["dir"] * guarded["theta_extreme_rad"] >= GUARD).all()
    assert table["duration_s"].sum() == pytest.approx(t[-1] - t[0])
    assert table["n_samples"].sum() == len(t)
    assert table["peak_current_a"].isna().all()


def test_start_in_q2_when_the_lower_guard_comes_first():
    t = np.arange(60) * 0.05
    theta = -0.03 * np.arange(60)                      # moving down from the first sample, reaches -0.94 at 32
    d = infer_dir(t, theta, GUARD)
    k = int(np.argmax(theta <= -GUARD))
    assert (d[:k] == -1).all() and (d[k:] == 1).all()
    assert reversal_indices(d).tolist() == [k]


def test_never_reaching_a_guard_is_one_phase_in_q1():
    t = np.arange(100) * 0.05
    theta = 0.5 * np.sin(t)
    d = infer_dir(t, theta, GUARD)
    assert (d == 1).all() and len(phase_bounds(d)) == 1


def test_motor_onset_from_the_cubic_start():
    t = np.arange(40) * 0.05
    on = 12
    theta = np.round(2.07 * np.clip(t - t[on], 0, None) ** 3 / COUNT) * COUNT   # c = Kt V / (6 La J)
    assert motor_onset(t, theta) == on
    assert motor_onset(t, np.zeros(40)) == 0                 # never moves: no onset to find
    assert (infer_dir(t, theta, GUARD)[:on] == 0).all()


def test_empty_and_mismatched():
    assert len(infer_dir(np.zeros(0), np.zeros(0), GUARD)) == 0
    with pytest.raises(ValueError):
        infer_dir(np.zeros(2), np.zeros(3), GUARD)


def test_an_angle_exactly_on_the_guard_reverses_the_command():
    """The sketch's rule is theta >= guard (MODEL.md): a sample exactly on the guard reverses, one a hair
    below does not; the phase that reached it ended at the guard."""
    g = 0.5
    t = np.arange(6) * 0.05
    on = np.array([0.0, 0.2, 0.4, g, 0.45, 0.3])
    below = np.array([0.0, 0.2, 0.4, np.nextafter(g, 0.0), 0.45, 0.3])
    d_on, d_below = infer_dir(t, on, g), infer_dir(t, below, g)
    assert d_on.tolist() == [1, 1, 1, -1, -1, -1]
    assert d_below.tolist() == [1, 1, 1, 1, 1, 1]
    phases = phase_table(t, on, np.gradient(on, t), None, d_on, g)
    assert phases["end_reason"].tolist() == ["guard", "end of recording"]
    assert phases["ended_at_guard"].tolist() == [True, False]
    logged = np.array([1, 1, 1, -1, -1, -1], dtype=np.int8)
    assert phase_table(t, below, np.gradient(below, t), None, logged, g)["end_reason"].iloc[0] == \
        "reversed before guard"


@pytest.mark.parametrize("seed", [0, 2])
def test_peak_current_has_the_commands_sign_and_is_near_the_truth(seed):
    """Against the rig's true current over the same samples: the extreme in the commanded direction."""
    from pipeline.derive.stage import derive_tables

    sig, cfg, rec = rig_run(seed=seed)
    phases = derive_tables(sig, cfg).phases
    true_i = rec.truth[(rec.truth["status"] == "ok") & (rec.truth["segment"] == 1)]["current_a"].to_numpy()
    errors = []
    for r in phases[(phases["dir"] != 0) & (phases["n_samples"] >= 6)].itertuples():
        seg = true_i[r.first_sample:r.first_sample + r.n_samples + 1]
        truth = r.dir * np.max(r.dir * seg)
        assert np.sign(r.peak_current_a) == np.sign(truth)
        assert r.end_reason != "guard" or np.sign(truth) == r.dir      # a whole phase drives its own sign
        errors.append(r.peak_current_a - truth)
    assert len(errors) >= 12
    assert np.sqrt(np.mean(np.square(errors))) < 0.025 and np.max(np.abs(errors)) < 0.06   # noise sigma 27 mA


def test_motor_onset_despite_a_settling_creep():
    """After a board reset's unpowered gap the pinion may still creep on its springs: the count moves by
    one a few samples in, the other way from the drive.  The onset is the drive's, not the creep's."""
    t = np.arange(80) * 0.05
    on = 40
    creep = 0.004 * t                                                 # rad: a count after ~0.6 s
    drive = -2.07 * np.clip(t - t[on], 0, None) ** 3
    theta = np.round((creep + drive) / COUNT) * COUNT
    assert theta[on - 30] != theta[0]                                  # the creep moved the count early
    assert abs(motor_onset(t, theta) - on) <= 1
    d = infer_dir(t, theta, GUARD)
    assert (d[:on - 1] == 0).all() and d[on + 1] == -1                 # and it drives down, as the angle goes
