"""The command's shell under hostile use: folders nested in each other, closed output streams, signals,
and the network (``--cluster`` at what is not a scheduler: tests/cluster/test_probe.py)."""

from __future__ import annotations

import ipaddress
import json
import os
import random
import re
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
@pytest.mark.long
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


@pytest.mark.long
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


_PENDING_EVENT = '{"time_utc":"2026-01-01T00:00:00Z","kind":"Append","name":"viewer_started","props":{}}\n'
_REMOTE = re.compile(r"(connect|sendto|sendmsg)\(.*sa_family=AF_INET6?, sin6?_port=htons\((\d+)\), "
                     r"(?:inet_pton\(AF_INET6, |sin6_flowinfo=.*?inet_pton\(AF_INET6, |sin_addr=inet_addr\()\"([^\"]+)\"")


def _home_with_rerun_analytics_on(home: Path) -> Path:
    """A user's home as the Rerun viewer leaves it: analytics enabled (not a first run) and one event of an
    earlier session pending, which any rerun process with analytics on sends to tel.rerun.io."""
    (home / ".config" / "rerun").mkdir(parents=True)
    data = home / ".local" / "share" / "rerun" / "analytics"
    data.mkdir(parents=True)
    (home / ".config" / "rerun" / "analytics.json").write_text(json.dumps({
        "analytics_enabled": True, "analytics_id": "0" * 32, "metadata": {},
        "config_file_path": str(home / ".config" / "rerun" / "analytics.json"), "data_dir_path": str(data)}))
    (data / "00000000-0000-4000-8000-000000000000.json").write_text(_PENDING_EVENT)
    return data


@pytest.mark.long
@pytest.mark.slow
def test_a_run_opens_no_socket_beyond_loopback_and_leaves_rerun_analytics_alone(workspace, tmp_path):
    """Every process of the run (pdr, the forkserver, the workers, the rerun CLI they start) traced by
    strace: a connection or datagram to an address other than loopback, or a DNS lookup, fails the test."""
    raw = _raw_with_goods(workspace)
    processed = workspace.processed()
    home = tmp_path / "home"
    pending = _home_with_rerun_analytics_on(home)
    before = sorted(p.name for p in pending.iterdir())
    trace = tmp_path / "network.trace"
    env = {k: v for k, v in os.environ.items() if k not in ("CI", "XDG_CONFIG_HOME", "XDG_DATA_HOME")}
    proc = subprocess.run(["strace", "-f", "--seccomp-bpf", "-e", "trace=connect,sendto,sendmsg", "-o", str(trace),
                           PDR, "run", "--raw", str(raw), "--processed", str(processed), "-j", "2"],
                          capture_output=True, text=True, timeout=300, env={**env, "HOME": str(home)})
    assert proc.returncode == 0, proc.stderr
    calls = trace.read_text().splitlines()
    assert any("connect(" in c or "sendmsg(" in c for c in calls), "strace saw nothing: the trace is not working"
    remote = [(m[1], m[2], m[3]) for m in map(_REMOTE.search, calls) if m
              and (m[2] == "53" or not ipaddress.ip_address(m[3]).is_loopback)]
    assert remote == [], remote
    assert sorted(p.name for p in pending.iterdir()) == before, "rerun's analytics ran (a session file appeared)"
    for seed in SEEDS:
        workspace.assert_as_alone(processed, seed)


@pytest.mark.long
@pytest.mark.slow
def test_kill_int_of_a_run_started_in_the_background_by_a_script_is_heard(workspace):
    """``pdr run &`` in a shell without job control starts with SIGINT ignored; the stop must still work."""
    raw = _raw_with_goods(workspace)
    processed = workspace.processed()
    script = 'trap "" INT; "$0" run --raw "$1" --processed "$2" -j 2 & pid=$!; sleep 1.5; kill -INT $pid; wait $pid'
    proc = subprocess.run(["sh", "-c", script, PDR, str(raw), str(processed)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.splitlines() == ["pdr: interrupted: the recordings finished so far are kept; pdr run again "
                                        "does the rest"], proc.stderr
    _no_torn_or_temporary_file(processed)


@pytest.mark.long
@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_during_discover_of_many_is_one_line_begins_nothing_more_and_keeps_what_is_finished(tmp_path, sig):
    """``pdr discover raw/*.csv``: a stop once the first recording is discovered says so in one line,
    starts none of the recordings still waiting (before, it ran them all, then exited without a word), and
    leaves every finished one's outputs whole."""
    raw, out = tmp_path / "raw", tmp_path / "out"
    raw.mkdir()
    names = [f"good{seed}" for seed in range(8)]
    for seed, name in enumerate(names):
        (raw / f"{name}.csv").write_bytes(good_csv(seed))
    proc = subprocess.Popen([PDR, "discover", *(str(raw / f"{n}.csv") for n in names), "--out", str(out), "-j", "2",
                             "--no-rrd"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 120
    while not list(out.glob("*/discovery.json")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    family = _descendants(proc.pid)
    os.killpg(proc.pid, sig)
    _, err = proc.communicate(timeout=60)
    status, words = {signal.SIGINT: (130, "interrupted"), signal.SIGTERM: (143, "terminated (SIGTERM)")}[sig]
    assert proc.returncode == status, err
    assert err.splitlines() == [f"pdr: {words}: the discoveries finished so far are in {out}/<run>/; the summary "
                                "across runs was not written (discover them again to have it)"], err
    assert not _wait_gone(family, within_s=10), "processes left"
    finished = sorted(p.parent.name for p in out.glob("*/discovery.json"))
    assert 1 <= len(finished) <= 4, finished              # the two under way at most finished after the stop
    assert not (out / "summary.csv").exists()
    for name in finished:
        assert json.loads((out / name / "discovery.json").read_text())["recording"].endswith(f"{name}.csv")
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
