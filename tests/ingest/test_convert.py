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
