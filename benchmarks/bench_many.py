"""``pdr run`` on 100 and then 1,000 new recordings in one folder: the rate, and the peak threads and
resident memory of every process of the run (issue 30).

Targets on 1,000: every recording validated, none failed; no process above 64 threads or 1.5 GB
of resident memory at any moment; >= 15 recordings/s, as on 100.  The real ``pdr run`` command runs
(process start included) while this process samples ``/proc`` every ``SAMPLE_S``: the command's
own process, its forkserver and workers, and the ``rerun rrd verify`` children.  The folder holds
copies of ``DISTINCT`` virtual-rig recordings (500 samples each) under new names: to pdr each is
a new recording, and generating 1,000 distinct ones would take longer than processing them.
The 100 run comes first, in the same session, because the machine may be shared: the 1,000 run's
rate is also given relative to it.
Run: python -m benchmarks.bench_many [N]   (Linux: reads /proc)
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.bench_pipeline import make_recordings

SIZES = (100, 1000)
DISTINCT = 50
SAMPLE_S = 0.05
MAX_THREADS = 64
MAX_RSS_MB = 1536
TARGET_RATE = 15.0


def _proc_status(pid: int) -> tuple[int, float] | None:
    """(threads, resident MB) of a process, None once it is gone."""
    try:
        fields = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                      if ":" in line)
    except OSError:
        return None
    rss_kb = int(fields.get("VmRSS", "0 kB").split()[0])     # none for a process exiting
    return int(fields["Threads"]), rss_kb / 1024


def _descendants(root: int) -> dict[int, int]:
    """Every process under ``root`` -> its parent, walked down ``/proc/<pid>/task/<tid>/children``
    (a few dozen small reads, where a scan of all /proc would read every process on the machine)."""
    parents, todo = {}, [root]
    while todo:
        pid = todo.pop()
        try:
            tids = os.listdir(f"/proc/{pid}/task")
        except OSError:
            continue
        for tid in tids:
            try:
                children = Path(f"/proc/{pid}/task/{tid}/children").read_text().split()
            except OSError:
                continue
            for child in map(int, children):
                parents[child] = pid
                todo.append(child)
    return parents


def _role(pid: int, root: int, parents: dict[int, int]) -> str:
    """What a process of the run is, from its command line and its parent (a worker forked by the
    forkserver keeps the forkserver's command line)."""
    if pid == root:
        return "pdr run (main)"
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return "gone"
    if "rrd verify" in cmd:
        return "rerun rrd verify"
    if parents.get(pid) == root:
        return "forkserver" if "forkserver" in cmd else "resource tracker" if "resource_tracker" in cmd else "child"
    if parents.get(parents.get(pid, 0)) == root:
        return "worker"
    return "a worker's child before its exec" if "forkserver" in cmd else "other descendant"


@dataclass
class Peaks:
    """The highest threads and resident MB seen per role, and per worker process."""
    by_role: dict[str, list[float]] = field(default_factory=dict)
    samples: int = 0

    def see(self, role: str, threads: int, rss_mb: float) -> None:
        peak = self.by_role.setdefault(role, [0, 0.0])
        peak[0], peak[1] = max(peak[0], threads), max(peak[1], rss_mb)


def _sample_tree(root: int, peaks: Peaks, stop: threading.Event) -> None:
    """Until ``stop``: the threads and resident memory of ``root`` and every process under it."""
    while not stop.is_set():
        parents = _descendants(root)
        for pid in (root, *parents):
            status = _proc_status(pid)
            if status is None:
                continue
            role = _role(pid, root, parents)        # each time: a forked child becomes rerun at its exec
            peaks.see(f"{role} {pid}" if role == "worker" else role, *status)
        peaks.samples += 1
        stop.wait(SAMPLE_S)


def run_sampled(raw: Path, processed: Path) -> tuple[float, int, str, Peaks]:
    """The ``pdr run`` command on ``raw``: wall seconds, exit status, its first line (the summary), the peaks."""
    pdr = Path(sys.executable).with_name("pdr")
    peaks, stop = Peaks(), threading.Event()
    t0 = time.perf_counter()
    proc = subprocess.Popen([str(pdr), "run", "--raw", str(raw), "--processed", str(processed), "-j", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    sampler = threading.Thread(target=_sample_tree, args=(proc.pid, peaks, stop), daemon=True)
    sampler.start()
    out, _ = proc.communicate()
    wall = time.perf_counter() - t0
    stop.set()
    sampler.join()
    lines = [line for line in out.strip().splitlines() if line.strip()]
    return wall, proc.returncode, lines[0] if lines else "", peaks


def fill_folder(raw: Path, n: int, originals: Path) -> None:
    """``n`` recordings in ``raw``: copies of the ``originals`` (CSV and TOML) under new names."""
    raw.mkdir(parents=True)
    sources = sorted(originals.glob("*.csv"))
    for i in range(n):
        src = sources[i % len(sources)]
        shutil.copyfile(src, raw / f"many-{i:05d}.csv")
        shutil.copyfile(src.with_suffix(".toml"), raw / f"many-{i:05d}.toml")


def main(sizes: tuple[int, ...] = SIZES) -> None:
    from pipeline.model.compile import compile_kernels

    print(f"model kernels compiled or loaded from numba's cache in {compile_kernels():.1f} s (not counted)")
    rates = {}
    with tempfile.TemporaryDirectory(prefix="pdr-bench-many-") as tmp:
        originals = Path(tmp) / "originals"
        gen = make_recordings(originals, DISTINCT)
        print(f"generated {DISTINCT} virtual-rig recordings in {gen:.1f} s (not counted)")
        for n in sizes:
            raw, processed = Path(tmp) / f"raw-{n}", Path(tmp) / f"processed-{n}"
            fill_folder(raw, n, originals)
            wall, status, first, peaks = run_sampled(raw, processed)
            validated = sum(1 for _ in processed.glob("*/validation.json"))
            rates[n] = rate = n / wall
            relative = f", {rate / rates[sizes[0]]:.2f}x the {sizes[0]} run's" if n != sizes[0] else ""
            print(f"pdr run on {n} new recordings, 2 workers: {wall:.1f} s = {rate:.1f} recordings/s "
                  f"(target >= {TARGET_RATE:g}/s{relative}); exit {status}, {validated} of {n} validated; "
                  f"{first}")
            worst_threads = max(t for t, _r in peaks.by_role.values())
            worst_rss = max(r for _t, r in peaks.by_role.values())
            within = worst_threads <= MAX_THREADS and worst_rss <= MAX_RSS_MB
            print(f"  peaks over {peaks.samples} samples of /proc, every {SAMPLE_S * 1000:.0f} ms: "
                  f"{worst_threads} threads (limit {MAX_THREADS}), {worst_rss:.0f} MB resident "
                  f"(limit {MAX_RSS_MB} MB) in the worst process: {'within' if within else 'OVER'} the limits")
            for role, (threads, rss) in sorted(peaks.by_role.items()):
                print(f"    {role:<34} {threads:4d} threads  {rss:7.0f} MB")
            shutil.rmtree(processed)


if __name__ == "__main__":
    main((int(sys.argv[1]),) if len(sys.argv) > 1 else SIZES)
