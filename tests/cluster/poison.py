"""A chunk function for the cluster tests: the real work, except that a recording named ``poison*`` kills
the worker process that takes it (as a crash in a native library would)."""

import os

from pipeline.cluster.work import run_chunk


def crash_on_poison(jobs):
    if any(job.name.startswith("poison") for job in jobs):
        os._exit(1)
    return run_chunk(jobs)
