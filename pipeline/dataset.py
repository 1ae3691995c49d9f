"""All runs as one Hive-partitioned Parquet dataset per table, without copying: ``processed/dataset/``.

``processed/dataset/<table>/run=<run>/part-0.parquet`` is a relative symbolic
link to ``processed/<run>/<table>.parquet`` for each of the run's tables
(signals, kinematics, phases, overshoot, cycles, comparison), so
``pyarrow.dataset``, DuckDB and Polars read every run at once with ``run`` as
the partition column, and the bytes exist once.  A link follows the file it
names through every atomic replacement, so it is never stale; the view is
refreshed at the end of ``pdr run`` only to add new runs and drop removed ones.

``dataset/runs/run=<run>/part-0.parquet`` is the one real file: a row per
run (recording, raw file sha256, ``recorded`` = the raw file's modification
time, UTC), for questions by date.  A run's tables may differ in optional
columns (a recording without ``dir``, current or encoder): read with
``union_by_name`` (DuckDB) or a unified schema.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from pipeline.runs import DATASET_DIR  # one source: runs.py reserves the name for pdr
TABLES = ("signals", "kinematics", "phases", "overshoot", "cycles", "comparison")
RUNS_TABLE = "runs"
PART = "part-0.parquet"


def complete_runs(processed: Path) -> list[str]:
    """Runs whose every stage finished (their stamp written last)."""
    return sorted(p.name for p in processed.iterdir()
                  if p.is_dir() and not p.name.startswith(".") and (p / "stamp.json").is_file())


def _link(link: Path, target: str) -> None:
    """``link`` -> ``target``, replaced atomically when it points elsewhere."""
    try:
        if os.readlink(link) == target:
            return
    except OSError:
        pass
    link.parent.mkdir(parents=True, exist_ok=True)
    tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    os.symlink(target, tmp)
    os.replace(tmp, link)


def _runs_row(run_dir: Path):
    """The ``runs`` table's row for one run, from its stamp; None when the raw file is not readable here."""
    stamp = json.loads((run_dir / "stamp.json").read_text(encoding="utf-8"))
    return _row(Path(stamp["raw_dir"]) / stamp["recording"], stamp["raw_sha256"])


def _row(raw: Path, raw_sha256: str):
    """The ``runs`` table's row of a recording's runs; None when the raw file is not readable here."""
    import pyarrow as pa

    try:
        mtime_ms = int(raw.stat().st_mtime * 1000)
    except OSError:
        return None
    return pa.table({"recording": [raw.name], "raw_sha256": [raw_sha256],
                     "recorded": pa.array([mtime_ms], pa.timestamp("ms", tz="UTC"))})


def _write_if_changed(target: Path, table) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.io.atomic import write_bytes

    sink = pa.BufferOutputStream()
    pq.write_table(table, sink)
    data = sink.getvalue().to_pybytes()
    if not (target.is_file() and target.read_bytes() == data):
        write_bytes(target, data)


def _table_links(processed: Path, run: str) -> None:
    root = processed / DATASET_DIR
    for table in TABLES:
        if (processed / run / f"{table}.parquet").is_file():
            _link(root / table / f"run={run}" / PART, f"../../../{run}/{table}.parquet")


def add_runs(processed: Path, runs: list[str], raw: Path, raw_sha256: str) -> None:
    """The entries of runs just made from the raw file ``raw``: their tables' links and ``runs`` rows.

    ``pdr run``'s workers call this as each recording is done, before its
    stamps, so the file-system work is spread over the run instead of
    left to its end; ``refresh_dataset`` then finds them in place (it still
    removes the entries of runs that end up without a stamp).
    """
    processed = Path(processed)
    row = _row(Path(raw), raw_sha256)
    for run in runs:
        _table_links(processed, run)
        if row is not None:
            _write_if_changed(processed / DATASET_DIR / RUNS_TABLE / f"run={run}" / PART, row)


def refresh_dataset(processed: Path, changed: set[str] | None = None) -> list[str]:
    """Bring ``processed/dataset/`` in line with the complete runs; returns them.

    ``changed``: the runs just made, whose ``runs`` row is rewritten; others get one only when missing
    (None: every row is checked).
    """
    processed = Path(processed)
    root = processed / DATASET_DIR
    runs = complete_runs(processed)
    for run in runs:
        _table_links(processed, run)
    for run in runs:
        target = root / RUNS_TABLE / f"run={run}" / PART
        if changed is not None and run not in changed and target.is_file():
            continue
        row = _runs_row(processed / run)
        if row is not None:
            _write_if_changed(target, row)
    keep = {f"run={run}" for run in runs}
    for table in (*TABLES, RUNS_TABLE):
        folder = root / table
        if folder.is_dir():
            for part in folder.iterdir():
                if part.name.startswith("run=") and part.name not in keep:
                    shutil.rmtree(part, ignore_errors=True)
    return runs
