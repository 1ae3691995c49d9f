"""The sensor chain: millis() stamps, encoder counts, ACS712 + 10-bit ADC."""

from __future__ import annotations

import math

import numpy as np

from pipeline.rig import sensors


def test_millis_steps_by_50_or_51():
    true_ms, t_ms = sensors.loop_instants(2000, 0.05, 0.6, np.random.default_rng(0), start_ms=1.3)
    steps = set(np.diff(t_ms).tolist())
    assert steps == {50, 51}
    assert t_ms.dtype == np.int64 and np.all(t_ms == np.floor(true_ms))
    assert np.all(np.diff(true_ms) >= 50.0) and np.all(np.diff(true_ms) < 50.6)


def test_no_jitter_gives_a_steady_50():
    _, t_ms = sensors.loop_instants(100, 0.05, 0.0, np.random.default_rng(0), start_ms=0.0)
    assert set(np.diff(t_ms).tolist()) == {50}


def test_encoder_counts_are_integers_within_half_a_count():
    cpr = 6533.12
    theta = np.linspace(-2.0, 2.0, 1001)
    counts = sensors.encoder_counts(theta, cpr)
    assert counts.dtype == np.int64
    assert np.max(np.abs(counts * 2 * math.pi / cpr - theta)) <= 0.5 * 2 * math.pi / cpr + 1e-12
    # after a restart the counter reads zero at the restart angle
    assert sensors.encoder_counts(np.array([0.7]), cpr, theta_ref=0.7)[0] == 0


def test_adc_quantises_and_clips():
    v = np.array([-0.3, 0.0, 2.5, 2.504, 4.999, 5.0, 7.0])
    adc = sensors.adc_read(v, 5.0, 1024)
    assert adc.tolist() == [0, 0, 512, 512, 1023, 1023, 1023]
    assert sensors.adc_read(np.array([2.5049]), 5.0, 1024)[0] == 513


def test_part_zero_varies_around_2_5_v():
    rng = np.random.default_rng(1)
    zeros = np.array([sensors.part_zero_v(0.015, rng) for _ in range(2000)])
    assert abs(zeros.mean() - 2.5) < 0.002 and 0.013 < zeros.std() < 0.017
    assert sensors.part_zero_v(0.0, rng) == 2.5


def test_calibrated_zero_decodes_rest_to_zero_and_offset_to_i0():
    rng = np.random.default_rng(2)
    part, S = 2.513, 0.185
    v = sensors.acs712_volts(np.zeros(4000), part, S, 5.0 / 1024, rng)
    adc = sensors.adc_read(v, 5.0, 1024)
    decoded = (adc * 5.0 / 1024 - sensors.calibrated_zero_v(part, S, 0.0, 5.0, 1024)) / S
    assert abs(decoded.mean()) < 0.002                         # the calibration absorbs the floor's half step
    I0 = 0.12
    shifted = (adc * 5.0 / 1024 - sensors.calibrated_zero_v(part, S, I0, 5.0, 1024)) / S
    assert abs(shifted.mean() - I0) < 0.002                    # a mis-set zero reads I + I0
    assert 0.02 < decoded.std() < 0.04                         # noise ~ one ADC step, 26 mA
