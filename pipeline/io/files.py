"""Checks on an input path made with ``stat`` alone, before anything opens it."""

from __future__ import annotations

import os
import stat
from pathlib import Path


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def regular_file_problem(path: Path) -> str | None:
    """Why ``path`` cannot be read as a recording without opening it, or None when it is a regular file."""
    try:
        st = os.stat(path)          # follows symlinks: a dangling one or a loop raises here
    except FileNotFoundError:
        return "a symlink whose target is missing" if os.path.islink(path) else "no such file"
    except OSError as err:          # a symlink loop, a name too long, no permission
        return f"cannot be read: {err.strerror}"
    if not stat.S_ISREG(st.st_mode):
        return f"{_kind(st.st_mode)}, expected a regular CSV file"
    return None


# Reading a recording takes about ten times its size in memory at the peak (the bytes, the parsed
# columns, the tables of every stage); 256 MiB (about 10 million samples: 139 hours at 50 ms) needs
# ~2.5 GB.  A bigger file is refused by its size before it is read, rather than read until the kernel
# kills pdr and the recordings beside it with it.
MAX_RECORDING_BYTES = 256 << 20
SNIFF_BYTES = 64 << 10          # the first bytes a recording's content is judged by before it is read


def recording_file_problem(path: Path) -> str | None:
    """Why ``path`` cannot be read as a recording, judged before it is read whole: what it is (by
    ``stat``), its size, and its first ``SNIFF_BYTES`` (a file of zeros, a binary file), or None."""
    problem = regular_file_problem(path)
    if problem is not None:
        return problem
    size = os.stat(path).st_size
    if size > MAX_RECORDING_BYTES:
        return (f"{size / (1 << 20):.0f} MiB, expected a recording of at most {MAX_RECORDING_BYTES >> 20} MiB "
                f"(about 10 million samples; reading one takes ~10x its size in memory): split the capture")
    try:
        with open(path, "rb") as fh:
            head = fh.read(SNIFF_BYTES)
    except OSError as err:
        return f"cannot be read: {err.strerror}"
    if head and head.count(0) > len(head) // 2:
        return (f"binary content: {head.count(0)} of its first {len(head)} bytes are NUL (a sparse or zeroed "
                f"file, not a CSV capture)")
    return None
