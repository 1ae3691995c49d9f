"""The issue's bars for questions across runs, on virtual-rig recordings through ``pdr discover RECORDING...``'s
own code (``discover_many``, local worker processes):

- 20 recordings of one rig with b = 7.7e-4 (its TOML says b = 0) and per-run noise: the pooled b lies
  within its interval of the truth, and the interval shrinks about as 1/sqrt(runs) (5, 10, 20 runs);
- 20 recordings whose Coulomb friction grows by 30 % from the first to the last (one a day): flagged;
- 20 recordings of a rig with constant Coulomb friction, and 20 of a clean rig: not flagged.

Run: python -m benchmarks.bench_pooled [RUNS]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

RUNS = 20
B_TRUE = 7.7e-4
TC = 1.5e-3
DAY = 86400.0
T0 = 1.7e9


def _rig(raw: Path, prefix: str, n: int, seed0: int, effects_of, config) -> list[Path]:
    from pipeline.rig.recording import RigSetup, make_recording, write_recording

    out = []
    for i in range(n):
        rec = make_recording(RigSetup(effects=effects_of(i), config=config, duration_s=10.0), seed=seed0 + i)
        csv = write_recording(rec, raw, f"{prefix}{i:02d}")["csv"]
        os.utime(csv, (T0 + i * DAY, T0 + i * DAY))
        out.append(csv)
    return out


def main(n: int = RUNS) -> None:
    import numpy as np

    from pipeline.config import default_config
    from pipeline.discover.across import findings
    from pipeline.discover.many import discover_many
    from pipeline.discover.pooled import pool, standard_errors
    from pipeline.model.effects import make_effect

    base = default_config()
    paper = replace(base, model=base.model.with_(b=0.0))
    # each rig its own declared drive voltage, so the four are four rigs for the pooling
    rig = {k: replace(base, drive=replace(base.drive, v_in=v)) for k, v in (("drift", 6.2), ("stable", 6.4),
                                                                             ("clean", 6.6))}
    with tempfile.TemporaryDirectory(prefix="pdr-bench-pooled-") as tmp:
        raw = Path(tmp) / "raw"
        csvs = (_rig(raw, "b", n, 300, lambda i: (make_effect("viscous_friction", {"b": B_TRUE}),), paper)
                + _rig(raw, "drift", n, 400,
                       lambda i: (make_effect("coulomb_friction", {"Tc": TC * (1 + 0.3 * i / (n - 1))}),), rig["drift"])
                + _rig(raw, "stable", n, 500, lambda i: (make_effect("coulomb_friction", {"Tc": TC}),), rig["stable"])
                + _rig(raw, "clean", n, 600, lambda i: (), rig["clean"]))
        t0 = time.perf_counter()
        result = discover_many(csvs, Path(tmp) / "discovery", jobs=2, rrd=False)
        wall = time.perf_counter() - t0
        print(f"{len(csvs)} recordings discovered in {wall:.1f} s ({wall / len(csvs):.2f} s each on 2 workers)"
              + (f", {len(result.failed)} FAILED" if result.failed else ""))
        table, pooled = result.table, result.pooled
        for line in findings(pooled):
            print(f"  {line}")
        print("  verdicts per rig: " + "; ".join(
            f"{name}: {({k: int(v) for k, v in table[table['run'].str.startswith(name)]['verdict'].value_counts().items()})}"
            for name in ("b", "drift", "stable", "clean")))

        b_runs = table[table["run"].str.match(r"b\d") & table["viscous_friction.b"].notna()]
        x = b_runs["viscous_friction.b"].to_numpy(float)
        se = standard_errors(b_runs["viscous_friction.b_lo"].to_numpy(float), b_runs["viscous_friction.b_hi"].to_numpy(float))
        widths = {}
        for k in (5, 10, len(x)):
            p = pool(x[:k], se[:k])
            widths[k] = p.hi - p.lo
            inside = p.lo <= B_TRUE <= p.hi
            print(f"  b pooled over {k:2d} runs: {p.estimate:.6g} [{p.lo:.6g}, {p.hi:.6g}] ({p.method}); truth inside: "
                  f"{'yes' if inside else 'NO'}; (estimate - truth) / half-width = "
                  f"{(p.estimate - B_TRUE) / ((p.hi - p.lo) / 2):+.2f}")
        k = len(x)
        print(f"  interval width ratio 5 -> {k} runs: {widths[5] / widths[k]:.2f} (1/sqrt: {np.sqrt(k / 5):.2f}); "
              f"10 -> {k}: {widths[10] / widths[k]:.2f} (1/sqrt: {np.sqrt(k / 10):.2f})")
        flagged = {r["rig"] for r in pooled.to_dict("records") if r.get("trend_flagged")}
        rig_of = {name: set(table[table["run"].str.match(name + r"\d")]["rig"]) for name in ("b", "drift", "stable", "clean")}
        for name in ("b", "drift", "stable", "clean"):
            print(f"  {name}: trend flagged: {'yes' if rig_of[name] & flagged else 'no'}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else RUNS)
