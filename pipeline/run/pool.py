"""The local process pool ``pdr run`` (and discovery of many recordings) hands recordings to, and how the
recordings are sliced into its tasks; the cluster path slices the same way."""

from __future__ import annotations

import multiprocessing
import os
import threading

from pipeline.run.stop import children_ignore_sigint

# Imported once in the forkserver, inherited by every worker (its docstring says what it holds).
PRELOAD = ["pipeline.run.preload"]
CHUNK_MAX = 4      # recordings per worker task: one verify call for 4 files instead of 4 starts of the tool


def start_method() -> str:
    """``forkserver`` where the platform has it (Linux, macOS), else ``spawn`` (Windows)."""
    return "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"


# A worker collects young objects every 10,000 net allocations of container objects instead of Python's
# 700: a recording allocates many short-lived ones (pandas, matplotlib, rerun), and most of the
# collections at 700 find nothing to free; the garbage left between them is a few MB at most
# (docs/PERFORMANCE.md has the figures).
WORKER_GC_THRESHOLD = (10_000, 10, 10)


def _init_worker() -> None:
    """Worker initializer: fewer garbage collections, and exit as soon as the process that made the
    pool is gone (even by ``kill -9``)."""
    import gc

    gc.set_threshold(*WORKER_GC_THRESHOLD)
    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def wait() -> None:
        parent.join()
        os._exit(1)

    threading.Thread(target=wait, name="pdr-parent-watch", daemon=True).start()


def make_pool(jobs: int, method: str | None = None):
    from concurrent.futures import ProcessPoolExecutor

    method = method or start_method()
    ctx = multiprocessing.get_context(method)
    if method == "forkserver":
        from multiprocessing import forkserver

        ctx.set_forkserver_preload(PRELOAD)
        with children_ignore_sigint():      # Ctrl-C is the parent's to handle (pipeline.run.stop)
            forkserver.ensure_running()
    return ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_init_worker)


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
