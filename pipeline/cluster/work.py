"""What a cluster worker runs: one chunk of recordings, from raw bytes to output bytes.

The worker never sees the client's folders.  It ingests the bytes it was sent
under the recording's own path name (which the ingest report and the error
messages quote, so they read as in a local run), then hands the chunk to the
local runner's ``process_chunk`` in a scratch folder: the same derive,
validate, ``.rrd`` verification and stamps, by the same code.  What it
returns is every file of every run it made, as bytes keyed by
``<run>/<file>``, beside ``process_chunk``'s per-recording result.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from pipeline.config import RigConfig
from pipeline.cluster.runner import Stamp, failed_ahead, ingest_ahead, process_chunk

SCRATCH_ENV = "PDR_SCRATCH"


@dataclass(frozen=True)
class RecordingJob:
    """One recording as the client sends it: no path on the worker is read."""

    source: str             # the raw file's path as the client names it (quoted in reports and errors)
    data: bytes             # the raw file's bytes
    config: RigConfig       # resolved on the client from its rig TOML layers
    stamp: Stamp | None = None      # pdr run's; discovery needs none

    @property
    def name(self) -> str:
        return Path(self.source).name


def scratch_root() -> str | None:
    """``PDR_SCRATCH``, else ``/dev/shm`` (memory: the files live there only until read back), else the default."""
    chosen = os.environ.get(SCRATCH_ENV)
    if chosen:
        return chosen
    shm = Path("/dev/shm")
    return str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None


def ingest_bytes(job: RecordingJob, scratch: Path) -> list[str]:
    """``ingest_recording``'s work on bytes already read; the names of the runs made."""
    from pipeline.ingest.stage import ingest_signals
    from pipeline.ingest.write import write_run

    runs, _report, paths = ingest_signals(job.data, job.config, job.source, Path(job.source).stem, scratch)
    for run, run_paths in zip(runs, paths):
        write_run(run_paths, run.signals, run.report, job.config)
    return [p.name for p in paths]


def _files(run_dir: Path) -> dict[str, bytes]:
    return {f"{run_dir.name}/{f.name}": f.read_bytes() for f in sorted(run_dir.iterdir()) if f.is_file()}


def run_chunk(jobs: list[RecordingJob]) -> list[dict]:
    """Every stage on a chunk of recordings; never raises for a recording's failure.

    Each result is ``process_chunk``'s (status, runs, error, timings) plus
    ``files`` (``<run>/<file>`` -> bytes, stamps included; empty when the
    recording failed) and ``worker`` (this worker's address).
    """
    try:
        from distributed import get_worker
        worker = get_worker().address
    except (ImportError, ValueError):
        worker = "local"
    with tempfile.TemporaryDirectory(prefix="pdr-worker-", dir=scratch_root()) as tmp:
        scratch = Path(tmp)
        ingested = {job.name: ingest_ahead(Path(job.source), scratch, lambda job=job: ingest_bytes(job, scratch))
                    for job in jobs}
        ok = [job for job in jobs if ingested[job.name]["error"] is None]
        done = {r["recording"]: r for r in process_chunk([(Path(j.source), j.stamp) for j in ok], scratch,
                                                         {j.name: ingested[j.name] for j in ok})}
        results = []
        for job in jobs:
            info = ingested[job.name]
            result = done[job.name] if info["error"] is None else failed_ahead(Path(job.source), scratch, info)
            files: dict[str, bytes] = {}
            if result["status"] == "ok":
                for run in result["runs"]:
                    files.update(_files(scratch / run))
            result.update(files=files, worker=worker)
            results.append(result)
    return results
