"""Stacked effects on virtual-rig recordings: every hidden one named, none swapped for another."""

from pipeline.discover.stage import discover
from pipeline.model.effects import make_effect
from tests.discover.synthetic import rig_kinematics

NOISE_4X = 4 * 5.0 / 1024          # V: four ADC steps of sensor noise


def test_a_sensor_offset_of_about_one_noise_sigma_beside_a_loop_delay_is_named(tmp_path):
    """After the delay, the current's residual is the offset alone, ~1.4 noise variances per sample:
    too little for a stop at a few noise variances, many sigmas over the recording."""
    hidden = (make_effect("loop_delay", {"Td": 0.03}), make_effect("current_sensor_offset", {"I0": -0.12}))
    kin, rig, _ = rig_kinematics(hidden, seed=11, work=tmp_path, noise_v=NOISE_4X)
    d = discover(kin, rig, "delay+offset")
    assert {e.name for e in d.effects} == {"loop_delay", "current_sensor_offset"}
    assert d.verdict == "explained"
    found = {e.name: e.value for e in d.effects}
    assert abs(found["current_sensor_offset"] + 0.12) <= 0.2 * 0.12
