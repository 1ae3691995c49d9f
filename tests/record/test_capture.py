"""The capture loop on a real pseudo-terminal opened with pyserial: bytes as sent, stops and their reasons."""

from __future__ import annotations

import threading
import time

import pytest

from pipeline.errors import PdrError
from pipeline.record.capture import STOP_DURATION, STOP_INTERRUPT, STOP_PORT_GONE, capture, create_recording
from pipeline.record.session import open_port
from pipeline.rig.serve import PtyRig

LINES = [b"t_ms,counts,adc,dir\r\n"] + [f"{50 * i},{i * 7 - 30},{500 + i % 9},1\r\n".encode() for i in range(200)]


def _writer(rig: PtyRig, lines: list[bytes], gap_s: float, close: bool) -> threading.Thread:
    def run() -> None:
        rig.wait_for_reader(5.0)
        time.sleep(0.2)                          # pyserial flushes the input right after opening
        for line in lines:
            rig.send(line)
            time.sleep(gap_s)
        if close:
            rig.drain(5.0)
            rig.close()
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_existing_recording_is_refused_and_untouched(tmp_path):
    path = tmp_path / "taken.csv"
    path.write_bytes(b"old")
    with pytest.raises(PdrError, match="already exists.*never overwrites"):
        create_recording(path)
    assert path.read_bytes() == b"old"
    with pytest.raises(PdrError, match="folder not found"):
        create_recording(tmp_path / "nope" / "x.csv")


def test_unknown_port_is_one_line_naming_it(tmp_path):
    with pytest.raises(PdrError, match="/dev/nonexistent-pdr.*cannot open the serial port"):
        open_port("/dev/nonexistent-pdr", 115200)


def test_port_gone_ends_the_capture_with_every_byte_sent(tmp_path):
    rig = PtyRig()
    writer = _writer(rig, LINES, 0.0005, close=True)
    port = open_port(rig.path, 115200)
    fd = create_recording(tmp_path / "gone.csv")
    chunks: list[tuple[int, bytes]] = []
    result = capture(port, fd, stop=threading.Event(), on_chunk=lambda off, data: chunks.append((off, data)))
    port.close()
    writer.join(5)
    assert result.reason.startswith(STOP_PORT_GONE)
    assert (tmp_path / "gone.csv").read_bytes() == b"".join(LINES) == b"".join(c for _o, c in chunks)
    assert result.n_bytes == len(b"".join(LINES))
    assert [o for o, _c in chunks] == [sum(len(c) for _o, c in chunks[:i]) for i in range(len(chunks))]


@pytest.mark.parametrize("how", ["duration", "stop"])
def test_duration_and_stop_end_on_a_whole_line(tmp_path, how):
    rig = PtyRig()
    writer = _writer(rig, LINES, 0.004, close=False)
    port = open_port(rig.path, 115200)
    fd = create_recording(tmp_path / "part.csv")
    stop = threading.Event()
    if how == "stop":
        threading.Timer(0.45, stop.set).start()
    result = capture(port, fd, stop=stop, duration_s=0.45 if how == "duration" else None)
    port.close()
    data = (tmp_path / "part.csv").read_bytes()
    assert result.reason == (STOP_DURATION if how == "duration" else STOP_INTERRUPT)
    assert b"".join(LINES).startswith(data) and data.endswith(b"\r\n")
    assert 3 < data.count(b"\n") < len(LINES)                   # stopped mid-stream, not at its end
    writer.join(5)
    rig.close()
