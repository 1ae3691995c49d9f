"""What a recording may be called: the one naming rule, and how any name is shown.

A recording's name (``raw/<name>.csv``; ``pdr record --name NAME``) becomes a run folder, file names
inside it, a row of ``processed/summary.csv``, a partition ``run=<name>`` of ``processed/dataset`` and
words in terminal lines.  Each of those breaks on some names: a control character rewrites the
terminal or splits a table row, ``%`` is decoded by Hive-partition readers (``x%2Fy`` reads back as
``x/y``), a leading ``.`` hides the folder, and two spellings of one name (case, or Unicode NFC/NFD:
``é`` as one code point or as ``e`` + accent) give two folders that look the same.  So:

A recording name is valid UTF-8, 1 to ``MAX_STEM_BYTES`` bytes, does not start with ``.``, holds no
control or format character (Unicode categories Cc, Cf, Zl, Zp) and no ``%``, is not one of pdr's
own entries in ``processed/`` and does not end in ``-seg<N>`` (the segments of a recording whose
board reset).  Of two names equal once case-folded and NFC-normalised, the second is refused.
"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

from pipeline.errors import PdrError, printable, unshown

RULE = ("a recording name is 1 to 200 bytes of UTF-8, does not start with '.', and holds no control "
        "character, no '%' and no path separator")
DISCOVERY_DIR = "discovery"             # processed/discovery/<run>/: pdr discover's default output
SUMMARY_CSV = "summary.csv"             # processed/summary.csv: one row per run
DATASET_DIR = "dataset"                 # processed/dataset/<table>/run=<run>/: every run as one dataset
RESERVED_NAMES = (DISCOVERY_DIR, SUMMARY_CSV, DATASET_DIR)
SEGMENT_SUFFIX = re.compile(r"-seg[0-9]+$")
# A run's longest file name is ".<run>.mcap.<pid>.<n>.tmp" (an atomic write's temporary): with up to
# 40 bytes for the rest and "-segNNNN", a stem of 200 bytes stays within the usual 255-byte limit.
MAX_STEM_BYTES = 200
def name_problem(stem: str) -> str | None:
    """What is wrong with ``stem`` as a recording name (the rule above, in words), or None."""
    try:
        size = len(stem.encode("utf-8"))
    except UnicodeEncodeError:
        return "the file name is not valid UTF-8; rename it (run names are UTF-8 folder names)"
    if size > MAX_STEM_BYTES:
        return (f"the file name is {size} bytes long, expected at most {MAX_STEM_BYTES} before '.csv' "
                f"(its outputs' names must fit the file system); rename it")
    if not stem:
        return f"the name before '.csv' is empty; rename it ({RULE})"
    if stem.startswith("."):
        return (f"'{printable(stem)}' starts with '.': hidden names are reserved for pdr's own entries in "
                f"processed/ (the lock); rename it ({RULE})")
    if stem.casefold() in RESERVED_NAMES:
        return (f"'{stem}' is reserved for pdr's own entries in processed/ ({', '.join(RESERVED_NAMES)}); "
                f"rename the recording")
    bad = next((ch for ch in stem if unshown(ch)), None)
    if bad is not None:
        return (f"the name holds the control character {bad.encode('unicode_escape').decode('ascii')}; "
                f"rename it ({RULE})")
    if "/" in stem or "\\" in stem:
        return f"'{printable(stem)}' holds a path separator: a name is one file name; rename it ({RULE})"
    if "%" in stem:
        return f"the name holds '%', which dataset readers decode (x%2Fy reads as x/y); rename it ({RULE})"
    if SEGMENT_SUFFIX.search(stem):
        return ("names ending in -seg<N> are reserved for the segments of a recording whose board "
                "reset; rename the recording")
    return None


def check_recording_name(stem: str, path: str | Path) -> None:
    """Refuse, naming the file, a recording stem that is not a usable, unique run name."""
    problem = name_problem(stem)
    if problem is not None:
        raise PdrError(problem, path=path)


def twin_key(stem: str) -> str:
    """Names with the same key look alike (case, NFC/NFD): one folder each would be two of one name."""
    return unicodedata.normalize("NFC", stem).casefold()


def later_twins(paths: list[Path]) -> dict[Path, Path]:
    """Each path whose recording name (its stem, up to ``twin_key``) an earlier path already has -> that
    path: ``pdr ingest a/x.csv b/x.csv`` would write both into ``processed/x``."""
    first: dict[str, Path] = {}
    out: dict[Path, Path] = {}
    for path in paths:
        key = twin_key(Path(path).stem)
        if key in first:
            out[path] = first[key]
        else:
            first[key] = path
    return out
