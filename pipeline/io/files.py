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
