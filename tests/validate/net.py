"""Free local ports for the tests that start servers (bound to 127.0.0.1 only), and how they start them."""

import signal
import socket


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_port_pair() -> int:
    """A port P with P + 1 also free (``pdr view --web`` serves the recording on the next port)."""
    for _ in range(50):
        port = free_port()
        with socket.socket() as a, socket.socket() as b:
            try:
                a.bind(("127.0.0.1", port))
                b.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
        return port
    raise RuntimeError("no two adjacent free ports")


def default_sigint() -> None:
    """``preexec_fn`` of a server a test stops with SIGINT, as a user's Ctrl-C: a shell without job control
    starts its background jobs with SIGINT ignored, and the server would inherit that and never stop."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
