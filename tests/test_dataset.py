"""processed/ as one Hive-partitioned dataset per table: read by pyarrow.dataset, DuckDB and Polars
without a copy, the partitions following the runs as they come and go."""

import json
import os
from pathlib import Path

import duckdb
import polars as pl
import pyarrow.dataset as ds
import pytest

from pipeline.dataset import DATASET_DIR, PART, TABLES
from pipeline.run import run_pipeline
from tests.cluster.helpers import CODE, make_raw

WEEK = 7 * 86400
T0 = 1_700_000_000       # Tuesday 2023-11-14


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    raw = tmp_path_factory.mktemp("raw")
    make_raw(raw, 3)
    for i, csv in enumerate(sorted(raw.glob("*.csv"))):
        os.utime(csv, (T0 + i * WEEK, T0 + i * WEEK))          # one recording a week
    out = tmp_path_factory.mktemp("processed")
    report = run_pipeline(raw, out, jobs=1, code=CODE)
    assert not report.failed
    return out


def _replay_theta_mse(processed: Path, run: str) -> float:
    return json.loads((processed / run / "validation.json").read_text())["replay"]["signals"]["theta"]["mse"]


def test_every_table_is_a_partition_per_run_linked_not_copied(processed):
    for table in TABLES:
        for run in ("r000", "r001", "r002"):
            part = processed / DATASET_DIR / table / f"run={run}" / PART
            assert part.is_symlink() and not os.readlink(part).startswith("/")     # relative: the folder can move
            assert part.samefile(processed / run / f"{table}.parquet")


def test_pyarrow_duckdb_and_polars_read_all_runs(processed):
    root = processed / DATASET_DIR
    table = ds.dataset(root / "comparison", format="parquet", partitioning="hive").to_table()
    assert sorted(table.column("run").unique().to_pylist()) == ["r000", "r001", "r002"]

    rows = duckdb.sql(f"""
        SELECT c.run, date_trunc('week', r.recorded)::DATE AS week,
               avg((c.theta_replay_rad - c.theta_rad) ^ 2) AS replay_theta_mse
        FROM read_parquet('{root}/comparison/*/*.parquet', hive_partitioning = true) c
        JOIN read_parquet('{root}/runs/*/*.parquet', hive_partitioning = true) r USING (run)
        GROUP BY ALL ORDER BY run""").fetchall()
    assert [r[0] for r in rows] == ["r000", "r001", "r002"]
    weeks = [r[1] for r in rows]
    assert (weeks[1] - weeks[0]).days == 7 and (weeks[2] - weeks[1]).days == 7
    for run, _week, mse in rows:                       # the validation stage's own figure
        assert mse == pytest.approx(_replay_theta_mse(processed, run), rel=1e-9)

    lazy = pl.scan_parquet(f"{root}/kinematics/**/*.parquet", hive_partitioning=True)
    counts = lazy.group_by("run").agg(pl.len()).sort("run").collect()
    assert counts["run"].to_list() == ["r000", "r001", "r002"]
    assert counts["len"].to_list() == [ds.dataset(processed / r / "kinematics.parquet").count_rows()
                                      for r in ("r000", "r001", "r002")]


def test_a_removed_recording_leaves_the_dataset(processed, tmp_path):
    import shutil

    raw = tmp_path / "raw"
    make_raw(raw, 2)
    out = tmp_path / "processed"
    run_pipeline(raw, out, jobs=1, code=CODE)
    first = (out / DATASET_DIR / "runs" / "run=r000" / PART).read_bytes()
    (raw / "r001.csv").unlink()
    run_pipeline(raw, out, jobs=1, code=CODE)
    assert sorted(p.name for p in (out / DATASET_DIR / "comparison").iterdir()) == ["run=r000"]
    assert sorted(p.name for p in (out / DATASET_DIR / "runs").iterdir()) == ["run=r000"]
    assert (out / DATASET_DIR / "runs" / "run=r000" / PART).read_bytes() == first
    shutil.rmtree(out / DATASET_DIR)                  # a lost view comes back on the next run
    run_pipeline(raw, out, jobs=1, code=CODE)
    assert (out / DATASET_DIR / "runs" / "run=r000" / PART).read_bytes() == first


def test_the_entries_the_workers_add_are_the_ones_a_refresh_makes(processed, tmp_path):
    import shutil

    from pipeline.dataset import refresh_dataset

    copy = tmp_path / "processed"
    shutil.copytree(processed, copy, symlinks=True)
    shutil.rmtree(copy / DATASET_DIR)
    refresh_dataset(copy)                              # every entry from the stamps, none from a worker
    made = sorted(p.relative_to(copy / DATASET_DIR) for p in (copy / DATASET_DIR).rglob("*.parquet"))
    assert made == sorted(p.relative_to(processed / DATASET_DIR) for p in (processed / DATASET_DIR).rglob("*.parquet"))
    assert len(made) == 3 * (len(TABLES) + 1)
    for rel in made:
        a, b = processed / DATASET_DIR / rel, copy / DATASET_DIR / rel
        assert a.is_symlink() == b.is_symlink() and a.read_bytes() == b.read_bytes()
        if a.is_symlink():
            assert os.readlink(a) == os.readlink(b)


def test_a_recording_that_fails_after_its_entries_were_added_leaves_the_dataset(tmp_path, monkeypatch):
    from pipeline.validate import rerun_log

    raw = tmp_path / "raw"
    make_raw(raw, 2)
    monkeypatch.setattr(rerun_log, "verify_rrds",      # r001's recording fails its check, after the stages ran
                        lambda paths: {p: "rerun rrd verify failed: test" for p in paths if p.parent.name == "r001"})
    out = tmp_path / "processed"
    report = run_pipeline(raw, out, jobs=1, code=CODE)
    assert [r["recording"] for r in report.failed] == ["r001.csv"]
    assert [r.get("in_dataset") for r in report.ran] == [True, True]      # both were added, then r001 failed
    for table in (*TABLES, "runs"):
        assert sorted(p.name for p in (out / DATASET_DIR / table).iterdir()) == ["run=r000"]
