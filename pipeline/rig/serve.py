"""``pdr rig serve --pty``: the virtual rig behind a pseudo-terminal, for ``pdr record`` without hardware.

A recording of the virtual rig (``make_recording``: its hidden effects and
serial artefacts) is written to the master side of a pty, line by line, at
the instants the board printed them (``--speed X``: X times faster).  The
slave side is the "serial port" a reader opens.  Like an Arduino whose
bootloader runs when the port opens, nothing is sent until a reader has the
port open, then ``boot_s``: a reader that flushes its input on opening
(pyserial does) loses nothing.  At the end the server waits until the reader
has taken every byte, then closes the master: to the reader that is the
board being unplugged.  The bytes sent are exactly ``Recording.csv_bytes``.
"""

from __future__ import annotations

import fcntl
import os
import select
import struct
import termios
import time
import tty
from dataclasses import dataclass

import numpy as np

from pipeline.errors import PdrError
from pipeline.rig.recording import Recording

POLL_S = 0.02


@dataclass(frozen=True)
class Schedule:
    """The capture's physical lines (terminators kept) and when each leaves the board (s from the first)."""

    lines: list[bytes]
    at_s: np.ndarray


def line_schedule(rec: Recording) -> Schedule:
    """Each line goes out when its sample was taken; lines without one (header, comment, blank) with the next.

    A merged line (two samples, the newline lost) goes out at its second
    sample; lines after the last sample go out with it.
    """
    lines = rec.csv_bytes.splitlines(keepends=True)
    if b"".join(lines) != rec.csv_bytes:          # splitlines keeps every byte; this guards that claim
        raise PdrError("virtual rig capture does not split into lines losslessly")
    at = np.full(len(lines), np.nan)
    sent = rec.truth[rec.truth["line"] > 0]
    for line, t in zip(sent["line"].to_numpy(), sent["t_s"].to_numpy()):
        at[line - 1] = t if np.isnan(at[line - 1]) else max(at[line - 1], t)
    following = np.nan
    for i in range(len(at) - 1, -1, -1):
        if np.isnan(at[i]):
            at[i] = following
        following = at[i]
    last = np.nan
    for i in range(len(at)):                    # trailing lines without a sample: with the last one
        if np.isnan(at[i]):
            at[i] = last
        last = at[i]
    return Schedule(lines=lines, at_s=at - at[0])


class PtyRig:
    """A pseudo-terminal whose slave path is the virtual rig's serial port."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        self.path = os.ttyname(slave)
        tty.setraw(slave)                       # no echo, no CR/LF translation: bytes pass unchanged
        os.close(slave)                         # the reader's open is then seen as the hang-up clearing

    def reader_present(self) -> bool:
        """While no process has the slave open, the master polls as hung up."""
        poller = select.poll()
        poller.register(self.master, select.POLLHUP)
        return not any(ev & select.POLLHUP for _fd, ev in poller.poll(0))

    def wait_for_reader(self, timeout_s: float | None) -> bool:
        end = None if timeout_s is None else time.monotonic() + timeout_s
        while not self.reader_present():
            if end is not None and time.monotonic() > end:
                return False
            time.sleep(POLL_S)
        return True

    def send(self, data: bytes) -> bool:
        """Write all of ``data`` (blocking while the reader's buffer is full); False when the reader went away."""
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.master, view):]
            except OSError:
                return False
        return True

    def unread(self) -> int:
        """Bytes written that the reader has not read yet (the slave's input queue, seen from the master)."""
        try:
            slave = os.open(self.path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return 0
        try:
            return struct.unpack("i", fcntl.ioctl(slave, termios.FIONREAD, b"\0\0\0\0"))[0]
        finally:
            os.close(slave)

    def drain(self, timeout_s: float, settle_s: float = 0.2) -> None:
        """Wait until the reader has taken everything: nothing unread for ``settle_s`` in a row.

        A write to the master reaches the slave's queue a moment later (the
        kernel pushes it asynchronously), so one empty look is not enough.
        """
        end = time.monotonic() + timeout_s
        empty_since = None
        while self.reader_present() and time.monotonic() < end:
            now = time.monotonic()
            if self.unread():
                empty_since = None
            elif empty_since is None:
                empty_since = now
            elif now - empty_since >= settle_s:
                return
            time.sleep(POLL_S)

    def close(self) -> None:
        os.close(self.master)


def serve(rig: PtyRig, schedule: Schedule, speed: float, boot_s: float = 0.5) -> int:
    """Stream the schedule through the pty in real time / ``speed``; returns the bytes written.

    Stops early when the reader closes the port (nobody would read the rest).
    """
    time.sleep(boot_s)
    start = time.monotonic()
    sent = 0
    for line, at in zip(schedule.lines, schedule.at_s):
        wait = start + float(at) / speed - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        if not rig.reader_present() or not rig.send(line):
            break
        sent += len(line)
    return sent
