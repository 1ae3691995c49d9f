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
