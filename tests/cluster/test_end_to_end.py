"""End to end on a real cluster of separate processes: ``dask scheduler`` and two ``dask worker`` on
127.0.0.1 from this environment, ``pdr run --cluster`` on 16 virtual-rig recordings, one worker killed
during the run; the outputs must be those of a local run.  16 recordings go in ten tasks (of two, then
of one): when the first four are written back, both workers still hold tasks, so the one killed loses some."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.run import code_version, run_pipeline
from tests.cluster.helpers import differences, make_raw

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

BIN = Path(sys.executable).parent
RECORDINGS = 16


def _wait(predicate, timeout: float, what: str):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def dask_cluster(tmp_path):
    """A scheduler and two single-threaded workers without nannies (a killed worker stays dead)."""
    sched_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", str(sched_file)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        _wait(sched_file.is_file, 60, "the scheduler file")
        workers = [subprocess.Popen([str(BIN / "dask"), "worker", "--scheduler-file", str(sched_file),
                                     "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny", "--no-dashboard",
                                     "--preload", "pipeline.cluster.preload"],     # imports while the local run runs
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for _ in range(2)]
        procs += workers
        address = json.loads(sched_file.read_text())["address"]
        yield address, workers
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=3)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.mark.long
def test_pdr_run_on_a_cluster_with_a_worker_killed_matches_a_local_run(dask_cluster, tmp_path):
    from distributed import Client

    address, workers = dask_cluster
    raw = tmp_path / "raw"
    make_raw(raw, RECORDINGS)
    code = code_version()
    local = run_pipeline(raw, tmp_path / "local", jobs=2, code=code)
    assert not local.failed

    with Client(address, set_as_default=False) as client:
        client.wait_for_workers(2, timeout=60)
        by_pid = {pid: addr for addr, pid in client.run(os.getpid).items()}
    victim = workers[0]
    processed = tmp_path / "cluster"
    env = dict(os.environ, PDR_CLUSTER=address)      # the environment form of --cluster
    run = subprocess.Popen([str(BIN / "pdr"), "run", "--raw", str(raw), "--processed", str(processed)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        # Kill one worker once a few recordings are written back: it holds a chunk then.
        _wait(lambda: len(list(processed.glob("*/stamp.json"))) >= 4 or run.poll() is not None, 120,
              "the first recordings")
        assert run.poll() is None, run.communicate()[0]
        victim.send_signal(signal.SIGKILL)
        output, _ = run.communicate(timeout=300)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, output
    assert f"{RECORDINGS} recording(s) processed" in output
    assert f"workers lost during the run: {by_pid[victim.pid]}" in output
    assert "re-run on another worker after a worker died holding them" in output
    assert code_version() == code, "the source tree changed during the test"
    diff = differences(tmp_path / "local", processed)
    assert diff == [], diff
    assert not list(processed.rglob(".*.tmp"))
