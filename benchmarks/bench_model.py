"""Fast simulator speed, each figure against a baseline measured in the same run.

1. linear model, one 500-sample recording (millis() spacing 50/51 ms):
   ``simulate`` vs one scipy ``solve_ivp`` call per control period
   (DOP853, rtol 1e-10, atol 1e-12, same sampled controller) -- target >= 1000x;
2. every catalogued effect on at its typical value (``Param.typical``):
   ``simulate`` vs the rig's reference plant ``simulate_reference`` -- target >= 50x.

Every ``simulate`` call of the two ratios starts cold (its step matrices are
built inside the call), so the figures include that set-up; the event-driven
plant's later runs, which find its step matrices kept (a start estimate replays
one plant thousands of times), are timed beside it.  The compiled kernels (numba) are
warmed first (``pipeline.model.compile.compile_kernels``), so no ratio includes
a JIT compile or a load from numba's cache; that one-off cost is reported on
the first line.  Both sides of every ratio are the best of a few repeats (the
machine is shared).  Run: python -m benchmarks.bench_model
"""

from __future__ import annotations

import numpy as np

from benchmarks.bench_rig import best_of
from pipeline.config import default_config
from pipeline.model.compile import compile_kernels
from pipeline.model.effects import CATALOGUE, build_spec
from pipeline.model.nonsmooth import plant_constants
from pipeline.model.simulate import simulate
from pipeline.rig.plant import simulate_reference
from tests.model.ivp_reference import jittered_times, simulate_ivp


def _line(label: str, seconds: float, ratio: float | None = None, target: float | None = None) -> str:
    text = f"  {label:<44}{seconds * 1e3:10.2f} ms"
    if ratio is not None:
        verdict = "ok" if target is None or ratio >= target else "BELOW TARGET"
        text += f"   {ratio:8.1f}x" + (f"  (target >= {target:g}x: {verdict})" if target else "")
    return text


def bench_linear(t: np.ndarray) -> float:
    spec = default_config().plant_spec()
    base = best_of(lambda: simulate_ivp(spec, t), repeat=3)
    fast = best_of(lambda: simulate(spec, t), repeat=50)
    ratio = base / fast
    print(f"1. linear model, {len(t)} samples, closed loop, sampled guard")
    print(_line("per-period solve_ivp (rtol 1e-10)", base))
    print(_line("simulate (matrix exponential)", fast, ratio, 1000))
    return ratio


def every_effect():
    base = default_config()
    return build_spec(base.model, base.controller, base.drive, [cls.typical() for cls in CATALOGUE.values()])


def bench_every_effect(t: np.ndarray) -> float:
    spec = every_effect()
    ref = best_of(lambda: simulate_reference(spec, t), repeat=3)

    def cold():
        steps = plant_constants(spec)[2]       # the plant's first run: its step table emptied, built as it goes
        steps.keys.fill(-1.0)
        steps.counts.fill(0)
        return simulate(spec, t)

    fast = best_of(cold, repeat=20)
    warm = best_of(lambda: simulate(spec, t), repeat=20)
    a, b = simulate(spec, t), simulate_reference(spec, t)
    err = max(float(np.max(np.abs(a.theta - b.theta))), float(np.max(np.abs(a.current - b.current))))
    ratio = ref / fast
    print(f"2. every effect on, {len(t)} samples, closed loop (max |fast - reference| = {err:.1e})")
    print(_line("reference plant (solve_ivp + events)", ref))
    print(_line("simulate (exact, event-driven), a first run", fast, ratio, 50))
    print(_line("simulate, a later run of the same plant", warm, ref / warm))
    return ratio


def main() -> None:
    t = jittered_times(500, seed=0)
    print(f"JIT warm-up (compile or load from cache, not in any figure): {compile_kernels():.2f} s")
    bench_linear(t)
    bench_every_effect(t)


if __name__ == "__main__":
    main()
