"""`pdr view --web` and its ports: one taken by another program, 0 (any free pair), out of range."""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from tests.validate.net import default_sigint, free_port_pair

PDR = str(Path(sys.executable).with_name("pdr"))


@pytest.fixture(scope="module")
def rrd(tmp_path_factory) -> Path:
    """A small recording saved by the Rerun SDK (pdr view opens any .rrd by its path)."""
    import rerun as rr

    path = tmp_path_factory.mktemp("view-ports") / "tiny.rrd"
    rec = rr.RecordingStream("pdr-test-view-ports")
    rec.save(str(path))
    for k in range(10):
        rec.set_time("t", duration=k * 0.1)
        rec.log("signals/theta", rr.Scalars([0.1 * k]))
    rec.flush()
    rec.disconnect()
    return path


def _view(rrd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PDR, "view", "--web", *args, str(rrd)], capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("taken", [0, 1])
def test_a_port_another_program_holds_is_refused_by_name_and_nothing_is_served(rrd, taken):
    port = free_port_pair()
    with socket.socket() as other:
        other.bind(("127.0.0.1", port + taken))
        other.listen(1)
        proc = _view(rrd, "--port", str(port))
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stdout == ""                         # no address printed for a viewer that is not there
    assert proc.stderr.splitlines() == [
        f"pdr: error: key '--port': cannot serve {'the web viewer' if taken == 0 else 'the recording (--port + 1)'} "
        f"on 127.0.0.1:{port + taken}: in use by another program; choose another with --port (0 picks a free one)"]


@pytest.mark.parametrize("port", ["70000", "65535", "-1"])
def test_a_port_out_of_range_is_refused_in_one_line(rrd, port):
    proc = _view(rrd, "--port", port)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.splitlines() == [
        "pdr: error: key '--port': expected a port from 1 to 65534 (the recording is served on the next one), "
        f"or 0 for any free pair, got {port}"], proc.stderr


@pytest.mark.slow
def test_port_0_serves_the_viewer_and_the_recording_on_a_free_pair_it_prints(rrd):
    proc = subprocess.Popen([PDR, "view", "--web", "--port", "0", str(rrd)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    try:
        first, second = proc.stdout.readline(), proc.stdout.readline()
        match = re.search(r"(http://127\.0\.0\.1:(\d+)/\?url=\S+)", first)
        assert match, first + proc.stderr.read() if proc.poll() is not None else first
        port = int(match.group(2))
        assert port > 0 and f"ssh -L {port}:localhost:{port} -L {port + 1}:localhost:{port + 1} " in second
        page = urllib.request.urlopen(match.group(1), timeout=20)
        assert page.status == 200 and "Rerun" in page.read().decode()
        recording_url = urllib.parse.parse_qs(urllib.parse.urlparse(match.group(1)).query)["url"][0]
        assert recording_url == f"http://127.0.0.1:{port + 1}/tiny.rrd"
        assert urllib.request.urlopen(recording_url, timeout=20).read() == rrd.read_bytes()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
    assert proc.returncode == 0, proc.stderr.read()
