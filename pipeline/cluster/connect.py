"""Reaching a dask cluster: the address, the connection, and a check that the workers run this pdr.

A cluster whose workers run other pdr code would write outputs stamped with a
code version they were not made by, so the client compares the hash of its
own source tree (``pipeline.run.code_version``) with each worker's and
refuses a mismatch, naming the worker.  The same call imports the heavy
modules on every worker (what the local pool's forkserver preloads), while
the client reads the raw files meanwhile.
"""

from __future__ import annotations

import importlib
import threading

from pipeline.errors import PdrError

CONNECT_TIMEOUT_S = 10.0
WORKER_WAIT_S = 30.0


def connect(address: str, timeout: float | None = None):
    """A ``distributed.Client`` on ``address`` with at least one worker; a one-line error otherwise."""
    from distributed import Client

    from pipeline.cluster.probe import check_scheduler

    check_scheduler(address, timeout or CONNECT_TIMEOUT_S)     # never hand the client a non-scheduler
    try:
        client = Client(address, timeout=timeout or CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError, TypeError) as err:
        raise PdrError(f"cannot reach a dask scheduler there (expected tcp://HOST:PORT of a running "
                       f"`dask scheduler`): {err}", path=address) from None
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
    except TimeoutError:
        client.close()
        raise PdrError(f"the dask scheduler has no worker after {WORKER_WAIT_S:.0f} s "
                       "(start some with `dask worker ADDRESS`)", path=address) from None
    return client


def prepare_worker() -> str:
    """Runs on each worker: import what every recording needs, return the worker's code version."""
    from pipeline.cluster.runner import PRELOAD, code_version

    for module in PRELOAD:
        importlib.import_module(module)
    return code_version()


class WorkerCheck:
    """``prepare_worker`` on every worker, in a thread: ``result()`` raises if a worker runs other code."""

    def __init__(self, client, expected: str) -> None:
        self._client, self._expected = client, expected
        self._versions: dict[str, str] = {}
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._versions = self._client.run(prepare_worker)
        except BaseException as err:  # handed to result(), in the caller's thread
            self._error = err

    def result(self) -> dict[str, str]:
        self._thread.join()
        if self._error is not None:
            raise PdrError(f"preparing the cluster's workers failed: {type(self._error).__name__}: {self._error}")
        other = {w: v for w, v in self._versions.items() if v != self._expected}
        if other:
            worker, version = sorted(other.items())[0]
            raise PdrError(f"worker runs pdr code version {version}, this client {self._expected}: "
                           "install the same pdr on every worker", path=worker)
        return self._versions
