"""``pdr run --cluster`` against a ``distributed.LocalCluster`` with worker processes: the outputs are
those of a local run, failures are reported as locally, and a cluster that cannot be used is refused
in one line."""

import shutil

import pytest

from pipeline.cluster import connect as connect_module
from pipeline.cluster.connect import WorkerCheck
from pipeline.errors import PdrError
from pipeline.run import run_pipeline
from tests.cluster.helpers import CODE, differences, make_raw

pytestmark = pytest.mark.cluster


@pytest.fixture(scope="module")
def cluster():
    """Two worker processes on localhost.  A connection to a worker that has died waits dask's connect
    timeout (30 s by default) before the task is given up on; on localhost a live peer answers at once,
    so 5 s here (the scheduler and client in this process, the workers through their environment)."""
    import dask
    from distributed import LocalCluster

    with pytest.MonkeyPatch.context() as mp, dask.config.set({"distributed.comm.timeouts.connect": "5s"}):
        mp.setenv("DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT", "5s")
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None) as lc:
            yield lc


def test_cluster_run_writes_what_a_local_run_writes(cluster, tmp_path, capsys):
    raw = tmp_path / "raw"
    make_raw(raw, 3)
    (raw / "garbage.csv").write_text("this is not\na capture\n")
    (raw / "badkey.csv").write_bytes((raw / "r000.csv").read_bytes())
    (raw / "badkey.toml").write_text("[model]\nnot_a_parameter = 1\n")
    local = run_pipeline(raw, tmp_path / "local", jobs=2, code=CODE)
    capsys.readouterr()
    remote = run_pipeline(raw, tmp_path / "cluster", code=CODE, cluster=cluster.scheduler_address, show_progress=True)
    progress = capsys.readouterr().out
    assert "5/5" in progress and "workers busy" in progress and "of 2" in progress   # done of total, workers

    assert [(r["recording"], r["status"], r["error"]) for r in remote.ran] == \
           [(r["recording"], r["status"], r["error"]) for r in local.ran]
    assert {r["recording"] for r in remote.failed} == {"garbage.csv", "badkey.csv"}
    assert differences(tmp_path / "local", tmp_path / "cluster") == []
    assert any("2 worker(s) took part" in note for note in remote.notes)
    assert not any("re-run" in note or "lost" in note for note in remote.notes)

    # The second time nothing changed: nothing goes to the cluster.
    again = run_pipeline(raw, tmp_path / "cluster", code=CODE, cluster=cluster.scheduler_address)
    assert sorted(again.skipped) == [f"r{i:03d}.csv" for i in range(3)]
    assert {r["recording"] for r in again.ran} == {"garbage.csv", "badkey.csv"}

    # A recording whose raw file changed: its old stamp is replaced, a removed one's runs pruned.
    shutil.copy(raw / "r002.csv", raw / "r001.csv")
    (raw / "r000.csv").unlink()
    third = run_pipeline(raw, tmp_path / "cluster", code=CODE, cluster=cluster.scheduler_address)
    assert [r["recording"] for r in third.ran if r["status"] == "ok"] == ["r001.csv"]
    assert third.removed == ["r000"]


def test_workers_running_other_code_are_refused_naming_one(cluster):
    from distributed import Client

    with Client(cluster.scheduler_address, set_as_default=False) as client:
        with pytest.raises(PdrError, match="install the same pdr on every worker") as err:
            WorkerCheck(client, "not-this-code").result()
    assert str(err.value).startswith("tcp://127.0.0.1:")


def test_an_unreachable_scheduler_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setattr(connect_module, "CONNECT_TIMEOUT_S", 1.0)
    raw = tmp_path / "raw"
    make_raw(raw, 1)
    with pytest.raises(PdrError, match="cannot reach a dask scheduler") as err:
        run_pipeline(raw, tmp_path / "processed", code=CODE, cluster="tcp://127.0.0.1:9")
    assert "\n" not in str(err.value) and str(err.value).startswith("tcp://127.0.0.1:9: ")


def test_discover_many_on_the_cluster_writes_what_it_writes_locally(cluster, tmp_path):
    from pipeline.discover.many import discover_many
    from tests.discover.test_many import make_b_rig

    csvs = make_b_rig(tmp_path / "raw", 1)
    local = discover_many(csvs, tmp_path / "local", jobs=1, rrd=False)
    remote = discover_many(csvs, tmp_path / "cluster", cluster=cluster.scheduler_address, rrd=False)
    assert not local.failed and not remote.failed
    assert differences(tmp_path / "local", tmp_path / "cluster") == []
    assert list(remote.table["verdict"]) == ["explained"]


def test_a_recording_that_kills_every_worker_fails_alone(cluster, tmp_path):
    """Last in this module: its workers die twice (the nannies start new ones).  The chunk function
    stands in for the real work, which the other tests check."""
    from pipeline.cluster.execute import execute_on_cluster
    from pipeline.run import stamp_for
    from tests.cluster.poison import crash_on_poison

    raw = tmp_path / "raw"
    raw.mkdir()
    for name in ["poison"] + [f"r{i:03d}" for i in range(15)]:   # poison first: it shares a chunk with r000
        (raw / f"{name}.csv").write_text("t_ms,counts,adc,dir\n")
    todo = [(csv, stamp_for(csv, CODE)) for csv in sorted(raw.glob("*.csv"))]
    scheduler = cluster.scheduler
    # Give up on a task after one death, and give each worker one task at a time: otherwise a task
    # merely queued on a dying worker counts that death too, and would fail with allowed-failures 0.
    saved = scheduler.allowed_failures, scheduler.WORKER_SATURATION
    scheduler.allowed_failures, scheduler.WORKER_SATURATION = 0, 1.0
    try:
        results, stats = execute_on_cluster(todo, tmp_path / "processed", cluster.scheduler_address, False,
                                            work=crash_on_poison)
    finally:
        scheduler.allowed_failures, scheduler.WORKER_SATURATION = saved
    status = {r["recording"]: r["status"] for r in results}
    assert status.pop("poison.csv") == "failed" and set(status.values()) == {"ok"} and len(status) == 15
    poison = next(r for r in results if r["recording"] == "poison.csv")
    assert poison["error"].startswith("cluster: every worker that took it died")
    assert {"poison.csv", "r000.csv"} <= set(stats.rerun)
    assert not (tmp_path / "processed" / "poison").exists()
