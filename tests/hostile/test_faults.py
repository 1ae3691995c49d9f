"""Faults during ``pdr run``: ``kill -9`` of the main process or of a worker, a full disk, another command
on the same folder.  No torn file, no process left behind, and the next run recovers byte for byte."""

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

from pipeline.run import run_pipeline
from tests.hostile.folders import CODE, PDR, good_csv, no_traceback

SEEDS = (0, 1)


def _children() -> dict[int, list[int]]:
    """Parent pid -> child pids, from /proc (the tests run on Linux; the product does not read /proc)."""
    tree: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            tree.setdefault(ppid, []).append(int(entry))
    return tree


def _descendants(pid: int) -> set[int]:
    tree, found, todo = _children(), set(), [pid]
    while todo:
        for child in tree.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.add(pid)
    return alive


def _wait_gone(pids: set[int], within_s: float) -> set[int]:
    deadline = time.monotonic() + within_s
    while _alive(pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    return _alive(pids)


def _no_torn_file(processed: Path) -> None:
    """Every output present is complete: Parquet and JSON read back, no temporary passes for an output."""
    for path in processed.rglob("*"):
        if path.suffix == ".parquet":
            pq.read_table(path)
        elif path.suffix == ".json":
            json.loads(path.read_text())


def _start(raw: Path, processed: Path, jobs: int = 2) -> subprocess.Popen:
    return subprocess.Popen([PDR, "run", "--raw", str(raw), "--processed", str(processed), "-j", str(jobs)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _raw_with_goods(workspace) -> Path:
    for seed in SEEDS:
        workspace.alone(seed)
    raw = workspace.fresh_raw()
    for seed in SEEDS:
        (raw / f"good{seed}.csv").write_bytes(good_csv(seed))
    return raw


def _recovers(workspace, raw: Path, processed: Path) -> None:
    _no_torn_file(processed)
    report = run_pipeline(raw, processed, jobs=1, code=CODE)
    assert not report.failed, report.failed
    for seed in SEEDS:
        workspace.assert_as_alone(processed, seed)
    assert not list(processed.rglob(".*.tmp"))


@pytest.mark.long
@pytest.mark.slow
def test_kill_9_of_the_main_process_leaves_no_process_and_the_next_run_recovers(workspace):
    raw = _raw_with_goods(workspace)
    processed = workspace.processed()
    for delay in (random.Random().uniform(0.5, 4.0),):      # a different point of the run each time
        proc = _start(raw, processed)
        time.sleep(delay)
        family = _descendants(proc.pid)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        left = _wait_gone(family, within_s=15)
        assert not left, f"still running {delay:.2f} s into the run + 15 s after the kill: {sorted(left)}"
        _no_torn_file(processed)
    _recovers(workspace, raw, processed)


@pytest.mark.slow
def test_kill_9_of_a_worker_fails_or_retries_that_recording_only(workspace):
    raw = _raw_with_goods(workspace)
    processed = workspace.processed()
    proc = _start(raw, processed)
    deadline = time.monotonic() + 60
    victim = None
    while victim is None and time.monotonic() < deadline and proc.poll() is None:
        # a pool worker: a child of the forkserver (it shares the forkserver's command line)
        tree = _children()
        for pid in tree.get(proc.pid, []):
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue
            if b"forkserver" in cmd and tree.get(pid):
                victim = tree[pid][0]
                break
        time.sleep(0.05)
    assert victim is not None, "no worker process seen"
    os.kill(victim, signal.SIGKILL)
    out, err = proc.communicate(timeout=180)
    no_traceback(out.decode(errors="replace"), err.decode(errors="replace"))
    assert proc.returncode in (0, 1)
    if proc.returncode == 0:        # the recordings the worker held were retried, each in a fresh worker
        _no_torn_file(processed)
        for seed in SEEDS:
            workspace.assert_as_alone(processed, seed)
    else:
        _recovers(workspace, raw, processed)


@pytest.mark.slow
@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a small tmpfs needs root")
def test_a_full_disk_is_named_and_leaves_nothing_half_written(workspace, tmp_path):
    raw = _raw_with_goods(workspace)
    processed = tmp_path / "small"
    processed.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=600k", "tmpfs", str(processed)], check=True)
    try:
        report = run_pipeline(raw, processed, jobs=1, code=CODE)
        assert report.failed, "600 KiB should not hold two recordings' outputs"
        for r in report.failed:         # what `pdr run` prints after FAILED <recording>:
            no_traceback(r["error"])
            assert "no space left on the device" in r["error"] and "\n" not in r["error"], r["error"]
        assert not list(processed.rglob(".*.tmp"))
        _no_torn_file(processed)
        for stamp in processed.glob("*/stamp.json"):      # a stamp only beside complete outputs
            assert (stamp.parent / "validation.json").is_file()
    finally:
        _unmount(processed)


def _unmount(mount: Path) -> None:
    """Unmount the test's tmpfs; under a loaded suite a closing file can keep it busy for a moment, so
    a few tries over 5 s, then the holders are named in the failure and the mount is detached lazily
    (never left behind for the next run's temporary folders)."""
    for _ in range(25):
        if subprocess.run(["umount", str(mount)], capture_output=True).returncode == 0:
            return
        time.sleep(0.2)
    holders = subprocess.run(["fuser", "-vm", str(mount)], capture_output=True, text=True)
    subprocess.run(["umount", "-l", str(mount)], check=True)
    raise AssertionError(f"the tmpfs stayed busy after the run: {holders.stdout}{holders.stderr}")


@pytest.mark.slow
def test_ingest_while_a_run_holds_the_lock_waits_then_both_finish(workspace, tmp_path):
    from filelock import FileLock, Timeout

    raw = _raw_with_goods(workspace)
    processed = workspace.processed()
    proc = _start(raw, processed, jobs=1)
    lock = FileLock(processed / ".pdr.lock")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:          # until the run holds the lock
        try:
            lock.acquire(timeout=0)
            lock.release()
            time.sleep(0.02)
        except Timeout:
            break
    (tmp_path / "extra.csv").write_bytes(good_csv(2))
    ingest = subprocess.run([PDR, "ingest", str(tmp_path / "extra.csv"), "-q", "--processed", str(processed)],
                            capture_output=True, text=True, timeout=180)
    out, err = proc.communicate(timeout=180)
    assert proc.returncode == 0, err
    assert ingest.returncode == 0 and ingest.stderr.startswith("pdr: waiting for another pdr process"), ingest.stderr
    assert (processed / "extra" / "signals.parquet").is_file()
    for seed in SEEDS:
        workspace.assert_as_alone(processed, seed)
