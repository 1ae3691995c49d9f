"""A chunk function for the cluster tests: a recording named ``poison*`` kills the worker process that
takes it (as a crash in a native library would); the others are reported done without being processed
(the test is about which recordings fail, not about their outputs)."""

import os


def crash_on_poison(jobs):
    from distributed import get_worker

    if any(job.name.startswith("poison") for job in jobs):
        os._exit(1)
    return [{"recording": job.name, "status": "ok", "runs": [], "error": None, "timing_s": {}, "cpu_s": 0.0,
             "files": {}, "worker": get_worker().address} for job in jobs]
