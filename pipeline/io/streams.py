"""Standard streams a command can rely on, whatever the shell handed it (``pdr run 2>&-``, ``>&-``, ``<&-``).

A closed descriptor 0, 1 or 2 is worse than a missing ``sys.stderr``: the next
file the process opens takes its number, so a library or a child process that
writes to "stderr" would write into the lock file or an output.  Each closed
one is therefore opened on the null device first, and Python's stream object
for it, None at start-up, made on that descriptor: what the command prints
there is dropped, as the user asked, and the command itself runs as usual.
"""

from __future__ import annotations

import io
import os
import sys

_STREAMS = ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w"))


def _closed(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return True
    return False


def mend_standard_streams() -> list[str]:
    """Give every closed standard descriptor the null device and every missing ``sys`` stream an object;
    returns the names of those mended (for tests and diagnostics)."""
    mended = []
    for fd, name, mode in _STREAMS:
        if _closed(fd):
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
            mended.append(name)
        if getattr(sys, name) is None:
            stream = io.TextIOWrapper(io.FileIO(fd, mode, closefd=False), encoding="utf-8",
                                      errors="backslashreplace", line_buffering=(mode == "w"))
            setattr(sys, name, stream)
            setattr(sys, f"__{name}__", stream)
            if name not in mended:
                mended.append(name)
    return mended
