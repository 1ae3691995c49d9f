"""The command's shell under hostile use: folders nested in each other, closed output streams, signals,
a ``--cluster`` that is not a dask scheduler, and the network."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from pipeline.errors import PdrError
from pipeline.run import run_pipeline
from tests.hostile.folders import CODE, PDR, good_csv, no_traceback, snapshot
from tests.hostile.test_faults import SEEDS, _descendants, _raw_with_goods, _wait_gone


@pytest.mark.parametrize("inside", [".", "out", "a/b", "./out/../out2"])
def test_an_output_folder_in_the_raw_folder_is_refused_and_nothing_is_written(tmp_path, inside):
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "good0.csv").write_bytes(good_csv(0))
    before = snapshot(raw)
    with pytest.raises(PdrError, match="the output folder (is the raw folder|is inside the raw folder)") as err:
        run_pipeline(raw, raw / inside, jobs=1, code=CODE)
    assert "\n" not in str(err.value) and "--processed" in str(err.value)
    assert snapshot(raw) == before


def test_a_raw_folder_in_the_output_folder_is_refused(tmp_path):
    processed = tmp_path / "processed"
    raw = processed / "raw"
    raw.mkdir(parents=True)
    (raw / "good0.csv").write_bytes(good_csv(0))
    (tmp_path / "link").symlink_to(raw)             # the same folder through a link is seen through
    for given in (raw, tmp_path / "link"):
        with pytest.raises(PdrError, match="the raw folder is inside the output folder"):
            run_pipeline(given, processed, jobs=1, code=CODE)
    assert sorted(p.name for p in processed.iterdir()) == ["raw"]


def _stamped_runs(processed: Path) -> list[str]:
    return sorted(p.parent.name for p in processed.glob("*/stamp.json"))


def _no_torn_or_temporary_file(processed: Path) -> None:
    assert not [p for p in processed.rglob("*") if p.name.endswith(".tmp")], "a temporary was left"
    for path in processed.rglob("*"):
        if path.suffix == ".parquet":
            pq.read_table(path)
        elif path.suffix == ".json":
            json.loads(path.read_text())


@pytest.mark.slow
@pytest.mark.parametrize("sig, to_group, delay_s", [
    (signal.SIGINT, True, 1.5),                   # Ctrl-C in a terminal: the whole foreground group
    (signal.SIGINT, True, None),                  # ... at a random point of the run
    (signal.SIGINT, False, None),                 # kill -INT of pdr alone
    (signal.SIGTERM, False, None),                # a service manager or `timeout`
    (signal.SIGTERM, True, None),
])
def test_a_stop_during_run_j2_is_one_line_and_keeps_every_finished_run_whole(workspace, sig, to_group, delay_s):
    raw = _raw_with_goods(workspace)
    processed = workspace.processed()
    delay_s = delay_s if delay_s is not None else random.Random().uniform(1.0, 6.0)
    proc = subprocess.Popen([PDR, "run", "--raw", str(raw), "--processed", str(processed), "-j", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    time.sleep(delay_s)
    family = _descendants(proc.pid)
    (os.killpg if to_group else os.kill)(proc.pid, sig)
    out, err = proc.communicate(timeout=60)          # EOF once every holder of the pipes (workers too) is gone
    status, words = {signal.SIGINT: (130, "interrupted"), signal.SIGTERM: (143, "terminated (SIGTERM)")}[sig]
    finished = _stamped_runs(processed)
    if proc.returncode == 0:            # the run was over before the signal came: everything is there
        assert finished == [f"good{s}" for s in SEEDS], (delay_s, err)
    else:
        assert proc.returncode == status, (delay_s, proc.returncode, err)
        assert err.splitlines() == [f"pdr: {words}: the recordings finished so far are kept; pdr run again "
                                    "does the rest"], (delay_s, err)
    no_traceback(out, err)
    assert "leaked" not in err and "resource_tracker" not in err, err
    assert not _wait_gone(family, within_s=10), f"processes left {delay_s:.2f} s into the run"
    _no_torn_or_temporary_file(processed)
    for run in finished:
        workspace.assert_as_alone(processed, int(run.removeprefix("good")))
    if delay_s == 1.5:                  # too early for any recording to be finished: the stop was not ignored
        assert proc.returncode == status and finished == [], (proc.returncode, finished)


@pytest.mark.slow
@pytest.mark.parametrize("closed", ["2>&-", ">&-", "<&- 2>&-"])
def test_a_run_with_a_closed_output_stream_processes_everything_and_says_so_by_its_status(workspace, closed):
    raw = _raw_with_goods(workspace)
    processed = workspace.processed()
    keep = "err" if closed == ">&-" else "out"
    proc = subprocess.run(["sh", "-c", f'exec "$0" run --raw "$1" --processed "$2" -j 2 {closed}',
                           PDR, str(raw), str(processed)], capture_output=True, text=True, timeout=180)
    no_traceback(proc.stdout, proc.stderr)
    assert proc.returncode == 0, getattr(proc, f"std{keep}")
    for seed in SEEDS:
        workspace.assert_as_alone(processed, seed)
    assert (processed / ".pdr.lock").stat().st_size == 0, "something wrote into the lock file (fd 2 reused)"
    if closed == ">&-":
        assert "pdr run: 2 recording(s) processed" in proc.stderr
