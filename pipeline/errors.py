"""The one error type users see.

Every refusal in the pipeline (bad raw file, bad TOML key, schema violation, a
recording a stage cannot work on) is a ``PdrError`` whose message names the
file, line or key and what was expected.  The CLI prints it on one line and
exits non-zero; anything else escaping is a bug in pdr, not in the input.
"""

from __future__ import annotations

import unicodedata
from pathlib import Path

_UNSHOWN = ("Cc", "Cf", "Zl", "Zp")     # control, format (bidi overrides), line and paragraph separators


def unshown(ch: str) -> bool:
    return unicodedata.category(ch) in _UNSHOWN


def printable(text: str | Path) -> str:
    """``text`` safe on one terminal line: bytes that are not UTF-8 as ``\\xff``, control and format
    characters (escape codes, newlines, tabs, bidi overrides) as ``\\x1b``, ``\\n``, ``\\u202e``."""
    text = str(text).encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    if not any(unshown(ch) for ch in text):
        return text
    return "".join(ch.encode("unicode_escape").decode("ascii") if unshown(ch) else ch for ch in text)


class PdrError(Exception):
    """A clear, user-facing refusal: ``<where>: <what was expected>``."""

    def __init__(self, message: str, *, path: str | Path | None = None,
                 line: int | None = None, key: str | None = None) -> None:
        self.path = str(path) if path is not None else None
        self.line = line
        self.key = key
        where = []
        if self.path:
            where.append(self.path + (f":{line}" if line is not None else ""))
        elif line is not None:
            where.append(f"line {line}")
        if key:
            where.append(f"key '{key}'")
        self.detail = message
        # a name's escape codes or newline never reach the terminal
        super().__init__(printable((", ".join(where) + ": " if where else "") + message))


class ConfigError(PdrError):
    """A rig TOML that cannot be used (unknown key, wrong type, wrong sign)."""


class IngestError(PdrError):
    """A raw recording that cannot be read."""


class SchemaError(PdrError):
    """A table that violates its schema in ``schemas/``."""


LOW_SPACE_BYTES = 1 << 20      # less free space than this beside the outputs: a failure is put down to a full disk


def describe_failure(err: BaseException, folder: str | Path | None = None) -> str:
    """One line for an exception a stage raised: the user's problem in words, or an internal error.

    A full or read-only disk surfaces from libraries in many shapes (``OSError``
    with ``ENOSPC``, Rerun's "File-writer thread shut down prematurely"); when the
    folder being written has less than ``LOW_SPACE_BYTES`` free, that is what the
    line says, naming the folder.
    """

    return str(err) if isinstance(err, PdrError) else printable(_described(err, folder))


def _described(err: BaseException, folder: str | Path | None) -> str:
    import errno
    import shutil

    if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"no space left on the device writing {err.filename or folder}"
    if folder is not None:
        try:
            if shutil.disk_usage(folder).free < LOW_SPACE_BYTES:
                return f"no space left on the device writing {folder} ({type(err).__name__}: {err})"
        except OSError:
            pass
    if isinstance(err, OSError) and err.strerror:
        return f"{err.filename}: {err.strerror}" if err.filename else err.strerror
    return f"internal error {type(err).__name__}: {err}"


def for_each(items, work, folder: str | Path | None = None) -> int:
    """``work(item)`` for every item; a failure is printed as one line on stderr and the rest still run.

    What the stage commands given several recordings do: every one they can,
    each failure reported, the count returned so the command exits non-zero
    at the end.
    """
    import sys

    failures = 0
    for item in items:
        try:
            work(item)
        except Exception as err:  # a bad input or a bug in pdr: never costs the other recordings
            failures += 1
            print(f"pdr: error: {describe_failure(err, folder)}", file=sys.stderr)
    return failures


def shown(value: object, limit: int = 60) -> str:
    """A config value as a message shows it: short, one line, and without converting what cannot be
    (a 400-digit integer is too large for a float, an array nested thousands deep for ``repr``)."""
    if isinstance(value, bool):
        return repr(value)
    if isinstance(value, int) and abs(value) >= 10 ** 18:
        return f"an integer of {len(str(abs(value)))} digits"        # the TOML reader holds at most 4300
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."
