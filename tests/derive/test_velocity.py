"""Velocity estimators: exact where they must be, and measured against the virtual rig's true velocity."""

import numpy as np
import pytest

from pipeline.derive.velocity import backward_difference, local_polyfit, savgol_velocity, smooth_by_phase
from tests.derive.rigdata import rig_run


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def test_savgol_is_exact_on_a_cubic_with_uneven_times():
    rng = np.random.default_rng(3)
    t = np.cumsum(0.05 + rng.uniform(0, 0.002, 40))
    theta = 0.3 - 1.2 * t + 0.7 * t ** 2 - 0.1 * t ** 3
    assert np.allclose(savgol_velocity(t, theta), -1.2 + 1.4 * t - 0.3 * t ** 2, atol=1e-9)
    assert np.allclose(local_polyfit(t, theta, 9, 3), theta, atol=1e-9)


def test_backward_difference_is_the_papers():
    t = np.array([0.0, 0.05, 0.101, 0.15])
    theta = np.array([0.0, 0.01, 0.03, 0.03])
    w = backward_difference(t, theta)
    assert w[1] == pytest.approx(0.2) and w[2] == pytest.approx(0.02 / 0.051) and w[3] == 0.0
    assert w[0] == w[1]


@pytest.mark.parametrize("n", [0, 1, 2, 3])
def test_short_inputs(n):
    t = np.arange(n) * 0.05
    theta = 0.1 * t
    for f in (backward_difference, savgol_velocity):
        w = f(t, theta)
        assert w.shape == (n,)
        if n >= 2:
            assert np.allclose(w, 0.1)


def test_smoothing_never_crosses_a_command_change():
    t = np.arange(40) * 0.05
    kink = np.where(t < 1.0, t, 2.0 - t)          # slope jumps at sample 20, like the current at a reversal
    starts = np.array([0, 20])
    assert np.allclose(smooth_by_phase(t, kink, starts, 15, 3), kink, atol=1e-9)
    assert not np.allclose(local_polyfit(t, kink, 15, 3), kink, atol=1e-3)


def test_rms_error_against_true_velocity_on_the_virtual_rig():
    """Figures (6 seeds, see velocity.py): backward 0.064 rad/s, Savitzky-Golay 0.0040 rad/s."""
    errors = {"backward": [], "savgol": []}
    for seed in range(3):
        sig, cfg, rec = rig_run(seed=seed)
        t, theta = sig["t_s"].to_numpy(), sig["theta_rad"].to_numpy()
        true = rec.truth["omega_rad_s"].to_numpy()
        errors["backward"].append(rms(backward_difference(t, theta) - true))
        errors["savgol"].append(rms(savgol_velocity(t, theta) - true))
    assert 0.05 < np.mean(errors["backward"]) < 0.08       # half-sample lag + count quantisation
    assert np.max(errors["savgol"]) < 0.006
    assert np.mean(errors["savgol"]) * 10 < np.mean(errors["backward"])
