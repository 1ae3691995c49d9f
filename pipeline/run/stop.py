"""Stopping ``pdr run`` from outside: Ctrl-C and SIGTERM end it with one line, keeping what is finished.

The terminal sends Ctrl-C's SIGINT to every process of the foreground group:
the forkserver (while it imports the heavy modules) and the pool's workers
would each print a traceback of their own, and the parent then fails to talk
to them (``EOFError`` in ``_adjust_process_count``).  So the children ignore
SIGINT (``children_ignore_sigint``: the disposition passes through the
forkserver's exec to every worker) and the parent alone decides: it stops the
workers, removes the temporaries they leave (outputs are written by rename,
so none is torn), and says so.  SIGTERM raises ``Stopped`` in the parent the
same way, with its own words and exit status (128 + 15, as a shell reports a
process killed by it).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

INTERRUPTED = "interrupted: the recordings finished so far are kept; pdr run again does the rest"
TERMINATED = "terminated (SIGTERM): the recordings finished so far are kept; pdr run again does the rest"


class Stopped(KeyboardInterrupt):
    """A stop asked from outside; ``exit_status`` is what the command exits with."""

    def __init__(self, message: str = INTERRUPTED, exit_status: int = 130) -> None:
        super().__init__(message)
        self.exit_status = exit_status


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def children_ignore_sigint() -> Iterator[None]:
    """SIGINT ignored while child processes are started (they inherit it); the parent's handler after."""
    if not _in_main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


_received: list[Stopped] = []       # the stops signals raised during ``stop_signals``
_deferring = 0                      # depth of ``stops_deferred`` in the main thread


def _stop(stop: Stopped) -> None:
    _received.append(stop)
    if not _deferring:
        raise stop


def _raise_terminated(signum: int, frame: object) -> None:
    _stop(Stopped(TERMINATED, 128 + signum))


def _raise_interrupted(signum: int, frame: object) -> None:
    _stop(Stopped())


@contextmanager
def stops_deferred() -> Iterator[None]:
    """A stop that comes during the block is raised at its end, not inside it.

    Around a worker's start: raised between the start and the pool's record of
    the new process, the stop would leave a worker nobody stops, which reads its
    queues after this process has removed them (a traceback on the terminal)."""
    global _deferring
    if not _in_main_thread():
        yield
        return
    before = len(_received)
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1
    if len(_received) > before and not _deferring:
        raise _received[-1]


def stopped_by(err: BaseException) -> Stopped | None:
    """The stop behind ``err``: itself (Ctrl-C or SIGTERM), or one a signal raised during ``stop_signals``
    that surfaced as another exception (raised while a C extension initialises, it arrives as
    ``ImportError: initialization failed``); None for a failure of its own."""
    if isinstance(err, Stopped):
        return err
    if isinstance(err, KeyboardInterrupt):
        return Stopped()
    return _received[-1] if _received else None


@contextmanager
def stop_signals() -> Iterator[None]:
    """For the duration: SIGTERM raises ``Stopped`` in the main thread (the cleanup of Ctrl-C then runs),
    and SIGINT raises ``Stopped`` too (a ``KeyboardInterrupt``) even when it was ignored from the start; each
    is remembered (``stopped_by``).  A shell without job
    control starts ``pdr run &`` with SIGINT ignored, which Python keeps: a script's ``kill -INT`` (or a
    Ctrl-C to its whole group) then went unheard and the run carried on to the end."""
    if not _in_main_thread():
        yield
        return
    _received.clear()
    previous_term = signal.signal(signal.SIGTERM, _raise_terminated)
    previous_int = signal.signal(signal.SIGINT, _raise_interrupted)
    try:
        yield
    finally:
        if signal.getsignal(signal.SIGTERM) is _raise_terminated:     # not once nothing is left to stop
            signal.signal(signal.SIGTERM, previous_term)
            signal.signal(signal.SIGINT, previous_int)
        _received.clear()


def nothing_left_to_stop() -> None:
    """Every recording is done: a stop from here to the process's end would only cut the summary short
    (or kill the process as it exits, with the status of a signal), so SIGINT and SIGTERM are ignored
    and the status is the run's."""
    if _in_main_thread():
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
