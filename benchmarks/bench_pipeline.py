"""``pdr run`` end to end on 100 new 500-sample virtual-rig recordings.

Reports recordings per second (target >= 15/s on two cores, issue 14), where the time
goes (seconds per stage summed over the workers, and CPU per recording per
stage: the machine is shared, so wall time alone says little), and a re-run with nothing
changed through the real ``pdr`` command (target < 2 s).  Baselines measured
in the same run: the model alone (closed loop + replay simulations of every
recording, the part the issue wants to be a small share) and the same
pipeline on one core.  The model's numba kernels are compiled (or loaded) first,
as ``make``'s set-up does, so a kernel edit just before a run does not count.
Run: python -m benchmarks.bench_pipeline [N]
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

N_RECORDINGS = 100


def make_recordings(raw: Path, n: int, seed0: int = 1000) -> float:
    from pipeline.rig.recording import RigSetup, make_recording, write_recording

    t0 = time.perf_counter()
    for i in range(n):
        write_recording(make_recording(RigSetup(), seed=seed0 + i), raw, f"bench-{i:04d}")
    return time.perf_counter() - t0


def simulation_only(processed: Path) -> float:
    """The model alone on every processed run: both simulations, nothing else."""
    import pandas as pd

    from pipeline.runs import RunPaths, load_config
    from pipeline.validate.compare import simulate_both

    runs = [RunPaths(p) for p in sorted(processed.iterdir()) if (p / "kinematics.parquet").is_file()]
    inputs = [(pd.read_parquet(r.kinematics), load_config(r).plant_spec()) for r in runs]
    t0 = time.perf_counter()
    for kin, spec in inputs:
        simulate_both(spec, kin)
    return time.perf_counter() - t0


def _noop_rerun(raw: Path, processed: Path) -> str:
    pdr = Path(sys.executable).with_name("pdr")
    t0 = time.perf_counter()
    proc = subprocess.run([str(pdr), "run", "--raw", str(raw), "--processed", str(processed)],
                          capture_output=True, text=True)
    secs = time.perf_counter() - t0
    first = proc.stderr.strip().splitlines()[0] if proc.stderr else ""
    return f"{secs:.2f} s (target < 2 s), exit {proc.returncode}: {first}"


def noise_floor(processed: Path) -> None:
    """MSE spread over clean recordings, closed-loop switch slips, and the shipped gate on them."""
    import pandas as pd

    from pipeline.validate.gate import gate, load_thresholds

    table = pd.read_csv(processed / "summary.csv")
    print(f"  noise floor over {len(table)} clean recordings (replay MSE: median / max):")
    for sig, unit in (("theta", "rad^2"), ("omega", "(rad/s)^2"), ("current", "A^2")):
        col = table[f"replay_{sig}_mse"]
        print(f"    {sig:<8} {col.median():.3g} / {col.max():.3g} {unit}")
    slipped = int(((table["closed_loop_switches"] != table["measured_switches"])
                   | (table["closed_loop_max_slip_s"].fillna(0) > 0)).sum())
    print(f"  closed loop: {slipped} of {len(table)} runs had a switch decided at another sample; "
          f"closed-loop MSE max: theta {table['closed_loop_theta_mse'].max():.3g} rad^2, "
          f"omega {table['closed_loop_omega_mse'].max():.3g} (rad/s)^2, "
          f"current {table['closed_loop_current_mse'].max():.3g} A^2")
    thresholds = Path(__file__).resolve().parents[1] / "raw" / "thresholds.toml"
    verdicts = gate(processed, load_thresholds(thresholds))
    print(f"  shipped gate (raw/thresholds.toml): {sum(v.passed for v in verdicts)} of {len(verdicts)} clean runs pass")


def main(n: int = N_RECORDINGS) -> None:
    from pipeline.model.compile import compile_kernels
    from pipeline.run import run_pipeline

    # make's set-up compiles the model's kernels; after a kernel edit the first process would (not counted)
    print(f"model kernels compiled or loaded from numba's cache in {compile_kernels():.1f} s (not counted)")

    with tempfile.TemporaryDirectory(prefix="pdr-bench-") as tmp:
        raw, processed, processed_1 = Path(tmp) / "raw", Path(tmp) / "processed", Path(tmp) / "processed-1core"
        gen = make_recordings(raw, n)
        print(f"generated {n} virtual-rig recordings (500 samples each) in {gen:.1f} s (not counted)")

        report = run_pipeline(raw, processed, jobs=2)
        failed = len(report.failed)
        rate = n / report.wall_s
        print(f"pdr run, 2 workers: {report.wall_s:.2f} s for {n} recordings = {rate:.1f} recordings/s "
              f"(target >= 15/s){'' if not failed else f', {failed} FAILED'}")
        stages = report.stage_seconds()
        total = sum(stages.values())
        print("  where the time goes (s summed over workers, % of worker time):")
        for k, v in sorted(stages.items(), key=lambda kv: -kv[1]):
            print(f"    {k:<13} {v:7.2f} s  {100 * v / total:5.1f} %   {1000 * v / n:6.1f} ms/recording")
        overhead = 2 * report.wall_s - total
        print(f"    {'pool/idle':<13} {overhead:7.2f} s  (2 x wall - worker time: start-up, imports, waiting)")
        print(f"  workers ready {report.pool_ready_s:.2f} s after the start (forkserver imports and warm-up, one core); "
              f"meanwhile pdr run ingested {report.ingested_ahead} recordings on the other "
              f"and derived {report.derived_ahead} of them")
        print("  CPU per recording by stage (process time of the worker; rrd_verify: the rerun child processes):")
        stage_cpu = report.stage_cpu_seconds()
        for k, v in stage_cpu.items():
            print(f"    {k:<13} {1000 * v / n:6.1f} ms/recording")
        cpu = report.cpu_seconds() / n
        print(f"  CPU per recording in the workers: {1000 * cpu:.0f} ms (wall per recording per worker: "
              f"{1000 * total / n:.0f} ms; the difference is waiting for a core). On two free cores that is "
              f"at most {2 / cpu:.1f} recordings/s")

        # In a shared tree the code may change while the benchmark runs (that re-runs everything,
        # rightly): the first call catches up, the second is the re-run with nothing changed.
        _noop_rerun(raw, processed)
        rerun = _noop_rerun(raw, processed)
        print(f"re-run with nothing changed (the pdr command, process start included): {rerun}")
        noise_floor(processed)

        sim = simulation_only(processed)
        print(f"baseline, the model alone (closed loop + replay, {n} runs): {sim:.2f} s = "
              f"{100 * sim / report.wall_s:.1f} % of the end-to-end wall time, {1000 * sim / n:.1f} ms/recording")

        report1 = run_pipeline(raw, processed_1, jobs=1)
        print(f"baseline, same pipeline on 1 core: {report1.wall_s:.2f} s = {n / report1.wall_s:.1f} recordings/s; "
              f"2 workers are {report1.wall_s / report.wall_s:.2f}x faster")



if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else N_RECORDINGS)
