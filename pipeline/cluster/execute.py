"""The client side of ``pdr run --cluster``: submit the recordings, show progress, write what comes back.

Recordings go in the local runner's chunks (a few per task, so one ``rerun
rrd verify`` checks several files), sized by the cluster's worker threads.
A worker that dies while holding a task: the scheduler gives the task to
another worker (up to ``distributed.scheduler.allowed-failures`` deaths, then
``KilledWorker``).  A chunk that keeps killing workers is split: each of its
recordings is sent again alone, so only the one that kills a worker (a crash
in a native library, say) is reported failed, as the local pool does.  Whether a task was
re-run is read from the scheduler (its ``suspicious`` count: the workers that
died holding it), so the run summary says which recordings were re-run and
which workers were lost.
"""

from __future__ import annotations

import queue
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.errors import PdrError
from pipeline.io.atomic import deferred_sync, write_bytes
from pipeline.io.queues import next_batch
from pipeline.cluster.runner import RunReport, Stamp, chunks, code_version, failed_ahead, previous_runs, withdraw
from pipeline.runs import RunPaths

STAMP_NAME = RunPaths(Path("run")).stamp.name
BUSY_POLL_S = 0.5       # how often the progress line asks the scheduler which workers are busy


@dataclass
class ClusterRun:
    """What happened on the cluster, for the run summary."""

    address: str
    workers_seen: set[str] = field(default_factory=set)
    workers_lost: list[str] = field(default_factory=list)
    rerun: dict[str, int] = field(default_factory=dict)      # recording -> worker deaths while it was held
    bytes_sent: int = 0
    bytes_returned: int = 0

    def notes(self) -> list[str]:
        out = [f"cluster {self.address}: {len(self.workers_seen)} worker(s) took part; "
               f"{self.bytes_sent / 1e6:.1f} MB of raw files sent, {self.bytes_returned / 1e6:.1f} MB of outputs returned"]
        if self.workers_lost:
            out.append(f"workers lost during the run: {', '.join(sorted(self.workers_lost))}")
        if self.rerun:
            names = sorted(self.rerun)
            shown = ", ".join(names[:8]) + (f", ... ({len(names) - 8} more)" if len(names) > 8 else "")
            out.append(f"{len(names)} recording(s) re-run on another worker after a worker died holding them "
                       f"(their outputs come from the completed run only): {shown}")
        return out


def _job(csv: Path, stamp: Stamp):
    """The recording as a worker needs it, or the reason it cannot go (as ``ingest_recording`` words it)."""
    from pipeline.cluster.work import RecordingJob
    from pipeline.config import config_for_recording

    try:
        config = config_for_recording(csv)
        data = csv.read_bytes()
    except PdrError as err:
        return f"ingest: {err}"
    except OSError as err:
        return f"ingest: {PdrError(f'cannot read the recording: {err.strerror}', path=csv)}"
    return RecordingJob(source=str(csv), data=data, config=config, stamp=stamp)


def _write_results(results: list[dict], processed: Path, stats: ClusterRun) -> None:
    """A chunk's returned files into ``processed/``: every file renamed into place, one sync, then the stamps."""
    old = {r["recording"]: previous_runs(processed, Path(r["recording"])) for r in results}
    stamps: list[tuple[Path, bytes]] = []
    with deferred_sync():
        for r in results:
            for rel, data in r.pop("files", {}).items():
                stats.bytes_returned += len(data)
                target = processed / rel
                if target.name == STAMP_NAME:
                    stamps.append((target, data))
                else:
                    target.parent.mkdir(parents=True, exist_ok=True)
                    write_bytes(target, data)
    for target, data in stamps:
        write_bytes(target, data)
    for r in results:
        runs, before = r["runs"], old[r["recording"]]
        if r["status"] == "ok":
            import shutil
            for name in set(before) - set(runs):
                shutil.rmtree(processed / name, ignore_errors=True)
        else:
            withdraw(processed, sorted(set(before) | set(runs)))


class _Writer:
    """Writes what the workers return in a thread of its own, so the client keeps collecting meanwhile.

    Each time it takes everything returned so far: the files, one sync, then
    their stamps.  The busier the client (or the slower the sync), the more
    results share one sync.
    """

    def __init__(self, processed: Path, stats: ClusterRun) -> None:
        self._queue: queue.Queue = queue.Queue()
        self._processed, self._stats = processed, stats
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="pdr-writer", daemon=True)
        self._thread.start()

    def put(self, results: list[dict]) -> None:
        self._queue.put(results)

    def close(self) -> None:
        """Waits for everything handed over to be written; raises what the writer raised."""
        self._queue.put(None)
        self._thread.join()
        if self._error is not None:
            raise self._error

    def _run(self) -> None:
        done = False
        while not done:
            batch = next_batch(self._queue)
            done = None in batch
            results = [r for item in batch if item is not None for r in item]
            if results and self._error is None:
                try:
                    _write_results(results, self._processed, self._stats)
                except BaseException as err:  # handed to close(), in the caller's thread
                    self._error = err


def _failed(sources: list[str], error: str, processed: Path) -> list[dict]:
    """Recordings that got no worker's result: reported failed, their old outputs withdrawn."""
    info = {"runs": [], "error": error, "wall_s": 0.0, "cpu_s": 0.0}
    return [failed_ahead(Path(source), processed, info) for source in sources]


def _suspicious(dask_scheduler, keys: list[str]) -> dict[str, int]:
    """On the scheduler: how many workers died while holding each task."""
    tasks = dask_scheduler.tasks
    return {k: tasks[k].suspicious for k in keys if k in tasks and tasks[k].suspicious}


def _lost_workers_died(err: BaseException) -> bool:
    from distributed.scheduler import KilledWorker

    return isinstance(err, KilledWorker)


def execute_on_cluster(todo: list[tuple[Path, Stamp]], processed: Path, address: str, show_progress: bool,
                       report: RunReport | None = None, work=None) -> tuple[list[dict], ClusterRun]:
    """Every recording of ``todo`` through the cluster at ``address``; results as the local runner's.

    ``work``: what a worker runs on a chunk (default ``work.run_chunk``; tests pass one that crashes).
    """
    from distributed import as_completed
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from pipeline.cluster.connect import WorkerCheck, connect
    from pipeline.cluster.work import run_chunk

    work = work or run_chunk
    processed = Path(processed)
    stats = ClusterRun(address=address)
    client = connect(address)
    try:
        check = WorkerCheck(client, code_version())
        results: list[dict] = []
        jobs = []
        for csv, stamp in todo:
            job = _job(csv, stamp)
            if isinstance(job, str):
                results.extend(_failed([str(csv)], job, processed))
            else:
                jobs.append(job)
                stats.bytes_sent += len(job.data)
        check.result()
        if report is not None:
            report.pool_ready_s = time.perf_counter() - report.started
        stats.workers_seen.update(client.nthreads())
        threads = max(1, sum(client.nthreads().values()))
        tag = uuid.uuid4().hex[:8]
        by_key: dict[str, list] = {}

        def submit(chunk: list, key: str):
            fut = client.submit(work, chunk, key=key, pure=False)
            by_key[fut.key] = chunk
            return fut

        futures = [submit(chunk, f"pdr-run-{tag}-{i:05d}") for i, chunk in enumerate(chunks(jobs, threads))]
        writer = _Writer(processed, stats)
        with Progress(TextColumn("[bold]pdr run"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      TextColumn("{task.description}"), disable=not show_progress, transient=False) as bar:
            task = bar.add_task("", total=len(todo))
            bar.advance(task, len(results))
            polled = 0.0
            pending = as_completed(futures, loop=client.loop)
            for fut in pending:
                chunk = by_key[fut.key]
                try:
                    done = fut.result()
                except Exception as err:  # KilledWorker, or the task itself could not run
                    if _lost_workers_died(err) and len(chunk) > 1:      # find the culprit: each alone
                        for j, job in enumerate(chunk):
                            pending.add(submit([job], f"{fut.key}-{j}"))
                        continue
                    why = (f"cluster: every worker that took it died, as many times as the scheduler allows ({err})"
                           if _lost_workers_died(err) else f"cluster: {type(err).__name__}: {err}")
                    done = _failed([job.source for job in chunk], why, processed)
                writer.put(done)
                results.extend(done)
                stats.workers_seen.update(r["worker"] for r in done if r.get("worker", "local") != "local")
                bar.advance(task, len(chunk))
                if time.perf_counter() - polled > BUSY_POLL_S:
                    polled = time.perf_counter()
                    stats.workers_seen.update(client.nthreads())
                    busy = sum(1 for keys in client.processing().values() if keys)
                    bar.update(task, description=f"workers busy {busy} of {len(client.nthreads())}")
        writer.close()
        rerun = client.run_on_scheduler(_suspicious, keys=list(by_key))
        for key, deaths in rerun.items():
            for job in by_key[key]:
                stats.rerun[job.name] = deaths
        for r in results:
            if r["recording"] in stats.rerun:
                r["rerun_after_worker_death"] = stats.rerun[r["recording"]]
        alive = set(client.nthreads())
        stats.workers_lost = sorted(w for w in stats.workers_seen if w not in alive)
    finally:
        client.close()
    return sorted(results, key=lambda r: r["recording"]), stats
