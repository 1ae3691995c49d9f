"""The pieces of ``pipeline.run`` that the cluster path and discovery of many recordings reuse, imported here
only, so a move inside ``pipeline.run`` is a change to this one file."""

from pipeline.run.report import RunReport
from pipeline.run.pool import PRELOAD, chunks
from pipeline.run.pool import make_pool as local_pool
from pipeline.run.stages import failed_ahead, ingest_ahead, process_chunk
from pipeline.run.stamp import Stamp, code_version, previous_runs, withdraw

__all__ = ["PRELOAD", "RunReport", "Stamp", "chunks", "code_version", "failed_ahead", "ingest_ahead", "local_pool",
           "previous_runs", "process_chunk", "withdraw"]
