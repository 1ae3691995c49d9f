"""Virtual rig speed: the reference plant and one synthetic recording.

Baseline measured in the same run: the naive way to integrate a sampled
controller with scipy -- one ``solve_ivp`` call per control period
(``tests.model.ivp_reference``, tolerances 1e-10/1e-12).  The reference plant instead integrates between the
instants where the input or a decision can change, with dense output.
Run: python -m benchmarks.bench_rig
"""

from __future__ import annotations

import time


from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.model.simulate import sample_times, simulate
from pipeline.rig.plant import simulate_reference
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.rig.serial import Artefacts
from tests.model.ivp_reference import simulate_ivp   # the one per-period baseline (bench_model uses it too)


def best_of(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    spec = default_config().plant_spec()
    t = sample_times(24.95, 0.05)
    base = best_of(lambda: simulate_ivp(spec, t), repeat=2)
    ref = best_of(lambda: simulate_reference(spec, t))
    fast = best_of(lambda: simulate(spec, t))
    print(f"500 samples, linear model, sampled guard:")
    print(f"  per-period solve_ivp baseline  {base * 1e3:8.1f} ms")
    print(f"  reference plant (events)       {ref * 1e3:8.1f} ms   {base / ref:6.1f}x faster than baseline")
    print(f"  fast simulator (for scale)     {fast * 1e3:8.1f} ms   {ref / fast:6.1f}x faster than reference")
    every = (make_effect("coulomb_friction", {"Tc": 6e-4}), make_effect("backlash", {"gap": 0.05}), make_effect("loop_delay", {"Td": 0.05}), make_effect("rack_inertia", {"Jr": 1e-3}),
             make_effect("current_sensor_offset", {"I0": 0.05}))
    full = default_config().plant_spec(every)
    ref_full = best_of(lambda: simulate_reference(full, t))
    print(f"  reference plant, every non-smooth effect on: {ref_full * 1e3:.1f} ms")
    cases = {
        "plain recording (520 samples)": RigSetup(),
        "every artefact + reset": RigSetup(artefacts=Artefacts(
            ide_prefix="ide2", crlf=True, bom=True, comments=3, blank_lines=3, partial_first_line=True,
            garbled=5, dropped=5, reset_after_s=12.0)),
        "every non-smooth effect hidden": RigSetup(effects=every),
    }
    print("make_recording (target < 0.5 s each):")
    for label, setup in cases.items():
        s = best_of(lambda: make_recording(setup, seed=1))
        print(f"  {label:32s} {s * 1e3:8.1f} ms")


if __name__ == "__main__":
    main()
