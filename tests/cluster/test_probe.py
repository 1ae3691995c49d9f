"""``--cluster`` at something that is not a dask scheduler: one line naming the address and what answers
there, within the connect timeout, before dask's client is handed the connection."""

from __future__ import annotations

import http.server
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from pipeline.cluster import connect as connect_module
from pipeline.errors import PdrError
from pipeline.run import run_pipeline
from tests.hostile.folders import CODE, good_csv

TIMEOUT_S = 1.0


@contextmanager
def _listener(behaviour: str) -> Iterator[str]:
    """A local TCP listener that is silent, speaks HTTP, or sends bytes of no protocol at once."""
    if behaviour == "http":
        server = http.server.HTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            yield f"tcp://127.0.0.1:{server.server_address[1]}"
        finally:
            server.shutdown()
            server.server_close()
        return
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(8)                  # the kernel completes connections; nothing is ever accepted or said
    stop = threading.Event()

    def babble() -> None:
        sock.settimeout(0.1)
        while not stop.is_set():
            try:
                conn, _ = sock.accept()
            except OSError:
                continue
            with conn:
                conn.sendall(b"\xff" * 64)          # read by dask as a frame length of exabytes

    thread = threading.Thread(target=babble, daemon=True) if behaviour == "garbage" else None
    if thread:
        thread.start()
    try:
        yield f"tcp://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        stop.set()
        if thread:
            thread.join()
        sock.close()


def _refused_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("behaviour, said", [
    ("http", "an HTTP server answers there, not a dask scheduler"),
    ("silent", f"a TCP listener there said nothing in {TIMEOUT_S:g} s (a dask scheduler greets at once)"),
    ("garbage", "something answers there that is not a dask scheduler (it sent \\xff\\xff"),
])
def test_a_listener_that_is_not_a_scheduler_is_named_within_the_timeout(tmp_path, monkeypatch, behaviour, said):
    monkeypatch.setattr(connect_module, "CONNECT_TIMEOUT_S", TIMEOUT_S)
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "good0.csv").write_bytes(good_csv(0))
    with _listener(behaviour) as address:
        started = time.monotonic()
        with pytest.raises(PdrError) as err:
            run_pipeline(raw, tmp_path / "processed", code=CODE, cluster=address)
        took = time.monotonic() - started
    text = str(err.value)
    assert text.startswith(f"{address}: {said}"), text
    assert text.endswith("expected tcp://HOST:PORT of a running `dask scheduler`") and "\n" not in text
    assert took < 10 * TIMEOUT_S, f"{took:.1f} s"          # bounded by the timeout: no hang


@pytest.mark.parametrize("address, said", [
    ("tls://127.0.0.1:1", "a tls:// scheduler needs the cluster's certificates"),
    ("ws://127.0.0.1:1", "unsupported protocol ws://"),
    ("tcp://127.0.0.1:99999", "not a valid port"),
    ("tcp://127.0.0.1:{refused}", "cannot reach a dask scheduler there: Connection refused"),
])
def test_addresses_that_cannot_be_a_scheduler_are_refused_in_one_line(tmp_path, monkeypatch, address, said):
    monkeypatch.setattr(connect_module, "CONNECT_TIMEOUT_S", TIMEOUT_S)
    address = address.format(refused=_refused_port())
    with pytest.raises(PdrError) as err:
        connect_module.connect(address)
    assert str(err.value).startswith(f"{address}: {said}") and "\n" not in str(err.value), str(err.value)
