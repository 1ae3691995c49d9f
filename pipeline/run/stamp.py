"""``pdr run``'s incremental cache: what a recording's outputs were made from, and whether they still are.

Each run folder gets a ``stamp.json`` holding one key per recording, the hash
of (raw bytes, the bytes of every rig TOML layer that applies, the code version
= hash of ``pipeline/**/*.py`` and ``schemas/*.json``).  A recording whose runs
all carry the current key and every declared output is skipped; deciding that
reads a few kilobytes per recording and imports nothing heavy.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from pipeline.config import config_layers_for
from pipeline.runs import SEGMENT_SUFFIX, RunPaths, glob_escape

PACKAGE_ROOT = Path(__file__).resolve().parent.parent
SCHEMA_ROOT = PACKAGE_ROOT.parent / "schemas"


@dataclass(frozen=True)
class Stage:
    name: str
    inputs: tuple[str, ...]         # RunPaths attributes read (ingest reads the raw file and its TOML layers)
    outputs: tuple[str, ...]        # RunPaths attributes written


# the stages pdr run chains, with the RunPaths attributes each reads and writes: a recording counts as done
# only when every declared output exists, and the runner never needs to know a file name
STAGES = (
    Stage("ingest", (), ("signals", "mcap", "ingest_report", "rig_config")),
    Stage("derive", ("signals", "rig_config"), ("kinematics", "phases", "overshoot", "cycles", "summary")),
    Stage("validate", ("rig_config", "kinematics", "phases", "overshoot"),
          ("validation", "comparison", "rrd", "overview_png")),
)


def declared_outputs(paths: RunPaths) -> list[Path]:
    return [getattr(paths, name) for stage in STAGES for name in stage.outputs]


def sha256_file(path: Path) -> str:
    """Hash of a file read in blocks (a raw capture can be hundreds of megabytes)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def code_version() -> str:
    """Hash of the pipeline's source and schemas: any code change re-runs every recording."""
    h = hashlib.sha256()
    files = sorted(PACKAGE_ROOT.rglob("*.py")) + sorted(SCHEMA_ROOT.glob("*.json"))
    for path in files:
        h.update(str(path.relative_to(PACKAGE_ROOT.parent)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


@dataclass(frozen=True)
class Stamp:
    """What a recording's outputs were made from."""

    recording: str                      # raw file name
    raw_dir: str                        # resolved raw folder
    raw_sha256: str
    config_layers: dict[str, str]       # TOML path -> sha256
    code_version: str

    @property
    def key(self) -> str:
        blob = json.dumps([self.recording, self.raw_sha256, sorted(self.config_layers.items()),
                           self.code_version])
        return hashlib.sha256(blob.encode()).hexdigest()[:24]

    def to_json(self, runs: list[str]) -> dict:
        return {"recording": self.recording, "raw_dir": self.raw_dir, "raw_sha256": self.raw_sha256,
                "config_layers": self.config_layers, "code_version": self.code_version, "key": self.key,
                "runs": runs, "stages": [s.name for s in STAGES]}


def stamp_for(csv: Path, code: str) -> Stamp:
    """The stamp of a recording as it is now (raises ``OSError`` when a file cannot be read)."""
    layers = {str(p): sha256_file(p) for p in config_layers_for(csv)}
    return Stamp(recording=csv.name, raw_dir=str(csv.parent.resolve()), raw_sha256=sha256_file(csv),
                 config_layers=layers, code_version=code)


def candidate_runs(processed: Path, csv: Path) -> list[Path]:
    """Folders that may hold this recording's runs: ``<stem>`` and ``<stem>-segN``."""
    stem = csv.stem
    found = [processed / stem] if (processed / stem).is_dir() else []
    found += [p for p in processed.glob(f"{glob_escape(stem)}-seg*") if SEGMENT_SUFFIX.fullmatch(p.name[len(stem):])]
    return found


def read_stamp(run_dir: Path) -> dict | None:
    try:
        return json.loads((run_dir / "stamp.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def previous_runs(processed: Path, csv: Path) -> list[str]:
    """Runs the last successful processing of this recording produced (from their stamps)."""
    runs: set[str] = set()
    for d in candidate_runs(processed, csv):
        s = read_stamp(d)
        if s and s.get("recording") == csv.name:
            runs.update(s.get("runs", []))
    return sorted(runs)


def up_to_date(processed: Path, csv: Path, stamp: Stamp) -> bool:
    """All runs of the recording exist, carry the current key, and hold every stage's declared outputs."""
    runs = previous_runs(processed, csv)
    if not runs:
        return False
    for name in runs:
        paths = RunPaths(processed / name)
        s = read_stamp(paths.root)
        if s is None or s.get("key") != stamp.key or not all(p.is_file() for p in declared_outputs(paths)):
            return False
    return True


def withdraw(processed: Path, runs: list[str]) -> int:
    """A recording that failed: its old stamps and validations no longer describe its raw file.
    Returns how many files were removed."""
    removed = 0
    for name in runs:
        paths = RunPaths(processed / name)
        for f in (paths.stamp, paths.validation):
            if f.is_file():
                f.unlink(missing_ok=True)
                removed += 1
    return removed


def prune_orphans(processed: Path, raw: Path, present: set[str]) -> list[str]:
    """Remove runs whose stamp names a recording of this raw folder that is no longer in it (``present``:
    the names of every recording entry, refused ones included: those are withdrawn, not deleted)."""
    raw_dir = str(raw.resolve())
    removed = []
    for d in sorted(p for p in processed.iterdir() if p.is_dir() and not p.name.startswith(".")):
        s = read_stamp(d)
        if s and s.get("raw_dir") == raw_dir and s.get("recording") not in present:
            shutil.rmtree(d, ignore_errors=True)
            removed.append(d.name)
    return removed
