"""``pdr run``: every stage on every new or changed recording of ``raw/``.

Incremental: each run folder gets a ``stamp.json`` holding one key per
recording, the hash of (raw bytes, the bytes of every rig TOML layer that
applies, the code version = hash of ``pipeline/**/*.py`` and ``schemas/*.json``).
A recording whose runs all carry the current key and all outputs is skipped;
deciding that reads a few kilobytes per recording and imports nothing heavy, so
a re-run with nothing changed takes well under two seconds.

Parallel: recordings are independent, so they go to a process pool (both
cores by default), a few per task (``chunks``) so that one ``rerun rrd
verify`` checks several files.  Workers come from a ``forkserver`` that has
already imported numpy, pandas, pyarrow, rerun and matplotlib, so a worker
starts in milliseconds, and each worker keeps its overview figure between
recordings.  Those imports take ~2 s on one core; meanwhile this process
ingests recordings from the end of the list (``_ingest_ahead``), which the
workers then skip.  One bad recording never stops the others: its error is reported
(a ``PdrError`` as the user-facing line, anything else as an internal error),
its stale outputs are withdrawn so ``pdr gate`` cannot pass on old figures,
and the exit status is non-zero.

Concurrency: an exclusive lock (``processed/.pdr.lock``, ``flock``) is held
for the whole run, so two ``pdr run`` on the same folder run one after the
other; the second finds everything up to date.
"""

from __future__ import annotations

import fcntl
import hashlib
import importlib
import json
import os
import shutil
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import typer

from pipeline.config import config_layers_for
from pipeline.dataset import DATASET_DIR, refresh_dataset
from pipeline.errors import PdrError
from pipeline.io.atomic import deferred_sync, write_json
from pipeline.runs import RunPaths

LOCK_NAME = ".pdr.lock"
PACKAGE_ROOT = Path(__file__).resolve().parent
SCHEMA_ROOT = PACKAGE_ROOT.parent / "schemas"
STAGES = ("ingest", "derive", "validate")
# Imported once in the forkserver, inherited by every worker.
PRELOAD = ["numpy", "pandas", "pyarrow.parquet", "rerun", "matplotlib.figure", "pipeline.run",
           "pipeline.ingest.stage", "pipeline.derive.stage", "pipeline.validate.stage",
           "pipeline.validate.rerun_log", "pipeline.validate.warmup"]


@contextmanager
def processed_lock(processed: Path, wait_message: bool = True) -> Iterator[None]:
    """Exclusive lock on ``processed/`` for the duration of a run (released on exit, even if killed)."""
    processed = Path(processed)
    processed.mkdir(parents=True, exist_ok=True)
    with open(processed / LOCK_NAME, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if wait_message:
                print(f"pdr: waiting for another pdr process using {processed}/ ...", file=sys.stderr)
            fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def code_version() -> str:
    """Hash of the pipeline's source and schemas: any code change re-runs every recording."""
    h = hashlib.sha256()
    files = sorted(PACKAGE_ROOT.rglob("*.py")) + sorted(SCHEMA_ROOT.glob("*.json"))
    for path in files:
        h.update(str(path.relative_to(PACKAGE_ROOT.parent)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


@dataclass(frozen=True)
class Stamp:
    """What a recording's outputs were made from."""

    recording: str                      # raw file name
    raw_dir: str                        # resolved raw folder
    raw_sha256: str
    config_layers: dict[str, str]       # TOML path -> sha256
    code_version: str

    @property
    def key(self) -> str:
        blob = json.dumps([self.recording, self.raw_sha256, sorted(self.config_layers.items()),
                           self.code_version])
        return hashlib.sha256(blob.encode()).hexdigest()[:24]

    def to_json(self, runs: list[str]) -> dict:
        return {"recording": self.recording, "raw_dir": self.raw_dir, "raw_sha256": self.raw_sha256,
                "config_layers": self.config_layers, "code_version": self.code_version, "key": self.key,
                "runs": runs, "stages": list(STAGES)}


def stamp_for(csv: Path, code: str) -> Stamp:
    layers = {str(p): _sha256(p) for p in config_layers_for(csv)}
    return Stamp(recording=csv.name, raw_dir=str(csv.parent.resolve()), raw_sha256=_sha256(csv),
                 config_layers=layers, code_version=code)


def candidate_runs(processed: Path, csv: Path) -> list[Path]:
    """Folders that may hold this recording's runs: ``<stem>`` and ``<stem>-segN``."""
    stem = csv.stem
    found = [processed / stem] if (processed / stem).is_dir() else []
    found += [p for p in processed.glob(f"{stem}-seg*") if p.name[len(stem) + 4:].isdigit()]
    return found


def _read_stamp(run_dir: Path) -> dict | None:
    try:
        return json.loads((run_dir / "stamp.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def previous_runs(processed: Path, csv: Path) -> list[str]:
    """Runs the last successful processing of this recording produced (from their stamps)."""
    runs: set[str] = set()
    for d in candidate_runs(processed, csv):
        s = _read_stamp(d)
        if s and s.get("recording") == csv.name:
            runs.update(s.get("runs", []))
    return sorted(runs)


def up_to_date(processed: Path, csv: Path, stamp: Stamp) -> bool:
    """All runs of the recording exist, carry the current key, and have every stage's last output."""
    runs = previous_runs(processed, csv)
    if not runs:
        return False
    for name in runs:
        paths = RunPaths(processed / name)
        s = _read_stamp(paths.root)
        if s is None or s.get("key") != stamp.key or not paths.validation.is_file():
            return False
    return True


def _withdraw(processed: Path, runs: list[str]) -> None:
    """A recording that failed: its old stamps and validations no longer describe its raw file."""
    for name in runs:
        paths = RunPaths(processed / name)
        for f in (paths.stamp, paths.validation):
            f.unlink(missing_ok=True)


def process_recording(csv: Path, processed: Path, stamp: Stamp) -> dict:
    """All stages on one recording (runs in a worker). Never raises: failures are returned."""
    return process_chunk([(csv, stamp)], processed)[0]


def process_chunk(items: list[tuple[Path, Stamp]], processed: Path, ingested: dict[str, dict] | None = None
                  ) -> list[dict]:
    """All stages on a few recordings in one worker task; never raises: failures are returned per recording.

    Every stage but the ``.rrd`` verification runs recording by recording;
    then one ``rerun rrd verify`` checks all the chunk's files (starting the
    tool costs more than verifying a 500-sample file), and only the
    recordings whose files passed get their stamps.  A recording whose
    file fails is reported failed and its outputs withdrawn, like any other
    failure, so a re-run does it again.
    """
    import resource

    from pipeline.validate.rerun_log import verify_rrds

    def child_cpu() -> float:
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        return usage.ru_utime + usage.ru_stime

    with deferred_sync():       # one sync for the chunk's files, before any of their stamps
        done = [_all_stages(csv, processed, (ingested or {}).get(csv.name)) for csv, _stamp in items]
    rrds = [RunPaths(processed / name).rrd for out, _old in done if out["status"] == "ok" for name in out["runs"]]
    t0, c0 = time.perf_counter(), child_cpu()
    bad = verify_rrds(rrds)
    # the shared verification's time and CPU (the tool is a child process), split evenly over its files
    wall, cpu = (time.perf_counter() - t0) / max(len(rrds), 1), (child_cpu() - c0) / max(len(rrds), 1)
    results = []
    for (csv, stamp), (out, old) in zip(items, done):
        if out["status"] == "ok":
            runs = [RunPaths(processed / name) for name in out["runs"]]
            out["timing_s"]["rrd_verify"] = wall * len(runs)
            out["cpu_s"] += cpu * len(runs)
            out["cpu_stage_s"]["rrd_verify"] = cpu * len(runs)
            failed = [p.rrd for p in runs if p.rrd in bad]
            if failed:
                out.update(status="failed", error=f"validate: {bad[failed[0]]} ({failed[0].name})")
                for path in failed:
                    path.unlink(missing_ok=True)
            else:
                for paths in runs:
                    write_json(paths.stamp, stamp.to_json(out["runs"]))
                for name in set(old) - set(out["runs"]):
                    shutil.rmtree(processed / name, ignore_errors=True)
        if out["status"] == "failed":
            _withdraw(processed, sorted(set(old) | set(out["runs"])))
        results.append(out)
    return results


def ingest_ahead(csv: Path, processed: Path, ingest: Callable[[], list[str]] | None = None) -> dict:
    """Ingest one recording in ``pdr run``'s own process while the workers start; never raises.

    Returns what ``process_chunk`` needs to skip the ingest (``runs``), its
    wall and CPU time, or ``error`` (the recording then goes to no worker).
    ``ingest``: makes the runs and returns their names (default: ``ingest_recording`` on the file).
    """
    from pipeline.ingest.stage import ingest_recording

    t0, c0 = time.perf_counter(), time.process_time()
    out: dict = {"runs": [], "error": None}
    try:
        out["runs"] = ingest() if ingest is not None else [p.name for p in ingest_recording(csv, processed).runs]
    except PdrError as err:
        out["error"] = f"ingest: {err}"
    except Exception as err:  # a bug in pdr: still never stops the other recordings
        out["error"] = f"ingest: internal error {type(err).__name__}: {err}"
    out.update(wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0)
    return out


def _all_stages(csv: Path, processed: Path, ingested: dict | None = None) -> tuple[dict, list[str]]:
    """Ingest, derive and validate one recording (``.rrd`` not yet verified); the result and its previous runs.

    ``ingested``: ``ingest_ahead``'s result when the recording was ingested before it got here.
    """
    from pipeline.derive.stage import derive_and_write
    from pipeline.ingest.stage import ingest_recording
    from pipeline.validate.stage import validate_run

    timing = {"ingest": 0.0, "derive": 0.0}
    cpu = {"ingest": 0.0, "derive": 0.0, "validate": 0.0}   # process CPU (all threads) per stage
    out: dict = {"recording": csv.name, "status": "ok", "runs": [], "error": None, "timing_s": timing,
                 "cpu_stage_s": cpu}
    cpu0 = time.process_time()      # all threads of this worker: what the recording cost the machine
    old = previous_runs(processed, csv)
    stage = "ingest"
    try:
        if ingested is None:
            t0 = time.perf_counter()
            runs = ingest_recording(csv, processed).runs
            timing["ingest"] = time.perf_counter() - t0
            cpu["ingest"] = time.process_time() - cpu0
        else:
            runs = [RunPaths(processed / name) for name in ingested["runs"]]
            timing["ingest"], cpu["ingest"] = ingested["wall_s"], ingested["cpu_s"]
            cpu0 -= ingested["cpu_s"]
        out["runs"] = [p.name for p in runs]
        for paths in runs:
            stage = "derive"
            t0, c0 = time.perf_counter(), time.process_time()
            tables = derive_and_write(paths)
            timing["derive"] += time.perf_counter() - t0
            stage = "validate"
            c1 = time.process_time()
            row = validate_run(paths, derived={"kinematics": tables.kinematics, "phases": tables.phases,
                                               "overshoot": tables.overshoot}, verify=False)
            cpu["derive"] += c1 - c0
            cpu["validate"] += time.process_time() - c1
            for k, v in row.pop("timing_s").items():
                timing[k] = timing.get(k, 0.0) + v
    except PdrError as err:
        out.update(status="failed", error=f"{stage}: {err}")
    except Exception as err:  # a bug in pdr: still never stops the other recordings
        out.update(status="failed", error=f"{stage}: internal error {type(err).__name__}: {err}")
    out["cpu_s"] = time.process_time() - cpu0
    return out, old


@dataclass
class RunReport:
    ran: list[dict] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    pool_ready_s: float | None = None      # when the first worker could take a recording (from the run's start)
    ingested_ahead: int = 0                # recordings this process ingested meanwhile
    started: float = 0.0                   # perf_counter at the run's start
    notes: list[str] = field(default_factory=list)   # what else happened (on a cluster: workers lost, re-runs)

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.ran if r["status"] != "ok"]

    def cpu_seconds(self) -> float:
        """CPU time the recordings took in the workers (excludes pool start-up and waiting)."""
        return sum(r.get("cpu_s", 0.0) for r in self.ran)

    def stage_cpu_seconds(self) -> dict[str, float]:
        """CPU seconds per stage summed over the recordings (``rrd_verify``: the ``rerun`` child processes)."""
        total: dict[str, float] = {}
        for r in self.ran:
            for k, v in r.get("cpu_stage_s", {}).items():
                total[k] = total.get(k, 0.0) + v
        return total

    def stage_seconds(self) -> dict[str, float]:
        total: dict[str, float] = {}
        for r in self.ran:
            for k, v in r["timing_s"].items():
                total[k] = total.get(k, 0.0) + v
        return total


def prune_orphans(processed: Path, raw: Path, recordings: list[Path]) -> list[str]:
    """Remove runs whose stamp names a recording of this raw folder that no longer exists."""
    names = {c.name for c in recordings}
    raw_dir = str(raw.resolve())
    removed = []
    for d in sorted(p for p in processed.iterdir() if p.is_dir() and not p.name.startswith(".")):
        s = _read_stamp(d)
        if s and s.get("raw_dir") == raw_dir and s.get("recording") not in names:
            shutil.rmtree(d, ignore_errors=True)
            removed.append(d.name)
    return removed


def _pool(jobs: int):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(PRELOAD)
    return ProcessPoolExecutor(max_workers=jobs, mp_context=ctx)


def _isolated(csv: Path, processed: Path, stamp: Stamp) -> dict:
    from concurrent.futures.process import BrokenProcessPool

    with _pool(1) as pool:
        try:
            return pool.submit(process_recording, csv, processed, stamp).result()
        except BrokenProcessPool as err:
            _withdraw(processed, previous_runs(processed, csv))
            return {"recording": csv.name, "status": "failed", "runs": [],
                    "error": f"the worker process died while processing it ({err})", "timing_s": {}}


CHUNK_MAX = 4      # recordings per worker task: one verify call for 4 files instead of 4 starts of the tool


def chunks(todo: list, jobs: int) -> list[list]:
    """Consecutive slices of ``todo``: up to ``CHUNK_MAX`` each, small enough that every worker gets several.

    The last ``2 * jobs`` slices hold half as many, so the workers finish
    within about one recording of each other instead of one whole chunk.
    """
    size = max(1, min(CHUNK_MAX, len(todo) // (4 * jobs)))
    tail_size = max(1, size // 2)
    tail = min(len(todo), 2 * jobs * tail_size) if size > 1 else 0
    head = (len(todo) - tail) // size * size
    return ([todo[i:i + size] for i in range(0, head, size)]
            + [todo[i:i + tail_size] for i in range(head, len(todo), tail_size)])


def _start_pool(pool) -> None:
    """Start the pool's forkserver and first worker (returns when a worker has run a task)."""
    from concurrent.futures.process import BrokenProcessPool

    try:
        pool.submit(os.getpid).result()
    except BrokenProcessPool:      # the submissions that follow see it and retry each recording alone
        pass


def _ingest_ahead(todo: list[tuple[Path, Stamp]], processed: Path, starting: threading.Thread) -> dict[str, dict]:
    """Use the core that is idle while the forkserver imports: ingest recordings from the end of the list.

    Stops as soon as the pool has started (``starting`` finished); the workers
    then skip the ingest of what was done here.  The summary's pandas import
    comes first (the ingest needs it too).
    """
    importlib.import_module("pipeline.validate.summary")
    ahead: dict[str, dict] = {}
    with deferred_sync():
        for csv, _stamp in reversed(todo):
            if not starting.is_alive():
                break
            ahead[csv.name] = ingest_ahead(csv, processed)
    return ahead


def _failed_ahead(csv: Path, processed: Path, info: dict) -> dict:
    """The result of a recording whose ingest failed in ``_ingest_ahead`` (it goes to no worker)."""
    _withdraw(processed, sorted(set(previous_runs(processed, csv)) | set(info["runs"])))
    return {"recording": csv.name, "status": "failed", "runs": info["runs"], "error": info["error"],
            "timing_s": {"ingest": info["wall_s"]}, "cpu_s": info["cpu_s"], "cpu_stage_s": {"ingest": info["cpu_s"]}}


def _execute(todo: list[tuple[Path, Stamp]], processed: Path, jobs: int, show_progress: bool,
             report: RunReport | None = None) -> list[dict]:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    results: list[dict] = []
    with Progress(TextColumn("[bold]pdr run"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  TextColumn("{task.description}"), disable=not show_progress, transient=False) as bar:
        task = bar.add_task("", total=len(todo))
        if jobs <= 1 or len(todo) <= 1:
            for chunk in chunks(todo, 1):
                bar.update(task, description=chunk[0][0].name)
                results.extend(process_chunk(chunk, processed))
                bar.advance(task, len(chunk))
            return results
        from concurrent.futures import as_completed
        from concurrent.futures.process import BrokenProcessPool

        broken: list[tuple[Path, Stamp]] = []
        with _pool(min(jobs, len(todo))) as pool:
            # The first submit blocks until the forkserver has imported everything (~2 s on one core):
            # it waits in a thread while this one ingests.
            starting = threading.Thread(target=_start_pool, args=(pool,), daemon=True)
            starting.start()
            ahead = _ingest_ahead(todo, processed, starting)
            starting.join()
            if report is not None:
                report.pool_ready_s, report.ingested_ahead = time.perf_counter() - report.started, len(ahead)
            failed = {csv.name for csv, _stamp in todo if ahead.get(csv.name, {}).get("error")}
            for csv, _stamp in todo:
                if csv.name in failed:
                    results.append(_failed_ahead(csv, processed, ahead.pop(csv.name)))
                    bar.advance(task)
            todo = [item for item in todo if item[0].name not in failed]
            futures = {}
            for chunk in chunks(todo, jobs):
                try:
                    futures[pool.submit(process_chunk, chunk, processed,
                                        {c.name: ahead[c.name] for c, _s in chunk if c.name in ahead})] = chunk
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
        # A worker that dies (e.g. a crash in a native library) takes every pending recording
        # with it: retry those one by one, each in a fresh worker, so only the culprit fails.
        for csv, stamp in sorted(broken, key=lambda item: item[0]):
            bar.update(task, description=f"{csv.name} (retry)")
            results.append(_isolated(csv, processed, stamp))
            bar.advance(task)
    return sorted(results, key=lambda r: r["recording"])


def run_pipeline(raw: Path, processed: Path, *, jobs: int = 2, force: bool = False,
                 show_progress: bool = False, code: str | None = None, cluster: str | None = None) -> RunReport:
    """The imperative shell of ``pdr run`` (also what the benchmark and tests call).

    ``code`` pins the code version in the stamps (default: ``code_version()``),
    for callers that must not see a source tree being edited as a code change.
    ``cluster``: a dask scheduler's address; the recordings go there instead of the local pool.
    """
    raw, processed = Path(raw), Path(processed)
    if not raw.is_dir():
        raise PdrError("raw folder not found (expected a folder of <name>.csv recordings)", path=raw)
    report = RunReport(started=time.perf_counter())
    t0 = report.started
    with processed_lock(processed):
        recordings = sorted(raw.glob("*.csv"))
        code = code if code is not None else code_version()
        todo = []
        for csv in recordings:
            stamp = stamp_for(csv, code)
            if not force and up_to_date(processed, csv, stamp):
                report.skipped.append(csv.name)
            else:
                todo.append((csv, stamp))
        if todo and cluster:
            from pipeline.cluster.execute import execute_on_cluster
            report.ran, on_cluster = execute_on_cluster(todo, processed, cluster, show_progress, report)
            report.notes += on_cluster.notes()
        elif todo:
            report.ran = _execute(todo, processed, jobs, show_progress, report)
        report.removed = prune_orphans(processed, raw, recordings)
        summary_csv = processed / "summary.csv"
        if todo or report.removed or not summary_csv.is_file():
            from pipeline.validate.summary import write_summary
            write_summary(processed)
        if todo or report.removed or not (processed / DATASET_DIR).is_dir():
            refresh_dataset(processed, changed={name for r in report.ran for name in r["runs"]})
    report.wall_s = time.perf_counter() - t0
    return report


def print_report(report: RunReport, processed: Path) -> None:
    """End-of-run summary: what ran, what was skipped, what failed and why, where the time went."""
    from pipeline.validate.console import wide_console

    console = wide_console()
    n_runs = sum(len(r["runs"]) for r in report.ran if r["status"] == "ok")
    ok = len(report.ran) - len(report.failed)
    console.print(f"[bold]pdr run[/]: {ok} recording(s) processed ({n_runs} runs), "
                  f"{len(report.skipped)} unchanged and skipped, {len(report.failed)} failed"
                  + (f", {len(report.removed)} stale run(s) removed" if report.removed else "")
                  + f" in {report.wall_s:.2f} s")
    if report.skipped:
        shown = ", ".join(report.skipped[:8]) + (f", ... ({len(report.skipped) - 8} more)" if len(report.skipped) > 8 else "")
        console.print(f"unchanged (raw bytes, rig TOML layers and code as stamped): {shown}")
    if report.removed:
        console.print(f"removed runs of recordings no longer in the raw folder: {', '.join(report.removed)}")
    if report.ran:
        secs = report.stage_seconds()
        total = sum(secs.values()) or 1.0
        parts = ", ".join(f"{k} {v:.2f} s ({100 * v / total:.0f} %)" for k, v in secs.items())
        console.print(f"time by stage (summed over workers): {parts}")

        from pipeline.validate.summary import render_summary, summary_table

        table = summary_table(processed)
        ran = {name for r in report.ran for name in r["runs"]}
        render_summary(table[table["run"].isin(ran)] if not table.empty else table, console)
    for note in report.notes:
        console.print(note)
    for r in report.failed:
        console.print(f"[red]FAILED[/] {r['recording']}: {r['error']}")


def run_command(
    raw: Path = typer.Option(Path("raw"), "--raw", help="Folder of raw recordings (<name>.csv + optional <name>.toml)."),
    processed: Path = typer.Option(Path("processed"), "--processed", help="Output folder."),
    jobs: int = typer.Option(min(2, os.cpu_count() or 1), "--jobs", "-j", min=1, help="Worker processes."),
    force: bool = typer.Option(False, "--force", help="Re-run every recording even if unchanged."),
    cluster: str = typer.Option("", "--cluster", envvar="PDR_CLUSTER", show_envvar=True,
                                help="A dask scheduler (tcp://HOST:8786): the recordings are processed by its "
                                     "workers, the outputs written here."),
) -> None:
    """Run every stage (ingest, derive, validate) on every new or changed recording in raw/;
    unchanged ones are skipped. Exit status 1 if any recording failed.

    Example: pdr run --raw raw --processed processed -j 2   (or --cluster tcp://HOST:8786)
    """
    report = run_pipeline(raw, processed, jobs=jobs, force=force, show_progress=sys.stderr.isatty(),
                          cluster=cluster or None)
    print_report(report, processed)
    if report.failed:
        raise typer.Exit(1)
