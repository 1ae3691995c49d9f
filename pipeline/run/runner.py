"""``pdr run``'s imperative shell: the raw folder, the lock, the process pool, the end-of-run summary file.

Parallel: recordings are independent, so they go to a process pool (both
cores by default), a few per task (``chunks``) so that one ``rerun rrd
verify`` checks several files.  Where the platform has it, workers come from
a ``forkserver`` that has already imported numpy, pandas, pyarrow, rerun and
matplotlib, so a worker starts in milliseconds; elsewhere (Windows) they are
spawned.  Either way that start takes ~2 s on one core; meanwhile this process
ingests recordings from the end of the list (``ingest_ahead``), which the
workers then skip.  A worker whose parent dies exits too (``pool._init_worker``):
a ``kill -9`` of ``pdr run`` leaves no process behind.

One bad recording never stops the others: its error is reported, its stale
outputs are withdrawn so ``pdr gate`` cannot pass on old figures, and the exit
status is non-zero.  Two ``pdr run`` on one folder run one after the other
(``processed_lock``); the second finds everything up to date.
"""

from __future__ import annotations

import importlib
import multiprocessing
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pipeline.dataset import DATASET_DIR
from pipeline.errors import PdrError, describe_failure
from pipeline.io.atomic import deferred_sync, remove_stale_temporaries
from pipeline.run.lock import processed_lock
from pipeline.run.recordings import scan_raw
from pipeline.run.report import RunReport
from pipeline.run.pool import chunks, make_pool
from pipeline.run.stages import derive_ahead, failed_ahead, ingest_ahead, process_chunk
from pipeline.run.stamp import Stamp, code_version, previous_runs, prune_orphans, stamp_for, up_to_date, withdraw
from pipeline.run.stop import stopped_by, stops_deferred
from pipeline.runs import SUMMARY_CSV


def _isolated(csv: Path, processed: Path, stamp: Stamp, method: str | None) -> dict:
    from concurrent.futures.process import BrokenProcessPool

    with make_pool(1, method) as pool:
        try:
            with stops_deferred():
                future = pool.submit(process_chunk, [(csv, stamp)], processed)
            return future.result()[0]
        except BrokenProcessPool as err:
            withdraw(processed, previous_runs(processed, csv))
            return {"recording": csv.name, "status": "failed", "runs": [],
                    "error": f"the worker process died while processing it ({err})", "timing_s": {}}


def _start_pool(pool, spawned: threading.Event) -> None:
    """Start the pool's first worker (returns when it has run a task); ``spawned`` is set once the
    pool knows that worker's process (or its start failed), so a stop can wait for it and end it.

    Whatever goes wrong here the main thread sees on its own submissions: a pool that broke while
    starting (each recording is then retried alone), or one stopped by Ctrl-C or SIGTERM (the
    forkserver gone: ``EOFError``; the pool shut: ``RuntimeError``).  Nothing is printed from here."""
    try:
        try:
            future = pool.submit(os.getpid)
        finally:
            spawned.set()
        future.result()
    except BaseException:  # noqa: BLE001  (a thread's error would be printed as a traceback)
        pass


def _stop_workers(pool, processed: Path, spawned: threading.Event) -> None:
    """After Ctrl-C or SIGTERM: end the workers now (they ignore SIGINT, and a chunk can take seconds),
    then remove the temporaries they leave; every output is written by rename, so none is torn.

    The first worker may still be starting (the forkserver imports for ~2 s first): it is waited
    for, or it would read the pool's queues after this process has removed them."""
    spawned.wait(timeout=60)
    for proc in multiprocessing.active_children():      # this process starts no others than the pool's
        proc.terminate()
    pool.shutdown(wait=True, cancel_futures=True)
    for folder in (processed, *(p for p in processed.iterdir() if p.is_dir())):
        remove_stale_temporaries(folder)


def _ingest_ahead(todo: list[tuple[Path, Stamp]], processed: Path, starting: threading.Thread) -> dict[str, dict]:
    """Use the core that is idle while the workers start: ingest recordings from the end of the list,
    then, when every one is ingested and the workers are still starting, derive them in the same order.

    Stops as soon as the pool has started (``starting`` finished); the workers
    then skip the stages done here.  The summary's pandas import comes first
    (the ingest needs it too).
    """
    importlib.import_module("pipeline.validate.summary")
    ahead: dict[str, dict] = {}
    with deferred_sync():
        for csv, _stamp in reversed(todo):
            if not starting.is_alive():
                break
            ahead[csv.name] = ingest_ahead(csv, processed)
        for csv, _stamp in reversed(todo):
            if not starting.is_alive():
                break
            if ahead[csv.name]["error"] is None:
                derive_ahead(ahead[csv.name], processed)
    return ahead


@contextmanager
def _shared_folder() -> Iterator[Path | None]:
    """A temporary folder the workers of this run share (the overview backgrounds), removed at the end;
    None where none can be made (the workers then draw their own)."""
    try:
        folder = Path(tempfile.mkdtemp(prefix="pdr-shared-"))
    except OSError:
        yield None
        return
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _progress(show: bool):
    """The progress bar; rich is imported here, after the workers have started (~0.1 s of import)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(TextColumn("[bold]pdr run"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    TextColumn("{task.description}"), disable=not show, transient=False)


def _execute(todo: list[tuple[Path, Stamp]], processed: Path, jobs: int, show_progress: bool,
             report: RunReport, method: str | None) -> list[dict]:
    results: list[dict] = []
    if jobs <= 1 or len(todo) <= 1:
        with _progress(show_progress) as bar:
            task = bar.add_task("", total=len(todo))
            for chunk in chunks(todo, 1):
                bar.update(task, description=chunk[0][0].name)
                results.extend(process_chunk(chunk, processed, dataset=True))
                bar.advance(task, len(chunk))
        return results
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    broken: list[tuple[Path, Stamp]] = []
    pool = make_pool(min(jobs, len(todo)), method)
    # The first submit blocks until the workers have imported everything (~1.5 s on one core), which
    # the whole run waits for: it is made first, and waits in a thread while this one ingests.
    spawned = threading.Event()
    starting = threading.Thread(target=_start_pool, args=(pool, spawned), daemon=True)
    starting.start()
    try:
        with _shared_folder() as backgrounds, _progress(show_progress) as bar:
            task = bar.add_task("", total=len(todo))
            try:
                ahead = _ingest_ahead(todo, processed, starting)
                starting.join()
                report.pool_ready_s, report.ingested_ahead = time.perf_counter() - report.started, len(ahead)
                report.derived_ahead = sum("derived" in info for info in ahead.values())
                failed = {csv.name for csv, _stamp in todo if ahead.get(csv.name, {}).get("error")}
                for csv, _stamp in todo:
                    if csv.name in failed:
                        results.append(failed_ahead(csv, processed, ahead.pop(csv.name)))
                        bar.advance(task)
                todo = [item for item in todo if item[0].name not in failed]
                futures = {}
                for chunk in chunks(todo, jobs):
                    try:
                        with stops_deferred():      # a submit may start a worker (pipeline.run.stop)
                            futures[pool.submit(process_chunk, chunk, processed,
                                                {c.name: ahead[c.name] for c, _s in chunk if c.name in ahead},
                                                dataset=True, backgrounds=backgrounds)] = chunk
                    except BrokenProcessPool:           # the pool died already (while starting): retried below
                        broken.extend(chunk)
                for fut in as_completed(futures):
                    chunk = futures[fut]
                    try:
                        results.extend(fut.result())
                    except BrokenProcessPool:
                        broken.extend(chunk)
                        continue
                    bar.update(task, description=chunk[-1][0].name)
                    bar.advance(task, len(chunk))
            except BaseException as err:        # Ctrl-C or SIGTERM (pipeline.run.stop), whatever it surfaced as
                if (stop := stopped_by(err)) is None:
                    raise
                _stop_workers(pool, processed, spawned)
                raise stop from None
            pool.shutdown()
            # A worker that dies (e.g. a crash in a native library) takes every pending recording
            # with it: retry those one by one, each in a fresh worker, so only the culprit fails.
            for csv, stamp in sorted(broken, key=lambda item: item[0]):
                bar.update(task, description=f"{csv.name} (retry)")
                results.append(_isolated(csv, processed, stamp, method))
                bar.advance(task)
    finally:
        pool.shutdown()         # closed already, unless something failed before its block
    return results


def _refused(name: str, reason: str) -> dict:
    return {"recording": name, "status": "failed", "runs": [], "error": f"raw entry refused: {reason}",
            "timing_s": {}}


def refuse_nested(raw: Path, processed: Path) -> None:
    """An output folder inside the raw folder (``--processed raw/out``) would put outputs among the
    recordings and make them recordings of the next scan; a raw folder inside the outputs would be
    pruned as an orphan run.  Both are refused, as the same folder is (links resolved)."""
    r, p = raw.resolve(), processed.resolve()
    if p == r:
        raise PdrError("the output folder is the raw folder: give --processed a folder outside it", path=processed)
    if r in p.parents:
        raise PdrError(f"the output folder is inside the raw folder {raw}: give --processed a folder outside it",
                       path=processed)
    if p in r.parents:
        raise PdrError(f"the raw folder is inside the output folder {processed}: keep them apart", path=raw)


def run_pipeline(raw: Path, processed: Path, *, jobs: int = 2, force: bool = False,
                 show_progress: bool = False, code: str | None = None, method: str | None = None,
                 cluster: str | None = None) -> RunReport:
    """The imperative shell of ``pdr run`` (also what the benchmark and tests call).

    ``code`` pins the code version in the stamps (default: ``code_version()``),
    for callers that must not see a source tree being edited as a code change;
    ``method`` the pool's start method (default: ``pool.start_method()``);
    ``cluster`` a dask scheduler's address: the recordings go there instead of the local pool.
    """
    raw, processed = Path(raw), Path(processed)
    if not raw.is_dir():
        raise PdrError("raw folder not found (expected a folder of <name>.csv recordings)", path=raw)
    refuse_nested(raw, processed)
    report = RunReport(started=time.perf_counter())
    with processed_lock(processed):
        remove_stale_temporaries(processed)         # a killed run's summary.csv temporary
        folder = scan_raw(raw)
        report.ignored = folder.ignored
        failed = [_refused(name, reason) for name, reason in folder.refused.items()]
        code = code if code is not None else code_version()
        todo = []
        for csv in folder.recordings:
            try:
                stamp = stamp_for(csv, code)
            except (OSError, PdrError) as err:      # a rig TOML that is not a file; vanished since the scan
                failed.append(_refused(csv.name, describe_failure(err)))
                continue
            if not force and up_to_date(processed, csv, stamp):
                report.skipped.append(csv.name)
            else:
                todo.append((csv, stamp))
        withdrawn = sum(withdraw(processed, previous_runs(processed, raw / r["recording"])) for r in failed)
        if todo and cluster:
            from pipeline.cluster.execute import execute_on_cluster

            ran, on_cluster = execute_on_cluster(todo, processed, cluster, show_progress, report)
            report.notes += on_cluster.notes()
        else:
            ran = _execute(todo, processed, jobs, show_progress, report, method) if todo else []
        report.ran = sorted(ran + failed, key=lambda r: r["recording"])
        report.removed = prune_orphans(processed, raw, {c.name for c in folder.recordings} | set(folder.refused))
        if todo or withdrawn or report.removed or not (processed / SUMMARY_CSV).is_file():
            from pipeline.validate.summary import write_summary
            try:
                write_summary(processed)
            except OSError as err:      # reported beside the recordings' own results, not instead of them
                report.ran.append({"recording": SUMMARY_CSV, "status": "failed", "runs": [], "timing_s": {},
                                   "error": f"cannot write it: {describe_failure(err, processed)}"})
        if todo or withdrawn or report.removed or not (processed / DATASET_DIR).is_dir():
            from pipeline.dataset import refresh_dataset

            # the workers added the runs of the recordings they did (in_dataset); the rest is done here
            refresh_dataset(processed, changed={name for r in ran if not r.get("in_dataset") for name in r["runs"]})
    report.wall_s = time.perf_counter() - report.started
    return report
