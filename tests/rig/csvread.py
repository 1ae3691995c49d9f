"""A tiny strict reader for the rig's captures in tests (independent of the ingest stage)."""

from __future__ import annotations

import re

IDE = re.compile(r"^\d{1,2}:\d{1,2}:\d{1,2}\.\d{3} -> ")


def lines_of(data: bytes) -> list[str]:
    """Physical lines, BOM and IDE prefixes removed, CR/LF endings dropped."""
    text = data.decode("utf-8")
    if text.startswith("\ufeff"):
        text = text[1:]
    return [IDE.sub("", ln) for ln in text.replace("\r\n", "\n").split("\n")[:-1]]


def as_row(line: str, width: int = 4) -> list[int] | None:
    """The integers of a well-formed data line, or None."""
    parts = line.split(",")
    if len(parts) != width or not all(re.fullmatch(r"-?\d+", p) for p in parts):
        return None
    return [int(p) for p in parts]
