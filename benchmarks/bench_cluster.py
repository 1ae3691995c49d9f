"""``pdr run --cluster`` against the local pool on one machine, and a measured model of scaling.

Bar (issue 18): 1,000 recordings through the cluster path with 2 workers reach at
least 80 % of the local pool's recordings/s, same machine, one run each.  The
cluster is real: ``dask scheduler`` and two ``dask worker`` processes (one
thread each, no nanny) on 127.0.0.1, started from this environment; this
process is the client.  Measured besides: CPU per recording by stage (the
workers'), the client's CPU and wall time writing what comes back, bytes
moved per recording, the scheduler's per-task overhead (2,000 no-op tasks),
and from these the recordings/s predicted at 10 and 100 workers.
Run: python -m benchmarks.bench_cluster [N]
"""

from __future__ import annotations

import json
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

N_RECORDINGS = 1000
NOOP_TASKS = 2000
CHUNK = 4                      # recordings per task on a large run (pipeline.run.CHUNK_MAX)


def _start_cluster(tmp: Path) -> tuple[str, list[subprocess.Popen]]:
    dask = str(Path(sys.executable).with_name("dask"))
    sched_file = tmp / "scheduler.json"
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    while not sched_file.is_file():
        time.sleep(0.05)
    procs += [subprocess.Popen([dask, "worker", "--scheduler-file", str(sched_file), "--host", "127.0.0.1",
                                "--nthreads", "1", "--no-nanny", "--no-dashboard"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for _ in range(2)]
    return json.loads(sched_file.read_text())["address"], procs


def _stop(procs: list[subprocess.Popen]) -> None:
    """Workers first (a worker whose scheduler is gone keeps trying to reconnect), then the scheduler."""
    for p in reversed(procs):
        p.terminate()
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _cpu(pid: int) -> float:
    import psutil

    t = psutil.Process(pid).cpu_times()
    return t.user + t.system


def _self_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class _WriteClock:
    """Wall and CPU time the client spends in ``_write_results`` (writing, one sync per chunk, stamps)."""

    def __init__(self) -> None:
        import pipeline.cluster.execute as execute

        self.wall = self.cpu = 0.0
        self._module, self._real = execute, execute._write_results
        execute._write_results = self._timed

    def _timed(self, *args, **kwargs):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return self._real(*args, **kwargs)
        finally:
            self.wall += time.perf_counter() - t0
            self.cpu += time.process_time() - c0

    def restore(self) -> None:
        self._module._write_results = self._real


def _output_bytes(processed: Path) -> int:
    return sum(f.stat().st_size for d in processed.iterdir() if d.is_dir() and (d / "stamp.json").is_file()
               for f in d.iterdir() if f.is_file())


def _job_overhead(csv: Path) -> int:
    """Bytes a recording's task carries besides the raw file itself (pickled config, stamp, names)."""
    from pipeline.cluster.work import RecordingJob
    from pipeline.config import config_for_recording
    from pipeline.run import stamp_for

    job = RecordingJob(source=str(csv), data=csv.read_bytes(), config=config_for_recording(csv),
                       stamp=stamp_for(csv, "bench"))
    return len(pickle.dumps(job)) - len(job.data)


def scheduler_overhead(address: str, scheduler_pid: int) -> tuple[float, float]:
    """(wall per task, scheduler CPU per task) for ``NOOP_TASKS`` no-op tasks on the two workers."""
    from distributed import Client

    with Client(address, set_as_default=False) as client:      # abs: a no-op the workers need not import
        client.gather(client.map(abs, range(50), pure=False))
        c0, t0 = _cpu(scheduler_pid), time.perf_counter()
        futures = client.map(abs, range(NOOP_TASKS), pure=False)
        client.gather(futures)
        wall, cpu = time.perf_counter() - t0, _cpu(scheduler_pid) - c0
        del futures
    return wall / NOOP_TASKS, cpu / NOOP_TASKS


def main(n: int = N_RECORDINGS) -> None:
    from benchmarks.bench_pipeline import make_recordings
    from pipeline.model.compile import compile_kernels
    from pipeline.run import run_pipeline

    print(f"model kernels compiled or loaded in {compile_kernels():.1f} s (not counted)")
    with tempfile.TemporaryDirectory(prefix="pdr-bench-cluster-") as tmp_name:
        tmp = Path(tmp_name)
        raw = tmp / "raw"
        print(f"generated {n} virtual-rig recordings in {make_recordings(raw, n):.1f} s (not counted)")
        local = run_pipeline(raw, tmp / "local", jobs=2, code="bench")
        local_rate = n / local.wall_s
        print(f"local pool, 2 workers: {local.wall_s:.1f} s = {local_rate:.1f} recordings/s"
              + (f", {len(local.failed)} FAILED" if local.failed else ""))

        address, procs = _start_cluster(tmp)
        try:
            from distributed import Client
            with Client(address, set_as_default=False) as client:
                client.wait_for_workers(2, timeout=120)
            cpu0 = {p.pid: _cpu(p.pid) for p in procs}
            clock, self0 = _WriteClock(), _self_cpu()
            remote = run_pipeline(raw, tmp / "cluster", code="bench", cluster=address)
            client_cpu = _self_cpu() - self0
            clock.restore()
            cpu = {p.pid: _cpu(p.pid) - cpu0[p.pid] for p in procs}
            per_task_wall, per_task_cpu = scheduler_overhead(address, procs[0].pid)
        finally:
            _stop(procs)

        rate = n / remote.wall_s
        print(f"cluster, 2 workers (scheduler and workers on this machine): {remote.wall_s:.1f} s = {rate:.1f} "
              f"recordings/s = {100 * rate / local_rate:.0f} % of the local pool (bar >= 80 %)"
              + (f", {len(remote.failed)} FAILED" if remote.failed else ""))
        for note in remote.notes:
            print(f"  {note}")
        print(f"  workers ready (code checked, modules imported) {remote.pool_ready_s:.2f} s after the start")
        stage = remote.stage_cpu_seconds()
        print("  worker CPU per recording by stage: " + ", ".join(f"{k} {1000 * v / n:.1f} ms" for k, v in stage.items()))
        worker_cpu = sum(cpu[p.pid] for p in procs[1:]) / n
        print(f"  worker process CPU per recording (all threads, rrd verify's child processes not included): "
              f"{1000 * worker_cpu:.1f} ms; the stages above sum to {1000 * remote.cpu_seconds() / n:.1f} ms")
        print(f"  scheduler CPU per recording {1000 * cpu[procs[0].pid] / n:.2f} ms; client CPU per recording "
              f"{1000 * client_cpu / n:.1f} ms, of which writing {1000 * clock.cpu / n:.1f} ms "
              f"(wall writing, syncs included: {1000 * clock.wall / n:.1f} ms)")
        sent = sum(f.stat().st_size for f in raw.glob("*.csv")) / n + _job_overhead(next(raw.glob("*.csv")))
        back = _output_bytes(tmp / "cluster") / n
        print(f"  bytes per recording: {sent / 1e3:.1f} kB sent (raw file + pickled config and stamp), "
              f"{back / 1e3:.1f} kB returned (every output file)")
        print(f"  scheduler, {NOOP_TASKS} no-op tasks on 2 workers: {1e3 * per_task_wall:.2f} ms wall per task, "
              f"{1e3 * per_task_cpu:.2f} ms scheduler CPU per task")

        # The model: each worker (one core) does worker_cpu per recording; the one client does client_cpu
        # of CPU and, in its writer thread, write_wall of writing and syncing (the file system's share: one
        # sync per batch of results, so it shrinks per recording when results arrive faster); the
        # scheduler does per_task_cpu per task of CHUNK recordings.
        limits = {"client CPU": n / client_cpu, "client writes + syncs (this disk)": n / clock.wall,
                  "scheduler": CHUNK / per_task_cpu}
        print("  limits (recordings/s): " + ", ".join(f"{k} {v:.0f}" for k, v in limits.items()))
        for workers in (10, 100):
            bound, predicted = min([("workers", workers / worker_cpu), *limits.items()], key=lambda kv: kv[1])
            print(f"  predicted at {workers} workers (one core each): {predicted:.0f} recordings/s ({bound}-bound)")
        first, rate_cap = min(limits.items(), key=lambda kv: kv[1])
        print(f"  stops scaling at about {rate_cap * worker_cpu:.0f} workers ({first}); "
              f"without it at {sorted(limits.values())[1] * worker_cpu:.0f}")

if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else N_RECORDINGS)
