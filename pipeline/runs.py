"""Where each stage reads and writes: the layout of ``processed/<run>/``, defined once.

A run is one logging segment of one raw recording.  A file with a single
segment gives the run ``<stem>``; a file in which the board reset gives
``<stem>-seg1``, ``<stem>-seg2``, ... (see the ingest report).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.config import RigConfig, config_from_dict


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
    # run.py's incremental cache
    @property
    def stamp(self) -> Path: return self.root / "stamp.json"


def run_paths(processed: Path, run: str) -> RunPaths:
    return RunPaths(Path(processed) / run)


if TYPE_CHECKING:  # pandas is imported lazily: `pdr run` with nothing to do must start fast
    import pandas as pd


def load_signals(paths: RunPaths) -> pd.DataFrame:
    from pipeline.io.atomic import read_parquet

    return read_parquet(paths.signals)


def load_config(paths: RunPaths) -> RigConfig:
    """The rig configuration resolved at ingest time (stored so later stages never re-read TOML)."""
    data = json.loads(paths.rig_config.read_text(encoding="utf-8"))
    return config_from_dict(data["config"], source=str(paths.rig_config))


def resolve_runs(recording: str | Path, processed: Path) -> list[RunPaths]:
    """The processed runs a user means by RECORDING: a processed run folder, a run name, or a raw CSV path
    (its runs ``<stem>`` or ``<stem>-seg1``, ``-seg2``, ...).  Refuses, naming it, when nothing matches."""
    from pipeline.errors import PdrError

    item = Path(recording)
    if item.is_dir():
        return [RunPaths(item)]
    if item.suffix.lower() == ".csv":
        stem = item.stem
        segs = sorted((p for p in Path(processed).glob(f"{stem}-seg*") if p.name[len(stem) + 4:].isdigit()),
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
