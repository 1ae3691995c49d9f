"""Shared by the cluster tests: virtual-rig recordings, and the comparison of two processed folders."""

from __future__ import annotations

import subprocess
from pathlib import Path

from pipeline.rig.recording import RigSetup, make_recording, write_recording
from pipeline.validate.rerun_log import rerun_executable

CODE = "pinned"       # the stamps' code version: the shared source tree may change under a test


def make_raw(raw: Path, count: int, first_seed: int = 500) -> list[str]:
    """``count`` clean virtual-rig recordings ``r000.csv``... (with their TOML) in ``raw``."""
    raw.mkdir(parents=True, exist_ok=True)
    names = []
    for i in range(count):
        name = f"r{i:03d}"
        write_recording(make_recording(RigSetup(), seed=first_seed + i), raw, name)
        names.append(name)
    return names


def output_files(processed: Path) -> list[str]:
    """Every file under ``processed`` (relative), temporary files included, the lock excluded."""
    return sorted(str(p.relative_to(processed)) for p in processed.rglob("*") if p.is_file() and p.name != ".pdr.lock")


def differences(a: Path, b: Path) -> list[str]:
    """Files that differ between two processed folders: bytes, and ``.rrd`` by ``rerun rrd compare``
    (a Rerun recording holds random chunk and row ids, so its bytes differ between any two runs)."""
    files_a, files_b = output_files(a), output_files(b)
    out = [f"only in one: {sorted(set(files_a) ^ set(files_b))}"] if files_a != files_b else []
    for rel in sorted(set(files_a) & set(files_b)):
        if rel.endswith(".rrd"):
            proc = subprocess.run([rerun_executable(), "rrd", "compare", str(a / rel), str(b / rel)],
                                  capture_output=True)
            if proc.returncode != 0:
                out.append(f"{rel}: rerun rrd compare exit {proc.returncode}")
        elif (a / rel).read_bytes() != (b / rel).read_bytes():
            out.append(f"{rel}: bytes differ")
    return out
