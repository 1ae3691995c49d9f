"""What listens at a ``--cluster`` address, found before dask's client is let near it.

``distributed.Client`` trusts the other end: a silent TCP listener or an HTTP
server (the dashboard's port, say) leaves it waiting for good, and bytes that
are not its protocol can be read as a frame length of exabytes.  A dask
scheduler greets every connection at once (its handshake: a msgpack map with
``compression`` and ``pickle-protocol``), so one connection with a timeout
tells a scheduler from anything else, and says what was found instead.
"""

from __future__ import annotations

import socket
from urllib.parse import urlsplit

from pipeline.errors import PdrError

DEFAULT_PORT = 8786                        # `dask scheduler`'s default port
DASHBOARD_PORT = 8787                      # its dashboard's (HTTP)
_GREETING_MARKS = (b"pickle-protocol", b"compression")
_EXPECTED = "expected tcp://HOST:PORT of a running `dask scheduler`"


def scheduler_endpoint(address: str) -> tuple[str, int]:
    """Host and port of a ``tcp://HOST[:PORT]`` (or ``HOST:PORT``) address; a refusal for anything else."""
    text = address.strip()
    if "://" not in text:
        text = f"tcp://{text}"
    parts = urlsplit(text)
    if parts.scheme == "tls":
        raise PdrError("a tls:// scheduler needs the cluster's certificates, which pdr run does not take; "
                       f"{_EXPECTED} on a trusted network (or an SSH tunnel to one)", path=address)
    if parts.scheme != "tcp":
        raise PdrError(f"unsupported protocol {parts.scheme}://; {_EXPECTED}", path=address)
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        raise PdrError(f"not a valid port; {_EXPECTED}", path=address) from None
    if not host or parts.path not in ("", "/") or parts.query or parts.username:
        raise PdrError(_EXPECTED, path=address)
    return host, port if port is not None else DEFAULT_PORT


def _printable(data: bytes) -> str:
    return repr(data[:24])[2:-1] + ("..." if len(data) > 24 else "")


def _http_answer(sock: socket.socket, host: str, timeout: float) -> bytes:
    """The first bytes a silent listener answers to an HTTP request (b"" if none)."""
    try:
        sock.sendall(f"HEAD / HTTP/1.0\r\nHost: {host}\r\n\r\n".encode("ascii", "backslashreplace"))
        sock.settimeout(timeout)
        return sock.recv(64)
    except OSError:
        return b""


def _not_a_scheduler(greeting: bytes, http: bytes, port: int, timeout: float) -> str:
    if greeting.startswith(b"HTTP/") or http.startswith(b"HTTP/"):
        hint = f" (the dashboard's port {DASHBOARD_PORT}? the scheduler's is {DEFAULT_PORT})" \
            if port == DASHBOARD_PORT else ""
        return f"an HTTP server answers there, not a dask scheduler{hint}"
    if greeting:
        return f"something answers there that is not a dask scheduler (it sent {_printable(greeting)!s})"
    return f"a TCP listener there said nothing in {timeout:g} s (a dask scheduler greets at once)"


def check_scheduler(address: str, timeout: float) -> None:
    """Return when a dask scheduler answers at ``address`` within ``timeout`` seconds; else a one-line
    ``PdrError`` naming the address and what was found there."""
    host, port = scheduler_endpoint(address)
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.gaierror as err:
        raise PdrError(f"cannot reach a dask scheduler there: host name not found ({err.strerror}); "
                       f"{_EXPECTED}", path=address) from None
    except TimeoutError:
        raise PdrError(f"cannot reach a dask scheduler there: no answer in {timeout:g} s (unreachable or "
                       f"filtered); {_EXPECTED}", path=address) from None
    except OSError as err:
        raise PdrError(f"cannot reach a dask scheduler there: {err.strerror or err}; {_EXPECTED}",
                       path=address) from None
    with sock:
        try:
            sock.settimeout(timeout)
            greeting = sock.recv(256)
        except TimeoutError:
            greeting = b""
        except OSError as err:
            raise PdrError(f"cannot reach a dask scheduler there: {err.strerror or err}; {_EXPECTED}",
                           path=address) from None
        if any(mark in greeting for mark in _GREETING_MARKS):
            return
        http = b"" if greeting else _http_answer(sock, host, min(timeout, 2.0))
    raise PdrError(f"{_not_a_scheduler(greeting, http, port, timeout)}; {_EXPECTED}", path=address)
