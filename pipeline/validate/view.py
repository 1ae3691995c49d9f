"""``pdr view``: a run's recording in the Rerun viewer, native or in a browser.

- One run opens its own ``.rrd`` (the layout is saved inside it).
- Several runs open side by side: their recordings' chunks are moved under
  ``/runs/<name>`` into one recording with a layout of one column per run
  (``side_by_side_rrd``), written to the temporary folder.
- Without a display (a lab server, a cluster node, SSH) the native viewer
  cannot start; ``pdr view`` says so and points to ``--web``.
- ``--web`` serves the file(s) over HTTP and Rerun's web viewer beside them,
  both on ``--bind`` (127.0.0.1 by default), and prints the address to open.
  The web viewer loads the recording, layout included, from that address.
"""

from __future__ import annotations

import errno
import hashlib
import http.server
import os
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import PdrError

NO_DISPLAY = ("no display to open the viewer on (neither DISPLAY nor WAYLAND_DISPLAY is set, e.g. over SSH or "
              "on a cluster node): run `pdr view --web RUN...` and open the address it prints in a browser")


# The viewer keeps a layout per application id: the side-by-side files, whose views look at
# /runs/<name>/..., have their own, so a run's recording (application id "pdr") is never shown in it.
SIDE_BY_SIDE_APP = "pdr-side-by-side"


def display_available(environ=os.environ, platform: str = sys.platform) -> bool:
    """A native window can open: on Linux and the BSDs only with an X11 or Wayland display."""
    if not platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return True
    return bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def side_by_side_rrd(rrds: dict[str, Path], target: Path) -> Path:
    """One recording holding every run's data under ``/runs/<name>``, with the side-by-side layout."""
    import rerun as rr
    from rerun.chunk import RrdReader

    from pipeline.io.atomic import atomic_path
    from pipeline.validate.rerun_blueprint import side_by_side_blueprint
    from pipeline.validate.rerun_io import blueprint_chunks, write_recording

    moved, peak = [], 0.0
    for name, path in rrds.items():
        for chunk in RrdReader(path).stream().to_chunks():
            if chunk.entity_path.startswith("/__"):          # the recording's own properties
                continue
            if chunk.entity_path == "/signals/theta" and not chunk.is_static:
                values = np.asarray(chunk.to_record_batch().column("Scalars:scalars").to_pylist(), dtype=float)
                peak = max(peak, float(np.nanmax(np.abs(values))))
            moved.append(chunk.with_entity_path(f"/runs/{name}{chunk.entity_path}"))
    peak = float(np.ceil(peak * 10.0) / 10.0) or 1.0
    # one angle range for every column, the data of all with 3 % to spare (the legends have views of their own)
    layout = blueprint_chunks(side_by_side_blueprint, tuple(rrds), (round(-1.03 * peak, 3), round(1.03 * peak, 3)))
    with atomic_path(Path(target)) as tmp:
        write_recording(tmp, "side-by-side:" + "+".join(rrds), layout, lambda rec: rr.send_chunks(moved, recording=rec),
                        application_id=SIDE_BY_SIDE_APP)
    return Path(target)


def recording_to_open(rrds: dict[str, Path]) -> Path:
    """The run's own file, or for several runs their side-by-side recording (in the temporary folder,
    named after the runs and files so a repeated call reuses it)."""
    if len(rrds) == 1:
        return next(iter(rrds.values()))
    key = "\n".join(f"{n}\t{p.resolve()}\t{p.stat().st_mtime_ns}" for n, p in rrds.items())
    folder = Path(tempfile.gettempdir()) / "pdr-view"
    folder.mkdir(exist_ok=True)
    target = folder / f"{'+'.join(rrds)[:80]}-{hashlib.sha256(key.encode()).hexdigest()[:12]}.rrd"
    return target if target.is_file() else side_by_side_rrd(rrds, target)


def open_native(path: Path) -> None:
    from pipeline.validate.rerun_io import rerun_env, rerun_executable

    if not display_available():
        raise PdrError(NO_DISPLAY)
    subprocess.Popen([rerun_executable(), str(path)], env=rerun_env())


class _FileHandler(http.server.BaseHTTPRequestHandler):
    """Serves the one file it was given, with the CORS header the web viewer's fetch needs."""

    files: dict[str, Path] = {}

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        path = self.files.get(urllib.parse.unquote(urllib.parse.urlparse(self.path).path))
        if path is None:
            self.send_error(404)
            return
        data = path.read_bytes()
        self.send_response(200)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Access-Control-Allow-Origin", "*")
        self.end_headers()
        self.wfile.write(data)

    def log_message(self, *args) -> None:      # quiet: the command prints the address once
        pass


@dataclass
class WebServer:
    """The recording's HTTP server and the ``rerun --serve-web`` process beside it."""

    url: str                 # what to open in a browser
    recording_url: str       # where the web viewer fetches the recording from
    _httpd: http.server.ThreadingHTTPServer = field(repr=False)
    _viewer: subprocess.Popen = field(repr=False)
    port: int = 0            # the web viewer's (what --port asked, or the free one picked for 0)
    file_port: int = 0       # the recording's

    def stop(self) -> None:
        self._viewer.terminate()
        try:
            self._viewer.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self._viewer.kill()
        self._httpd.shutdown()
        self._httpd.server_close()


def _free(bind: str, port: int) -> OSError | None:
    """None when ``port`` can be listened on at ``bind`` now, else why not (in use, not permitted)."""
    import socket

    family = socket.AF_INET6 if ":" in bind else socket.AF_INET
    with socket.socket(family) as s:
        try:
            s.bind((bind, port))
        except OSError as err:
            return err
    return None


def listen_ports(bind: str, port: int) -> tuple[int, int]:
    """The web viewer's port and the recording's (the next one), both free on ``bind`` now.

    ``port`` 0 picks a free pair.  A port another program holds is refused here, by name: the viewer
    would fail to listen on it while a check that something answers there would pass."""
    if not 0 <= port <= 65534:
        raise PdrError(f"expected a port from 1 to 65534 (the recording is served on the next one), or 0 for "
                       f"any free pair, got {port}", key="--port")
    if port == 0:
        import socket

        for _ in range(50):
            with socket.socket(socket.AF_INET6 if ":" in bind else socket.AF_INET) as s:
                s.bind((bind, 0))
                candidate = s.getsockname()[1]
            if candidate < 65535 and _free(bind, candidate) is None and _free(bind, candidate + 1) is None:
                return candidate, candidate + 1
        raise PdrError(f"found no two adjacent free ports on {bind}: give one with --port", key="--port")
    for p, what in ((port, "the web viewer"), (port + 1, "the recording (--port + 1)")):
        err = _free(bind, p)
        if err is not None:
            said = "in use by another program" if err.errno == errno.EADDRINUSE else err.strerror
            raise PdrError(f"cannot serve {what} on {bind}:{p}: {said}; choose another with --port "
                           "(0 picks a free one)", key="--port")
    return port, port + 1


def _wait_listening(host: str, port: int, proc: subprocess.Popen, timeout: float = 20.0) -> None:
    import socket

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise PdrError(f"the Rerun web viewer exited at start (code {proc.returncode}); is port {port} in use?")
        with socket.socket() as s:
            if s.connect_ex((host, port)) == 0:
                return
        time.sleep(0.1)
    raise PdrError(f"the Rerun web viewer did not start listening on {host}:{port} within {timeout:.0f} s")


def serve_web(path: Path, bind: str = "127.0.0.1", port: int = 9090, file_port: int | None = None) -> WebServer:
    """Serve ``path`` over HTTP on ``file_port`` (default ``port + 1``) and Rerun's web viewer on ``port``
    (0: a free pair, see ``listen_ports``)."""
    from pipeline.validate.rerun_io import rerun_env, rerun_executable

    if file_port is None:
        port, file_port = listen_ports(bind, port)
    handler = type("Handler", (_FileHandler,), {"files": {f"/{path.name}": Path(path)}})
    try:
        httpd = http.server.ThreadingHTTPServer((bind, file_port), handler)
    except OSError as err:
        raise PdrError(f"cannot serve the recording on {bind}:{file_port}: {err.strerror}") from None
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    host = "127.0.0.1" if bind in ("0.0.0.0", "::") else bind
    recording_url = f"http://{host}:{file_port}/{urllib.parse.quote(path.name)}"
    viewer = subprocess.Popen([rerun_executable(), "--serve-web", "--bind", bind, "--web-viewer-port", str(port),
                               recording_url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=rerun_env())
    try:
        _wait_listening(host, port, viewer)
    except PdrError:
        viewer.kill()
        httpd.shutdown()
        httpd.server_close()
        raise
    url = f"http://{host}:{port}/?url={urllib.parse.quote(recording_url, safe='')}"
    return WebServer(url=url, recording_url=recording_url, _httpd=httpd, _viewer=viewer, port=port,
                     file_port=file_port)
