"""The raw folder as ``pdr run`` sees it: the recordings to process, and every entry it refuses, with why.

A raw folder is written by people and tools: it may hold a directory named
``x.csv``, a dangling symlink or a loop, a FIFO (opening it would block
forever), a link to ``/dev/zero`` (reading it would never end), a name that is
not UTF-8, or two names that differ only in case.  Each such entry is refused
here with one line, without opening it, and the others are processed.
Only ``stat`` is called, never ``open``: a refusal costs no I/O.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.errors import PdrError
from pipeline.io.files import regular_file_problem
from pipeline.runs import check_recording_name

RECORDING_SUFFIX = ".csv"           # matched case-insensitively: X.CSV is a recording too
COMPANION_SUFFIXES = (".toml", ".md", ".txt", ".json")   # rig layers, thresholds, notes: not recordings


@dataclass
class RawFolder:
    recordings: list[Path] = field(default_factory=list)        # regular files, sorted by name
    refused: dict[str, str] = field(default_factory=dict)       # entry name -> the one-line reason
    ignored: list[str] = field(default_factory=list)            # other files (.mat, .xlsx, ...): not recordings


def scan_raw(raw: Path) -> RawFolder:
    """Sort the entries of ``raw/`` into recordings, refusals and other files (hidden entries are left out)."""
    out = RawFolder()
    try:
        names = sorted(os.listdir(raw))
    except OSError as err:
        raise PdrError(f"cannot list the raw folder: {err.strerror}", path=raw) from None
    seen: dict[str, str] = {}       # casefolded stem -> entry name
    # of names that differ only in case, the one ending in a lowercase ".csv" is taken first
    names.sort(key=lambda name: (not name.endswith(RECORDING_SUFFIX), name))
    for name in names:
        if name.startswith("."):
            continue
        path = raw / name
        if not name.lower().endswith(RECORDING_SUFFIX):
            if not name.lower().endswith(COMPANION_SUFFIXES) and not os.path.isdir(path):
                out.ignored.append(name)
            continue
        stem = name[:-len(RECORDING_SUFFIX)]
        problem = regular_file_problem(path)
        if problem is None:
            try:
                check_recording_name(stem, path)
            except PdrError as err:
                problem = err.detail
        if problem is None and stem.casefold() in seen:
            problem = f"its run name collides with {seen[stem.casefold()]} (names differ only in case); rename one"
        if problem is not None:
            out.refused[name] = problem
            continue
        seen[stem.casefold()] = name
        out.recordings.append(path)
    out.recordings.sort()
    out.refused = dict(sorted(out.refused.items()))
    return out
