"""compile_kernels covers every compiled path validation and discovery take, with the inputs they pass.

numba compiles one version of a kernel per argument type, and a read-only
array (what pandas 3 hands out) is another type than a writable one: a
caller passing one would compile a second version (seconds) in every process
the first time.  ``simulate`` gives the kernels its own writable copy, so the
versions ``make``'s set-up compiles are the only ones ever needed.
"""

import numpy as np
import pandas as pd

from pipeline.config import default_config
from pipeline.model import event_step, linear
from pipeline.model.compile import compile_kernels
from pipeline.model.effects import build_spec, make_effect
from pipeline.model.simulate import simulate
from pipeline.validate.compare import simulate_both

DISPATCHERS = {"run_zoh": linear.run_zoh, "run_events": event_step.run_events}


def _versions() -> dict[str, int]:
    return {name: len(fn.signatures) for name, fn in DISPATCHERS.items()}


def test_read_only_and_strided_inputs_reuse_the_compiled_kernels():
    compile_kernels()
    before = _versions()
    assert all(n >= 1 for n in before.values())
    cfg = default_config()
    spec = cfg.plant_spec()
    sim = simulate(spec, duration=3.0)
    kin = pd.DataFrame({"t_s": sim.t, "theta_rad": sim.theta, "omega_rad_s": sim.omega,
                        "current_a": sim.current_measured, "dir": sim.dir})
    simulate_both(spec, kin)                                   # pandas' read-only columns
    strided = np.repeat(sim.t, 2)[::2]                         # a non-contiguous view
    strided.flags.writeable = False
    simulate(spec, strided, dir_log=sim.dir, closed_loop=False)
    coulomb = build_spec(cfg.model, cfg.controller, cfg.drive, (make_effect("coulomb_friction", {"Tc": 6e-4}),))
    simulate(coulomb, strided)
    assert _versions() == before
