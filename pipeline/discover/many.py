"""``pdr discover RECORDING...``: discovery on many raw recordings, locally or on a dask cluster, then
the questions across them (``across.py``).

Each recording is ingested, derived and discovered where it is sent (a local
worker process, or a cluster worker that gets the raw bytes and the resolved
rig configuration, as ``pdr run --cluster`` does); what comes back is the
discovery document and its files' bytes, which this process writes into
``<out>/<run>/`` atomically, as ``pdr discover`` on one recording would.  Then
``<out>/summary.csv`` (one row per run), ``<out>/pooled.csv`` (per rig and
effect parameter) and ``<out>/parameters.png``.

The time axis of the trend is each raw file's modification time (when the
capture was written), reported per run as ``recorded``.
"""

from __future__ import annotations

import tempfile
from concurrent.futures import Executor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from pipeline.cluster.work import RecordingJob, ingest_bytes, scratch_root
from pipeline.errors import PdrError
from pipeline.io.atomic import write_bytes, write_text
from pipeline.io.files import recording_file_problem

SUMMARY_NAME = "summary.csv"
POOLED_NAME = "pooled.csv"
PLOT_NAME = "parameters.png"


@dataclass
class ManyResult:
    table: pd.DataFrame                 # summary.csv
    pooled: pd.DataFrame                # pooled.csv
    written: dict[str, Path]
    failed: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def discover_job(job: RecordingJob, rrd: bool) -> dict:
    """Runs where the job is sent: ingest, derive and discover one recording; never raises for its failure.

    One segment is used when the board reset mid-file (``stage.segment_to_discover``), as ``pdr discover`` does.
    """
    from pipeline.derive.stage import derive_run
    from pipeline.discover.report import write_outputs
    from pipeline.discover.stage import discover_run, segment_to_discover
    from pipeline.runs import RunPaths

    out: dict = {"recording": job.source, "run": Path(job.source).stem, "doc": None, "files": {}, "error": None}
    try:
        with tempfile.TemporaryDirectory(prefix="pdr-discover-", dir=scratch_root()) as tmp:
            processed = Path(tmp) / "processed"
            runs = [RunPaths(processed / name) for name in ingest_bytes(job, processed)]
            if not runs:
                raise PdrError("no usable segment in the recording", path=job.source)
            for paths in runs:
                derive_run(paths)
            paths = segment_to_discover(runs)
            d, doc = discover_run(paths, recording=job.source)
            if len(runs) > 1:
                doc["segments"] = {"used": paths.name, "others": [p.name for p in runs if p != paths]}
            written = write_outputs(Path(tmp) / "out", d, doc, rrd=rrd)
            out.update(run=paths.name, doc=doc, files={p.name: p.read_bytes() for p in written.values()})
    except PdrError as err:
        out["error"] = str(err)
    except Exception as err:  # a bug in pdr: still never stops the other recordings
        out["error"] = f"internal error {type(err).__name__}: {err}"
    return out


def _jobs(recordings: list[Path]) -> tuple[list[tuple[RecordingJob, float]], list[dict]]:
    """Each raw file read with its resolved config and modification time; unreadable ones as failures."""
    from pipeline.config import config_for_recording

    jobs, failed, seen = [], [], {}
    for csv in recordings:
        try:
            if csv.suffix.lower() != ".csv" or not csv.is_file():
                raise PdrError("expected a raw .csv recording (several recordings: raw files only)", path=csv)
            if (problem := recording_file_problem(csv)) is not None:      # before reading it whole
                raise PdrError(problem, path=csv)
            if csv.stem in seen:
                raise PdrError(f"has the name of {seen[csv.stem]}, also given: runs are named after the file, "
                               "so one of them would overwrite the other's outputs", path=csv)
            seen[csv.stem] = str(csv)
            jobs.append((RecordingJob(source=str(csv), data=csv.read_bytes(), config=config_for_recording(csv)),
                         csv.stat().st_mtime))
        except PdrError as err:
            failed.append({"recording": str(csv), "run": csv.stem, "error": str(err)})
        except OSError as err:
            failed.append({"recording": str(csv), "run": csv.stem,
                           "error": str(PdrError(f"cannot read the recording: {err.strerror}", path=csv))})
    return jobs, failed


def _executor(jobs: int, cluster: str | None) -> tuple[Executor, object | None]:
    """A concurrent.futures executor: the cluster's (``Client.get_executor``), the local forkserver pool,
    or for one job a thread of this process (no worker to start)."""
    if cluster:
        from pipeline.cluster.connect import connect

        client = connect(cluster)
        return client.get_executor(pure=False), client
    if jobs <= 1:
        from concurrent.futures import ThreadPoolExecutor

        return ThreadPoolExecutor(max_workers=1), None
    from pipeline.cluster.runner import local_pool

    return local_pool(jobs), None


def _shut_down(executor: Executor, stopping: bool, on_cluster: bool) -> None:
    """Wait for the recordings under way; on a stop, those not begun are cancelled first (a local worker
    ignores Ctrl-C, so the one or two it is running end within a recording's time, their outputs unwritten),
    and a cluster's are cancelled where they run."""
    if not stopping:
        executor.shutdown(wait=True)
    elif on_cluster:
        executor.shutdown(wait=False)
    else:
        executor.shutdown(wait=True, cancel_futures=True)


def discover_many(recordings: list[Path], out: Path, *, jobs: int = 2, cluster: str | None = None,
                  rrd: bool = True, show_progress: bool = False) -> ManyResult:
    """Discovery on every recording, its outputs under ``out/<run>/``, then the tables across runs."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from pipeline.discover.across import (failed_row, parameters_png, pooled_frame, rig_key, run_row,
                                          summary_frame)

    out = Path(out)
    todo, failed = _jobs([Path(r) for r in recordings])
    rows = [failed_row(f["recording"], f["run"], None, None, f["error"]) for f in failed]
    executor, client = _executor(jobs, cluster)
    notes = [f"on the dask cluster {cluster}"] if cluster else []
    stopping = False
    try:
        with Progress(TextColumn("[bold]pdr discover"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      TextColumn("{task.description}"), disable=not show_progress, transient=False) as bar:
            task = bar.add_task("", total=len(recordings), completed=len(failed))
            futures = {executor.submit(discover_job, job, rrd): (job, mtime) for job, mtime in todo}
            for fut in as_completed(futures):
                job, mtime = futures[fut]
                rig = rig_key(job.config)
                try:
                    result = fut.result()
                except Exception as err:  # the worker died (local pool) or the cluster gave up on the task
                    result = {"recording": job.source, "run": Path(job.source).stem, "doc": None, "files": {},
                              "error": f"the worker running it died ({type(err).__name__}: {err})"}
                if result["error"] is None:
                    for name, data in result["files"].items():
                        write_bytes(out / result["run"] / name, data)
                    rows.append(run_row(result["doc"], mtime, rig))
                else:
                    failed.append(result)
                    rows.append(failed_row(job.source, result["run"], mtime, rig, result["error"]))
                bar.update(task, description=Path(job.source).name)
                bar.advance(task)
    except BaseException:       # Ctrl-C or SIGTERM (``pipeline.run.stop``): nothing more is begun
        stopping = True
        raise
    finally:
        _shut_down(executor, stopping, on_cluster=client is not None)
        if client is not None:
            client.close()
    table = summary_frame(rows)
    pooled = pooled_frame(table)
    written = {"summary": out / SUMMARY_NAME, "pooled": out / POOLED_NAME, "plot": out / PLOT_NAME}
    shown = table.drop(columns=["recorded_s"], errors="ignore")     # ``recorded`` says it to the second
    write_text(written["summary"], shown.to_csv(index=False, float_format="%.8g", lineterminator="\n"))
    write_text(written["pooled"], pooled.to_csv(index=False, float_format="%.8g", lineterminator="\n"))
    write_bytes(written["plot"], parameters_png(table, pooled))
    return ManyResult(table, pooled, written, failed, notes)
