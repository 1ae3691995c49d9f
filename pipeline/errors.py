"""The one error type users see.

Every refusal in the pipeline (bad raw file, bad TOML key, schema violation, a
recording a stage cannot work on) is a ``PdrError`` whose message names the
file, line or key and what was expected.  The CLI prints it on one line and
exits non-zero; anything else escaping is a bug in pdr, not in the input.
"""

from __future__ import annotations

from pathlib import Path


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
        super().__init__((", ".join(where) + ": " if where else "") + message)


class ConfigError(PdrError):
    """A rig TOML that cannot be used (unknown key, wrong type, wrong sign)."""


class IngestError(PdrError):
    """A raw recording that cannot be read."""


class SchemaError(PdrError):
    """A table that violates its schema in ``schemas/``."""
