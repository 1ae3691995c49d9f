"""The capture loop: serial bytes -> ``raw/NAME.csv``, exactly as received.

The file is created exclusively (an existing recording is never touched)
and every chunk read is written straight to it with ``os.write``: once
written, a chunk survives the process being killed.  ``fsync`` runs every
``sync_every_s`` (half a second), so even a power cut loses at most the last
second.  Board resets, partial lines and noise are kept as they come; ingest
reads them.

The loop does nothing else: the live view gets each chunk through
``on_chunk`` (a non-blocking hand-off to its queue) after the chunk is on
disk, so a slow viewer can cost frames, never bytes.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

from pipeline.errors import PdrError

READ_TIMEOUT_S = 0.1          # the longest a stop request waits for the loop to notice it
FINISH_LINE_S = 0.25          # at a stop, how long the line in progress may take to complete

STOP_INTERRUPT = "interrupted (Ctrl-C)"
STOP_DURATION = "duration reached"
STOP_PORT_GONE = "the port went away (board unplugged or the other end closed)"


class SerialPort(Protocol):
    """What the loop needs of ``serial.Serial`` (opened with ``timeout=READ_TIMEOUT_S``)."""

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...


@dataclass(frozen=True)
class CaptureResult:
    reason: str               # one of the STOP_* texts (STOP_PORT_GONE with the port's error appended)
    n_bytes: int
    seconds: float


def check_new_recording(path: Path) -> None:
    """Refuse early (before a viewer or the port is opened) what ``create_recording`` would refuse."""
    path = Path(path)
    if not path.parent.is_dir():
        raise PdrError("folder not found (expected the raw recordings folder)", path=path.parent)
    if path.exists():
        raise _exists_error(path)


def create_recording(path: Path) -> int:
    """Open ``path`` for appending, refusing if it exists (O_EXCL: no race with another writer)."""
    check_new_recording(path)
    try:
        return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o644)
    except FileExistsError:                   # created since the check
        raise _exists_error(path) from None


def _exists_error(path: Path) -> PdrError:
    return PdrError("a recording of that name already exists; pdr record never overwrites one, "
                    "choose another --name", path=path)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _read(port: SerialPort) -> bytes:
    return port.read(max(1, port.in_waiting))


def capture(port: SerialPort, fd: int, *, stop: threading.Event, duration_s: float | None = None,
            on_chunk: Callable[[int, bytes], None] | None = None,
            sync_every_s: float = 0.5) -> CaptureResult:
    """Copy the port to ``fd`` until ``stop`` is set, ``duration_s`` has passed, or the port fails.

    After a stop request or the duration, the line in progress is completed
    (up to ``FINISH_LINE_S``) so the file ends on a whole line when the
    board keeps printing.
    """
    start = last_sync = time.monotonic()
    written = 0
    last_byte = b"\n"
    reason = ""
    finish_by: float | None = None
    while True:
        now = time.monotonic()
        if finish_by is None:
            if stop.is_set():
                reason, finish_by = STOP_INTERRUPT, now + FINISH_LINE_S
            elif duration_s is not None and now - start >= duration_s:
                reason, finish_by = STOP_DURATION, now + FINISH_LINE_S
        if finish_by is not None and (last_byte == b"\n" or now >= finish_by):
            break
        try:
            data = _read(port) if finish_by is None else _finish_line(port)
        except OSError as err:                  # serial.SerialException is an OSError
            reason = f"{STOP_PORT_GONE}: {err}".rstrip(": ")
            break
        if data:
            _write_all(fd, data)
            if on_chunk is not None:
                on_chunk(written, data)
            written += len(data)
            last_byte = data[-1:]
        if now - last_sync >= sync_every_s:
            os.fsync(fd)
            last_sync = now
    os.fsync(fd)
    return CaptureResult(reason=reason, n_bytes=written, seconds=time.monotonic() - start)


def _finish_line(port: SerialPort) -> bytes:
    """Bytes up to and including the next line ending, or what arrived before the read timed out."""
    out = bytearray()
    while True:
        b = port.read(1)
        out += b
        if not b or b == b"\n":
            return bytes(out)
