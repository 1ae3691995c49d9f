"""The 9th effect on its own: where it holds the pinion, in both simulators (its conformance over the
catalogue -- declaration, fast vs reference, discovery -- is tests/model/test_catalogue.py)."""

import numpy as np
import pytest

from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.model.simulate import sample_times, simulate
from pipeline.rig.plant import simulate_reference


@pytest.mark.parametrize("Tl", [1.5e-3, -8e-4])
def test_motor_off_the_pinion_settles_where_the_springs_hold_the_load(Tl):
    cfg = default_config()
    spec = cfg.plant_spec((make_effect("constant_load_torque", {"Tl": Tl}),))
    p = spec.params
    t = sample_times(120.0, 0.05)
    off = np.zeros(len(t), dtype=np.int8)
    centre = -Tl / (p.R ** 2 * (p.K1 + p.K2))              # MODEL.md
    for run in (simulate(spec, t, dir_log=off, closed_loop=False),
                simulate_reference(spec, t, dir_log=off, closed_loop=False)):
        assert run.theta[-1] == pytest.approx(centre, rel=1e-3)
        assert abs(run.current[-1]) < 1e-6                  # motor off: the springs alone hold it

