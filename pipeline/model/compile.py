"""Compile every numba kernel of the model once, so no run pays for it: ``python -m pipeline.model.compile``.

numba compiles a kernel on its first call (tens of seconds for all of them
from an empty cache) and stores it beside the sources (``cache=True``); later
processes load it in well under a second.  ``make``'s set-up calls this after
installing, so the first ``pdr run`` or test session on a fresh machine does
not stall on it.  The calls below take every compiled path: the linear plant
closed loop and in replay, with and without a loop delay, the event-driven
plant with every catalogued effect, the continuous guard.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np


def compile_kernels() -> float:
    """Call every compiled path once (compile, or load from the cache); returns the seconds it took."""
    from pipeline.config import default_config
    from pipeline.model.effects import CATALOGUE, build_spec
    from pipeline.model.simulate import simulate

    start = time.perf_counter()
    cfg = default_config()
    spec = cfg.plant_spec()
    t = np.cumsum(np.where(np.arange(60) % 3 == 0, 0.051, 0.050))       # millis() spacing, 50/51 ms
    log = simulate(spec, t).dir
    delayed = replace(spec, Td=0.03, I0=0.01)
    simulate(delayed, t)
    simulate(delayed, t, dir_log=log, closed_loop=False)
    simulate(spec, t, guard="continuous")
    every = [cls.typical() for cls in CATALOGUE.values()]
    simulate(build_spec(cfg.model, cfg.controller, cfg.drive, every), t)
    return time.perf_counter() - start


def set_up_kernels() -> None:
    """numba's one-time set-up in this process: its target context, built when the first kernel is
    loaded from the cache (~0.15 s; every later kernel loads in about a millisecond).  Done by one short
    simulation, so ``pdr discover`` can do it while its second process ingests the recording."""
    from pipeline.config import default_config
    from pipeline.model.simulate import simulate

    simulate(default_config().plant_spec(), np.arange(4) * 0.05)


def main() -> None:
    print("pdr: compiling the model's kernels (numba; once per install or kernel change) ...", file=sys.stderr,
          flush=True)
    print(f"pdr: model kernels ready in {compile_kernels():.1f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
