"""The raw folder as ``pdr run`` sees it: the recordings to process, and every entry it refuses, with why.

A raw folder is written by people and tools: it may hold a directory named
``x.csv``, a dangling symlink or a loop, a FIFO (opening it would block
forever), a link to ``/dev/zero`` (reading it would never end), a name that is
not UTF-8 or breaks the naming rule (``pipeline.names``), or two names that differ only in
case or Unicode normalisation.  Each such entry is refused
here with one line, without opening it, and the others are processed.
Only ``stat`` is called on what is not a regular file, never ``open``; a regular file is judged by
its size and its first bytes (``io.files.recording_file_problem``), never read whole here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.errors import PdrError
from pipeline.io.files import recording_file_problem
from pipeline.names import check_recording_name, printable, twin_key

RECORDING_SUFFIX = ".csv"           # matched case-insensitively: X.CSV is a recording too
COMPANION_SUFFIXES = (".toml", ".md", ".txt", ".json")   # rig layers, thresholds, notes: not recordings


@dataclass
class RawFolder:
    recordings: list[Path] = field(default_factory=list)        # regular files, sorted by name
    refused: dict[str, str] = field(default_factory=dict)       # entry name -> the one-line reason
    ignored: list[str] = field(default_factory=list)            # other files (.mat, .xlsx, ...): not recordings


def scan_raw(raw: Path) -> RawFolder:
    """Sort the entries of ``raw/`` into recordings, refusals and other files.  Hidden entries are left
    out (``._x.csv``: a Mac's resource fork), but for ``.csv``, ``..csv``: a recording without a name,
    refused with a word rather than skipped unseen."""
    out = RawFolder()
    try:
        names = sorted(os.listdir(raw))
    except OSError as err:
        raise PdrError(f"cannot list the raw folder: {err.strerror}", path=raw) from None
    seen: dict[str, str] = {}       # twin_key(stem) -> entry name
    # of names that differ only in case, the one ending in a lowercase ".csv" is taken first
    names.sort(key=lambda name: (not name.endswith(RECORDING_SUFFIX), name))
    for name in names:
        nameless = name.lower().endswith(RECORDING_SUFFIX) and not name[:-len(RECORDING_SUFFIX)].strip(".")
        if name.startswith(".") and not nameless:
            continue
        path = raw / name
        if not name.lower().endswith(RECORDING_SUFFIX):
            if not name.lower().endswith(COMPANION_SUFFIXES) and not os.path.isdir(path):
                out.ignored.append(name)
            continue
        stem = name[:-len(RECORDING_SUFFIX)]
        problem = recording_file_problem(path)
        if problem is None:
            try:
                check_recording_name(stem, path)
            except PdrError as err:
                problem = err.detail
        if problem is None and twin_key(stem) in seen:
            problem = (f"its run name collides with {printable(seen[twin_key(stem)])} (the names differ only in case "
                       f"or Unicode normalisation, and look alike); rename one")
        if problem is not None:
            out.refused[name] = problem
            continue
        seen[twin_key(stem)] = name
        out.recordings.append(path)
    out.recordings.sort()
    out.refused = dict(sorted(out.refused.items()))
    return out
