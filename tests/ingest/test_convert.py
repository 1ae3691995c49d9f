"""Unit conversion at ingest (``pipeline.ingest.convert``)."""

from dataclasses import replace

import numpy as np

from pipeline.config import default_config
from pipeline.ingest.convert import estimate_zero, volts_per_step
from pipeline.rig.sensors import acs712_volts, adc_read


def test_an_automatic_zero_is_not_rounded_to_a_whole_adc_step():
    """Rest readings of a part whose zero sits 0.4 of a step above a code, with 1.4 steps of noise:
    the zero is found to a tenth of a step (the median of the integer codes is a whole code, 0.4 off:
    20 mA on the 20 A part, a sensor offset discovery would name)."""
    cfg = default_config()
    step = volts_per_step(cfg)
    zero = 512.4 * step
    rng = np.random.default_rng(4)
    adc = adc_read(acs712_volts(np.zeros(400), zero, 0.1, 1.4 * step, rng), 5.0, 1024)
    cfg = replace(cfg, current_sensor=replace(cfg.current_sensor, zero_v="auto"))
    got = estimate_zero({"adc": adc, "dir": np.zeros(400, dtype=np.int8)}, cfg, "r.csv")
    assert abs(got.zero_v - (zero - step / 2)) < 0.1 * step           # floor-quantised: half a step below


def test_an_automatic_zero_is_a_mean_of_the_rest_readings_blind_to_a_garbled_one():
    """Over 300 captures of 11 rest readings with one to two steps of noise, the zero's error is the
    mean's (sigma / sqrt(n)) within 15 %, and says so in its standard error; a mean of the middle half
    was up to 1.3 times that.  A garbled reading (code 0) among them moves it by less than a tenth of
    a step."""
    cfg = default_config()
    step = volts_per_step(cfg)
    auto = replace(cfg, current_sensor=replace(cfg.current_sensor, zero_v="auto"))
    rng = np.random.default_rng(11)
    errors, reported = [], []
    for _ in range(300):
        zero, sigma = (512 + rng.uniform()) * step, rng.uniform(1.0, 2.0) * step
        adc = adc_read(acs712_volts(np.zeros(11), zero, 0.1, sigma, rng), 5.0, 1024)
        got = estimate_zero({"adc": adc, "dir": np.zeros(11, dtype=np.int8)}, auto, "r.csv")
        errors.append((got.zero_v + step / 2 - zero) / (sigma / np.sqrt(11)))
        reported.append(got.standard_error_v / (sigma / np.sqrt(11)))
    assert np.std(errors) < 1.15 and abs(np.mean(errors)) < 0.2
    assert 0.8 < np.median(reported) < 1.1
    adc[3] = 0
    garbled = estimate_zero({"adc": adc, "dir": np.zeros(11, dtype=np.int8)}, auto, "r.csv")
    clean = np.delete(adc, 3) * step
    assert abs(garbled.zero_v - clean.mean()) < 0.1 * step and garbled.samples == 10
