"""``pdr run``'s pool under ``spawn``, the start method of platforms without a forkserver (Windows):
the same outputs as one process doing every recording."""

import pytest

from pipeline.run import run_pipeline
from pipeline.run.runner import start_method
from tests.hostile.conftest import workspace  # noqa: F401  (the fixture)
from tests.hostile.folders import CODE, good_csv


def test_forkserver_where_the_platform_has_it():
    import multiprocessing
    assert start_method() == ("forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn")


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
