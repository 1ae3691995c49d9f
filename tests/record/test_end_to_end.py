"""``pdr record`` on ``pdr rig serve --pty``: real processes, a real pseudo-terminal, the real pipeline after.

The bars of issue 19: the capture is byte-identical to what the rig sent (at 20x, 400 lines/s,
with the live view on) and validates like the same recording made with ``pdr rig make``;
``kill -9`` mid-capture leaves a file ingest accepts; the other end closing mid-stream ends
the capture cleanly and the pipeline runs on what was captured (the serve closing its end after
the stream, and here mid-line, with ``record`` called in this process).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from pipeline.ingest.stage import ingest_recording
from pipeline.record.capture import STOP_PORT_GONE
from pipeline.record.live import LIVE_VIEW_NAMES
from pipeline.record.session import RecordOptions, record, run_recorded
from pipeline.rig.cli import recording_from_options
from pipeline.rig.recording import write_recording
from pipeline.rig.serve import PtyRig, line_schedule

PDR = str(Path(sys.executable).with_name("pdr"))
RIG = ["--effect", "coulomb_friction:Tc=3e-4", "--artefact", "ide2", "--artefact", "garbled=3", "--seed", "7",
       "--duration", "8"]
pytestmark = pytest.mark.slow


@pytest.fixture
def serve_pty(tmp_path):
    """``pdr rig serve --pty ARGS`` in tmp_path: (process, device path); stopped at the end whatever happens."""
    procs: list[subprocess.Popen] = []

    def start(*args: str) -> tuple[subprocess.Popen, str]:
        proc = subprocess.Popen([PDR, "rig", "serve", "--pty", "--wait", "60", *args], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, cwd=tmp_path)
        procs.append(proc)
        return proc, proc.stdout.readline().strip()

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


def _validation(processed: Path, run: str) -> dict:
    out = json.loads((processed / run / "validation.json").read_text())
    out.pop("run")
    return out


def test_record_from_the_virtual_rig_is_byte_identical_and_validates_like_rig_make(tmp_path, serve_pty):
    (tmp_path / "raw").mkdir()
    server, port = serve_pty("--speed", "20", "--toml", "raw/live.toml", *RIG)
    assert port.startswith("/dev/")
    rec = subprocess.Popen([PDR, "record", port, "--name", "live", "--save-view", "live.rrd"], cwd=tmp_path,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # meanwhile, what `pdr rig make live --out made RIG...` writes (its own code), through the same pipeline
    write_recording(recording_from_options(["coulomb_friction:Tc=3e-4"], [], None, 7, 8.0, ["ide2", "garbled=3"]),
                    tmp_path / "made", "live")
    assert run_recorded(tmp_path / "made" / "live.csv", tmp_path / "made_processed", say=lambda _s: None) == 0
    stdout, stderr = rec.communicate(timeout=120)
    server.wait(30)
    assert rec.returncode == 0, stdout + stderr
    # the rig closed its end when done: the capture ends on that, and the pipeline runs on it
    assert "stopped: the port went away" in stdout and "pdr view live" in stdout
    assert "validation summary" in stderr

    sent = (tmp_path / "made" / "live.csv").read_bytes()
    assert (tmp_path / "raw" / "live.csv").read_bytes() == sent               # every byte, none added
    assert (tmp_path / "raw" / "live.toml").read_text() == (tmp_path / "made" / "live.toml").read_text()
    assert _validation(tmp_path / "processed", "live") == _validation(tmp_path / "made_processed", "live")

    # the live view saw every sample ingest kept (nothing dropped at 400 lines/s), read back by rerun
    kept = json.loads((tmp_path / "processed" / "live" / "ingest_report.json").read_text())["rows"]["kept"]
    reader = RrdReader(tmp_path / "live.rrd")
    rows = sum(ch.num_rows for ch in reader.stream().to_chunks()
               if ch.entity_path == "/signals/theta" and not ch.is_static)
    assert rows == kept
    names = {v[0] for ch in reader.stream(store=reader.blueprints()[0]).to_chunks()
             for rb in [ch.to_record_batch()] if "ViewBlueprint:display_name" in rb.schema.names
             for v in rb.column("ViewBlueprint:display_name").to_pylist() if v}
    assert names == set(LIVE_VIEW_NAMES)                     # it opens on the live layout
    assert "3 lines did not parse, 0 chunks dropped" in stdout


def test_kill_9_mid_capture_leaves_a_file_ingest_accepts(tmp_path):
    (tmp_path / "raw").mkdir()
    rig = PtyRig()
    recording = recording_from_options([], [], None, 3, 24.95, [])
    schedule = line_schedule(recording)
    sent_at: list[tuple[float, int]] = []

    def board() -> None:                        # the rig at 10x, logging when each line left
        rig.wait_for_reader(30)
        time.sleep(0.5)
        start, total = time.monotonic(), 0
        for line, at in zip(schedule.lines, schedule.at_s):
            time.sleep(max(0.0, start + at / 10 - time.monotonic()))
            if not rig.send(line):
                return
            total += len(line)
            sent_at.append((time.monotonic(), total))

    thread = threading.Thread(target=board, daemon=True)
    thread.start()
    proc = subprocess.Popen([PDR, "record", rig.path, "--name", "killed", "--no-view"], cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    csv = tmp_path / "raw" / "killed.csv"
    deadline = time.monotonic() + 60
    while (not csv.exists() or csv.stat().st_size < 3000) and time.monotonic() < deadline:
        time.sleep(0.05)
    waiting = rig.unread()                  # sent, not yet read by pdr record: the port still holds it
    os.kill(proc.pid, signal.SIGKILL)
    killed_at = time.monotonic()
    proc.wait(10)
    rig.close()
    thread.join(10)
    data = csv.read_bytes()
    assert recording.csv_bytes.startswith(data)                  # a prefix of what was sent, byte for byte
    sent_a_second_before = max((n for t, n in sent_at if t <= killed_at - 1.0), default=0)
    # all that was read is on disk, up to the last second (a starved reader may not have read it all yet)
    assert len(data) >= sent_a_second_before - waiting and len(data) < len(recording.csv_bytes)
    result = ingest_recording(csv, tmp_path / "processed")
    assert result.report["rows"]["kept"] >= data.count(b"\n") - 2        # the header, a cut last line at most
    assert result.report["rows"]["quarantined"] <= 1


def test_other_end_closing_mid_line_ends_cleanly_and_runs_the_pipeline(tmp_path):
    (tmp_path / "raw").mkdir()
    rig = PtyRig()
    recording = recording_from_options([], [], None, 4, 8.0, [])
    half = recording.csv_bytes[: len(recording.csv_bytes) // 2]
    half = half[: half.rindex(b"\n") + 1] + b"12345,6"              # unplugged in the middle of a line

    def board() -> None:
        rig.wait_for_reader(30)
        time.sleep(0.5)
        for i in range(0, len(half), 200):
            rig.send(half[i:i + 200])
            time.sleep(0.01)
        rig.drain(5)
        rig.close()

    thread = threading.Thread(target=board, daemon=True)
    thread.start()
    said: list[str] = []
    result, status = record(RecordOptions(port=rig.path, name="unplugged", raw=tmp_path / "raw",
                                          processed=tmp_path / "processed", view=None), say=said.append)
    thread.join(10)
    assert status == 0 and result.reason.startswith(STOP_PORT_GONE)
    assert said[-1] == f"pdr view unplugged --processed {tmp_path / 'processed'}"
    assert (tmp_path / "raw" / "unplugged.csv").read_bytes() == half
    report = json.loads((tmp_path / "processed" / "unplugged" / "ingest_report.json").read_text())
    assert report["rows"]["kept"] == half.count(b"\n") - 1 and report["rows"]["quarantined"] == 1
    validation = _validation(tmp_path / "processed", "unplugged")
    assert validation["n_samples"] == report["rows"]["kept"]
    assert validation["replay"]["signals"]["theta"]["mse"] < 1e-5
