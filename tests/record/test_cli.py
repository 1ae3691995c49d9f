"""``pdr record``'s options and refusals, and Ctrl-C."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.errors import PdrError
from pipeline.record.capture import STOP_INTERRUPT
from pipeline.record.session import STOP_TERMINATED, RecordOptions, record
from pipeline.rig.serve import PtyRig

runner = CliRunner()


def test_list_prints_ports_or_says_there_are_none():
    res = runner.invoke(app, ["record", "--list"])
    assert res.exit_code == 0
    lines = res.output.strip().splitlines()
    assert lines == ["no serial ports found"] or all(line.startswith("/dev/") for line in lines)


def test_refusals_name_what_was_expected(tmp_path):
    (tmp_path / "taken.csv").write_bytes(b"t_ms,counts\n")
    cases = [(["record", "--name", "x"], "expected a serial port"),
             (["record", "/dev/null"], "expected --name"),
             (["record", "/dev/null", "--name", "bad/name"], "path separator"),
             (["record", "/dev/null", "--name", "x", "--duration", "0"], "duration > 0"),
             (["record", "/dev/null", "--name", "x", "--no-view", "--save-view", "a.rrd"], "at most one of"),
             (["record", "/dev/null", "--name", "taken", "--raw", str(tmp_path), "--no-view"], "already exists"),
             (["record", "/dev/nonexistent-pdr", "--name", "x", "--raw", str(tmp_path), "--no-view"],
              "cannot open the serial port")]
    for args, expected in cases:
        res = runner.invoke(app, args)
        assert res.exit_code != 0 and expected in str(res.exception), (args, res.exception)
    assert (tmp_path / "taken.csv").read_bytes() == b"t_ms,counts\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken.csv"]


@pytest.mark.parametrize("name", ["x\n", "x\ty", "x\r", "\nx", "x\x1b[31m", ".hidden", "a/b", "x%2Fy", "run-seg1"])
def test_names_with_control_characters_are_refused_by_one_rule_and_create_nothing(tmp_path, name):
    res = runner.invoke(app, ["record", "/dev/null", "--name", name, "--raw", str(tmp_path), "--no-view"])
    assert res.exit_code != 0 and isinstance(res.exception, PdrError), res.output
    assert str(res.exception).startswith("key 'NAME': ") and "rename" in str(res.exception)
    assert "\n" not in str(res.exception) and "\x1b" not in str(res.exception)     # printed on one clean line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("sig, said_reason", [(signal.SIGINT, STOP_INTERRUPT), (signal.SIGTERM, STOP_TERMINATED)])
def test_ctrl_c_stops_on_a_whole_line_and_keeps_every_byte(tmp_path, sig, said_reason):
    """SIGINT to this process while ``record`` captures in its main thread, as Ctrl-C in a terminal."""
    (tmp_path / "raw").mkdir()
    rig = PtyRig()
    sent = bytearray()
    csv = tmp_path / "raw" / "stopped.csv"

    def board() -> None:                    # prints a line every 5 ms until the reader goes away
        rig.wait_for_reader(30)
        time.sleep(0.3)
        for i in range(100000):
            line = f"{5 * i},{i % 300},{512 + i % 7},1\n".encode()
            if not rig.reader_present() or not rig.send(line):
                return
            sent.extend(line)
            time.sleep(0.005)

    def ctrl_c() -> None:                   # once bytes reach the file, the capture loop (and its handler) runs
        deadline = time.monotonic() + 30
        while (not csv.exists() or csv.stat().st_size < 500) and time.monotonic() < deadline:
            time.sleep(0.02)
        if csv.exists() and csv.stat().st_size >= 500:      # never signal a process that is not capturing
            os.kill(os.getpid(), sig)

    threads = [threading.Thread(target=f, daemon=True) for f in (board, ctrl_c)]
    for t in threads:
        t.start()
    said: list[str] = []
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    result, status = record(RecordOptions(port=rig.path, name="stopped", raw=tmp_path / "raw", view=None,
                                          run=False), say=said.append)
    for t in threads:
        t.join(10)
    rig.close()
    assert status == 0 and result.reason == said_reason
    assert said[1].startswith(f"stopped: {said_reason}") and "--no-run" in said[-1]
    data = csv.read_bytes()
    assert bytes(sent).startswith(data) and data.endswith(b"\n") and len(data) >= 500
    assert {s: signal.getsignal(s) for s in handlers} == handlers          # restored after the capture
