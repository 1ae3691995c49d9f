"""Per-signal noise from the recording alone: white part, quantisation step, clock step."""

import numpy as np
import pytest

from pipeline.estimate.noise import clock_step, difference_noise, quantum, sample_instants, signal_noise, timing_noise

COUNT = 2 * np.pi / 6533.12            # one encoder count, rad
ADC_AMPS = 5.0 / 1024 / 0.185          # one ADC step of an ACS712-05B, A


def _swing(n: int = 500, dt: float = 0.05) -> np.ndarray:
    t = np.arange(n) * dt
    return np.sin(1.7 * t) + 0.3 * np.sin(3.2 * t + 1.0)       # the rig's two oscillation scales, rad


@pytest.mark.parametrize("sigma", [0.01, 0.1])
def test_white_noise_is_seen_through_a_fast_smooth_swing(sigma):
    rng = np.random.default_rng(3)
    y = _swing() + rng.normal(0.0, sigma, 500)
    assert difference_noise(y) == pytest.approx(sigma ** 2, rel=0.2)


def test_missing_values_cost_their_neighbours_only():
    rng = np.random.default_rng(4)
    y = _swing() + rng.normal(0.0, 0.05, 500)
    y[::37] = np.nan
    assert difference_noise(y) == pytest.approx(0.05 ** 2, rel=0.25)


def test_the_quantisation_step_is_read_off_the_data():
    theta = np.round(3.0 * _swing() / COUNT) * COUNT          # a fast encoder skips counts between samples
    assert quantum(theta) == pytest.approx(COUNT, rel=1e-9)
    adc = np.floor((2.5 + 0.185 * 0.4 * _swing()) * 1024 / 5.0 + np.random.default_rng(5).normal(0, 1, 500))
    current = (adc * 5.0 / 1024 - 2.4987) / 0.185             # the ingest's conversion, float rounding and all
    assert quantum(current) == pytest.approx(ADC_AMPS, rel=1e-9)
    assert quantum(_swing() + np.random.default_rng(6).normal(0.0, 1e-3, 500)) == 0.0


def test_a_quantised_signal_without_noise_is_never_below_its_quantisation():
    theta = np.round(0.02 * _swing() / COUNT) * COUNT         # creeps: most differences are 0
    assert signal_noise(theta) >= COUNT ** 2 / 12 * (1 - 1e-9)


def test_the_clock_step_comes_from_the_stamps():
    rng = np.random.default_rng(7)
    millis = np.floor(np.cumsum(50.0 + rng.uniform(0.0, 0.6, 500))) / 1000.0
    micros = np.floor(np.cumsum(50000.0 + rng.uniform(0.0, 600.0, 500))) / 1e6
    assert clock_step(millis) == pytest.approx(1e-3)
    assert clock_step(micros) == pytest.approx(1e-6)
    assert clock_step(np.arange(500) * 0.05) == 0.0            # a schedule, not a truncating clock
    omega = np.full(500, 2.0)
    assert timing_noise(omega, millis) == pytest.approx(4.0 * 1e-6 / 12.0)     # about the mid-step instant


def test_a_truncating_clock_samples_half_a_step_after_its_stamps():
    """millis() stamps floor(true instant): the instants are the stamps plus half a step on average,
    and a schedule's exact stamps are left alone."""
    rng = np.random.default_rng(3)
    true = np.cumsum(50.0 + rng.uniform(0.0, 0.6, 2000))
    millis = np.floor(true) / 1000.0
    lag = true / 1000.0 - sample_instants(millis)
    assert abs(np.mean(lag)) < 2e-5 and np.max(np.abs(lag)) <= 0.5e-3 + 1e-12
    schedule = np.arange(500) * 0.05
    assert np.array_equal(sample_instants(schedule), schedule)


@pytest.mark.parametrize("noise_steps", [0.5, 1.0, 2.0])
def test_quantised_noise_of_a_few_adc_codes_is_read_without_bias(noise_steps):
    """A 10-bit current of the 30 A part with noise of half a step to two steps: the floor is the
    variance of what is logged about the true current (noise and quantisation together).  The median
    scale of the differences read half a step's noise 32 % high and one step's 9 % low."""
    step = 5.0 / 1024 / 0.066
    t = np.arange(3000) * 0.05
    ratios = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        true = 0.8 * np.sin(1.7 * t + seed)
        logged = np.floor(true / step + rng.normal(0.0, noise_steps, len(t))) * step
        ratios.append(signal_noise(logged) / np.var(logged - true))
    assert np.mean(ratios) == pytest.approx(1.0, abs=0.03)
    assert max(abs(r - 1.0) for r in ratios) < 0.12
