"""The work one worker does on a few recordings: the stages ``pdr run`` chains (declared, with what each
reads and writes, in ``stamp.STAGES``).

One bad recording never stops the others: everything here returns failures instead of raising them.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Callable

from pipeline.errors import describe_failure
from pipeline.io.atomic import deferred_sync, write_json
from pipeline.run.stamp import previous_runs, withdraw
from pipeline.runs import RunPaths


def _child_cpu() -> float:
    """CPU seconds of this process's finished children (the ``rerun`` tool); 0 where ``resource`` is missing."""
    try:
        import resource
    except ImportError:         # Windows
        return 0.0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def process_recording(csv: Path, processed: Path, stamp) -> dict:
    """All stages on one recording (``pdr record`` calls it for the capture it just made); never raises."""
    return process_chunk([(csv, stamp)], processed)[0]


def process_chunk(items: list, processed: Path, ingested: dict[str, dict] | None = None,
                  dataset: bool = False, backgrounds: Path | None = None) -> list[dict]:
    """All stages on a few recordings (``(csv, stamp)`` pairs) in one worker task; never raises.

    Every stage but the ``.rrd`` verification runs recording by recording;
    then one ``rerun rrd verify`` checks all the chunk's files (starting the
    tool costs more than verifying a 500-sample file), and only the
    recordings whose files passed get their stamps.  A recording whose
    file fails is reported failed and its outputs withdrawn, like any other
    failure, so a re-run does it again.  ``dataset``: also add each
    recording's runs to ``processed/dataset/`` (``in_dataset`` in its result
    says it was done), synced with its outputs.  ``backgrounds``: a folder where the
    workers of one run share the overview figures' backgrounds (``plots.shared_backgrounds``).
    """
    from pipeline.validate.plots import shared_backgrounds
    from pipeline.validate.rerun_log import verify_rrds

    with deferred_sync(), shared_backgrounds(backgrounds):   # one sync for the chunk's files, before any stamp
        done = [all_stages(csv, processed, (ingested or {}).get(csv.name)) for csv, _stamp in items]
        if dataset:
            for (_csv, stamp), (out, _old) in zip(items, done):
                if out["status"] == "ok":
                    _add_to_dataset(processed, stamp, out)
    rrds = [RunPaths(processed / name).rrd for out, _old in done if out["status"] == "ok" for name in out["runs"]]
    t0, c0 = time.perf_counter(), _child_cpu()
    try:
        bad = verify_rrds(rrds)
    except Exception as err:  # the tool could not run (e.g. no space for its output): no file passes
        bad = {path: describe_failure(err, processed) for path in rrds}
    # the shared verification's time and CPU (the tool is a child process), split evenly over its files
    wall, cpu = (time.perf_counter() - t0) / max(len(rrds), 1), (_child_cpu() - c0) / max(len(rrds), 1)
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
                try:
                    for paths in runs:
                        write_json(paths.stamp, stamp.to_json(out["runs"]))
                except OSError as err:
                    out.update(status="failed", error=f"stamp: {describe_failure(err, processed)}")
                for name in set(old) - set(out["runs"]):
                    shutil.rmtree(processed / name, ignore_errors=True)
        if out["status"] == "failed":
            withdraw(processed, sorted(set(old) | set(out["runs"])))
        results.append(out)
    return results


def _add_to_dataset(processed: Path, stamp, out: dict) -> None:
    """``dataset.add_runs`` for a recording done; on failure its entries are left to ``pdr run``'s end."""
    from pipeline.dataset import add_runs

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        add_runs(processed, out["runs"], Path(stamp.raw_dir) / stamp.recording, stamp.raw_sha256)
        out["in_dataset"] = True
    except OSError:
        pass
    out["timing_s"]["dataset"] = time.perf_counter() - t0
    out["cpu_stage_s"]["dataset"] = cpu = time.process_time() - c0
    out["cpu_s"] += cpu


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
    except Exception as err:  # a bad input or a bug in pdr: never stops the other recordings
        out["error"] = f"ingest: {describe_failure(err, processed)}"
    out.update(wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0)
    return out


def failed_ahead(csv: Path, processed: Path, info: dict) -> dict:
    """The result of a recording whose ingest failed ahead of the workers (it goes to no worker)."""
    withdraw(processed, sorted(set(previous_runs(processed, csv)) | set(info["runs"])))
    return {"recording": csv.name, "status": "failed", "runs": info["runs"], "error": info["error"],
            "timing_s": {"ingest": info["wall_s"]}, "cpu_s": info["cpu_s"], "cpu_stage_s": {"ingest": info["cpu_s"]}}


def derive_ahead(info: dict, processed: Path) -> None:
    """Derive the runs ``ingest_ahead`` made (``info``), still in ``pdr run``'s own process; never raises.

    Adds ``derived`` (wall and CPU seconds) to ``info`` once every run is
    derived; on a failure it adds nothing, and the worker derives the
    recording again and reports what failed.
    """
    from pipeline.derive.stage import derive_and_write

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        for name in info["runs"]:
            derive_and_write(RunPaths(processed / name))
    except Exception:  # the worker meets it again, and says it
        return
    info["derived"] = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


def all_stages(csv: Path, processed: Path, ingested: dict | None = None) -> tuple[dict, list[str]]:
    """Ingest, derive and validate one recording (``.rrd`` not yet verified); the result and its previous runs.

    ``ingested``: ``ingest_ahead``'s result when the recording was ingested before it got here
    (with ``derived`` when ``derive_ahead`` derived it too: validate then reads derive's tables back).
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
        derived = (ingested or {}).get("derived")
        if derived is not None:
            timing["derive"], cpu["derive"] = derived["wall_s"], derived["cpu_s"]
            cpu0 -= derived["cpu_s"]
        out["runs"] = [p.name for p in runs]
        for paths in runs:
            stage = "derive"
            t0, c0 = time.perf_counter(), time.process_time()
            handed = None
            if derived is None:
                tables = derive_and_write(paths)
                handed = {"kinematics": tables.kinematics, "phases": tables.phases, "overshoot": tables.overshoot}
                timing["derive"] += time.perf_counter() - t0
            stage = "validate"
            c1 = time.process_time()
            row = validate_run(paths, derived=handed, verify=False)
            cpu["derive"] += c1 - c0
            cpu["validate"] += time.process_time() - c1
            for k, v in row.pop("timing_s").items():
                timing[k] = timing.get(k, 0.0) + v
    except Exception as err:  # a bad input or a bug in pdr: never stops the other recordings
        out.update(status="failed", error=f"{stage}: {describe_failure(err, processed)}")
    out["cpu_s"] = time.process_time() - cpu0
    return out, old
