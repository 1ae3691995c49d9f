"""What the sketch's source declares, read from firmware/pdr_logger/pdr_logger.ino: its settings block and
the rig TOML its comment gives, so the tests hold the two against each other and use the TOML as a user
would (the sketch is the one source of both)."""

from __future__ import annotations

import math
import re

from tests.firmware.toolchain import SKETCH_DIR

SKETCH = SKETCH_DIR / "pdr_logger.ino"
_SETTING = re.compile(r"^static const \w+ ([A-Z_]+) = ([^;]+);", re.M)


def settings() -> dict[str, str]:
    """The sketch's ``static const`` settings, name -> the literal as written."""
    return dict(_SETTING.findall(SKETCH.read_text(encoding="utf-8")))


def number(name: str) -> float:
    """A numeric setting (a C literal such as 6533.12f or 115200)."""
    return float(settings()[name].rstrip("fFuUlL"))


def first_dir() -> int:
    """FIRST_DIR as the model's dir0: 1 (q1) or -1 (q2)."""
    return {"PDR_DIR_Q1": 1, "PDR_DIR_Q2": -1}[settings()["FIRST_DIR"]]


def toml_text() -> str:
    """The matching raw/<name>.toml, as the sketch's comment gives it."""
    text = SKETCH.read_text(encoding="utf-8")
    block = text[text.index("The matching raw/<name>.toml:"):text.index("Change a setting here")]
    return "\n".join(line.strip().removeprefix("*").strip() for line in block.splitlines()[1:]).strip() + "\n"


def guard_counts(guard_rad: float, counts_per_rev: float) -> int:
    """The sketch's GUARD_COUNTS for a TOML's guard: the smallest count whose angle (counts * 2 pi /
    counts_per_rev, derive's conversion) reaches it, so both reverse on the same samples."""
    count_rad = 2 * math.pi / counts_per_rev
    n = math.ceil(guard_rad / count_rad)
    while (n - 1) * count_rad >= guard_rad:
        n -= 1
    while n * count_rad < guard_rad:
        n += 1
    return n
