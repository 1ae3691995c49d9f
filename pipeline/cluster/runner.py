"""The local runner's pieces that the cluster path and discovery of many recordings reuse, imported here
only: when ``pipeline.run`` moves them (it is being split into a package: runner, stages, stamp,
report), this is the one file to change."""

from pipeline.run import PRELOAD, RunReport, Stamp, chunks, code_version, ingest_ahead, previous_runs, process_chunk
from pipeline.run import _failed_ahead as failed_ahead
from pipeline.run import _pool as local_pool
from pipeline.run import _withdraw as withdraw

__all__ = ["PRELOAD", "RunReport", "Stamp", "chunks", "code_version", "failed_ahead", "ingest_ahead", "local_pool",
           "previous_runs", "process_chunk", "withdraw"]
