"""``pdr run``'s pool under ``spawn``, the start method of platforms without a forkserver (Windows):
the same outputs as one process doing every recording."""

import pytest

from pipeline.run import run_pipeline
from pipeline.run.pool import start_method
from tests.hostile.conftest import workspace  # noqa: F401  (the fixture)
from tests.hostile.folders import CODE, good_csv


def test_forkserver_where_the_platform_has_it():
    import multiprocessing
    assert start_method() == ("forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn")


@pytest.mark.long
@pytest.mark.slow
def test_the_pool_under_spawn_gives_the_single_process_outputs(workspace):
    for seed in (0, 1):
        workspace.alone(seed)           # each recording processed alone, in this process
    raw = workspace.fresh_raw()
    for seed in (0, 1):
        (raw / f"good{seed}.csv").write_bytes(good_csv(seed))
    processed = workspace.processed()
    spawned = run_pipeline(raw, processed, jobs=2, code=CODE, method="spawn")
    assert [r["status"] for r in spawned.ran] == ["ok", "ok"], spawned.ran
    assert spawned.pool_ready_s is not None         # the pool was used, not the in-process path
    for seed in (0, 1):
        workspace.assert_as_alone(processed, seed)


def _worker_state() -> tuple:
    import gc
    import sys
    return gc.isenabled(), gc.get_threshold(), "pipeline.validate.warmup" in sys.modules, gc.get_freeze_count()


@pytest.mark.skipif(start_method() != "forkserver", reason="the preload is the forkserver's")
def test_a_worker_starts_preloaded_with_its_garbage_collector_on():
    """The forkserver imports everything with the collector paused (``pipeline.run.preload``); a worker
    must not inherit it paused, and collects young objects at its own threshold."""
    from pipeline.run.pool import WORKER_GC_THRESHOLD, make_pool

    with make_pool(1) as pool:
        enabled, threshold, warmed, frozen = pool.submit(_worker_state).result()
    assert enabled and threshold == WORKER_GC_THRESHOLD and warmed and frozen > 100_000
