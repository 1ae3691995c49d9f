"""Console output shared by ``pdr run``, ``pdr validate`` and ``pdr gate`` (rich only: cheap to import)."""

from __future__ import annotations

import sys


def wide_console(stderr: bool = True):
    """A rich console that does not squeeze tables to 80 columns when writing to a file or CI log."""
    from rich.console import Console

    stream = sys.stderr if stderr else sys.stdout
    return Console(stderr=stderr, width=None if stream.isatty() else 140)
