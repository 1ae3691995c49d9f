"""Where each stage reads and writes: the layout of ``processed/<run>/``, defined once.

A run is one logging segment of one raw recording.  A file with a single
segment gives the run ``<stem>``; a file in which the board reset gives
``<stem>-seg1``, ``<stem>-seg2``, ... (see the ingest report).

Run names are unique by construction: what a recording may be called is
``pipeline.names`` (the one naming rule); two recordings whose stems differ
only in case or Unicode normalisation are told apart by the raw-folder scan
(``pipeline.run.recordings``).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.config import RigConfig, config_from_dict
from pipeline.errors import PdrError
from pipeline.names import (DATASET_DIR, DISCOVERY_DIR, MAX_STEM_BYTES, RESERVED_NAMES, SEGMENT_SUFFIX,  # noqa: F401
                            SUMMARY_CSV, check_recording_name, name_problem, printable)



def check_name(name: str) -> str:
    """A name pdr gives a new recording (``pdr record --name``, the virtual rig): the one rule every
    recording in raw/ is held to (``names.name_problem``)."""
    problem = name_problem(name)
    if problem is not None:
        raise PdrError(problem, key="NAME")
    return name


LOCK_NAME = ".pdr.lock"                 # processed/.pdr.lock: the lock every writing command holds


def segment_run_name(stem: str, k: int) -> str:
    """The run of a recording's ``k``-th kept segment (1-based) when the board reset."""
    return f"{stem}-seg{k}"


def glob_escape(text: str) -> str:
    """``text`` matched literally by ``Path.glob`` (a recording may be named ``run[1].csv``)."""
    return "".join(f"[{c}]" if c in "*?[" else c for c in text)


@dataclass(frozen=True)
class RunPaths:
    root: Path          # processed/<run>

    @property
    def name(self) -> str:
        return self.root.name

    # ingest
    @property
    def signals(self) -> Path: return self.root / "signals.parquet"
    @property
    def mcap(self) -> Path: return self.root / f"{self.name}.mcap"
    @property
    def ingest_report(self) -> Path: return self.root / "ingest_report.json"
    @property
    def rig_config(self) -> Path: return self.root / "rig.json"
    # derive
    @property
    def kinematics(self) -> Path: return self.root / "kinematics.parquet"
    @property
    def phases(self) -> Path: return self.root / "phases.parquet"
    @property
    def overshoot(self) -> Path: return self.root / "overshoot.parquet"
    @property
    def cycles(self) -> Path: return self.root / "cycles.parquet"
    @property
    def summary(self) -> Path: return self.root / "summary.json"
    # validate
    @property
    def validation(self) -> Path: return self.root / "validation.json"
    @property
    def comparison(self) -> Path: return self.root / "comparison.parquet"
    @property
    def comparison_mcap(self) -> Path: return self.root / "comparison.mcap"
    @property
    def rrd(self) -> Path: return self.root / f"{self.name}.rrd"
    @property
    def overview_png(self) -> Path: return self.root / "overview.png"
    # pdr run's incremental cache (run/stamp.py)
    @property
    def stamp(self) -> Path: return self.root / "stamp.json"


def run_paths(processed: Path, run: str) -> RunPaths:
    return RunPaths(Path(processed) / run)


if TYPE_CHECKING:  # pandas is imported lazily: `pdr run` with nothing to do must start fast
    import pandas as pd


def load_signals(paths: RunPaths) -> pd.DataFrame:
    from pipeline.io.atomic import read_parquet

    return read_parquet(paths.signals)


def ingest_segment(paths: RunPaths) -> dict:
    """This run's entry among its ingest report's segments (index, current zero, wall clock, ...);
    {} when the report cannot be read: what it tells is context, never needed to go on."""
    try:
        report = json.loads(paths.ingest_report.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    segments = report.get("segments", []) if isinstance(report, dict) else []
    return next((seg for seg in segments if isinstance(seg, dict) and seg.get("run") == paths.name), {})


def load_config(paths: RunPaths) -> RigConfig:
    """The rig configuration resolved at ingest time (stored so later stages never re-read TOML)."""
    data = json.loads(paths.rig_config.read_text(encoding="utf-8"))
    return config_from_dict(data["config"], source=str(paths.rig_config))


def config_sources(paths: RunPaths) -> dict[str, str]:
    """Where each setting of the run's rig configuration came from ("section.key" -> "default" or a
    TOML path), as stored at ingest; empty when the file does not say."""
    try:
        data = json.loads(paths.rig_config.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    sources = data.get("sources") if isinstance(data, dict) else None
    return sources if isinstance(sources, dict) else {}


def resolve_runs(recording: str | Path, processed: Path) -> list[RunPaths]:
    """The processed runs a user means by RECORDING: a processed run folder, a run name, or a raw CSV path
    (its runs ``<stem>`` or ``<stem>-seg1``, ``-seg2``, ...).  Refuses, naming it, when nothing matches."""
    item = Path(recording)
    if item.name in RESERVED_NAMES or item.name.startswith("."):
        raise PdrError(f"'{item.name}' is one of pdr's own entries, not a run", path=str(recording))
    if item.is_dir():
        return [RunPaths(item)]
    if item.suffix.lower() == ".csv":
        stem = item.stem
        matches = Path(processed).glob(f"{glob_escape(stem)}-seg*")
        segs = sorted((p for p in matches if p.name[len(stem) + 4:].isdigit()),
                      key=lambda p: int(p.name[len(stem) + 4:]))
        found = ([Path(processed) / stem] if (Path(processed) / stem).is_dir() else []) + segs
        if not found:
            raise PdrError(f"no processed run for this recording in {processed}/: run `pdr ingest` on it first",
                           path=item)
        return [RunPaths(p) for p in found]
    if (Path(processed) / str(recording)).is_dir():
        return [RunPaths(Path(processed) / str(recording))]
    raise PdrError(f"expected a processed run folder, a run name in {processed}/ or a raw .csv path",
                   path=str(recording))
