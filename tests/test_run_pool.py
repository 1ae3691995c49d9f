"""``pdr run``'s pool under ``spawn``, the start method of platforms without a forkserver (Windows):
the same outputs as one process doing every recording."""

import pytest

from pipeline.run import run_pipeline
from pipeline.run.runner import start_method
from tests.hostile.folders import CODE, good_csv, run_outputs


def test_forkserver_where_the_platform_has_it():
    import multiprocessing
    assert start_method() == ("forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn")


@pytest.mark.slow
def test_the_pool_under_spawn_gives_the_single_process_outputs(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    for seed in (0, 1):
        (raw / f"good{seed}.csv").write_bytes(good_csv(seed))
    single = run_pipeline(raw, tmp_path / "single", jobs=1, code=CODE)
    spawned = run_pipeline(raw, tmp_path / "spawned", jobs=2, code=CODE, method="spawn")
    assert [r["status"] for r in single.ran] == [r["status"] for r in spawned.ran] == ["ok", "ok"]
    assert spawned.pool_ready_s is not None         # the pool was used, not the in-process path
    for seed in (0, 1):
        assert run_outputs(tmp_path / "spawned", f"good{seed}") == run_outputs(tmp_path / "single", f"good{seed}")
