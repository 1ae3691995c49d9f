"""Small helpers shared by the ingest tests: a config from TOML text, ingest of bytes."""

from __future__ import annotations

from pathlib import Path

from pipeline.config import RigConfig, default_config, resolve_config
from pipeline.ingest.stage import ingest_capture

CLEAN = (b"t_ms,counts,adc,dir\n"
         b"0,0,511,0\n50,0,512,0\n100,0,511,0\n150,0,510,0\n"
         b"200,3,530,1\n250,12,545,1\n300,30,550,1\n350,55,549,1\n400,80,548,-1\n450,90,480,-1\n")


def config_from_toml(tmp_path: Path, text: str, name: str = "rig.toml") -> RigConfig:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return resolve_config([path])


def ingest(data: bytes, cfg: RigConfig | None = None, stem: str = "rec"):
    """(runs, report) of the pure stage on bytes."""
    return ingest_capture(data, cfg or default_config(), "rec.csv", stem)


def quarantined_lines(report: dict) -> list[int]:
    return [q["line"] for q in report["quarantined"]]


def without_columns(data: bytes, *names: bytes) -> bytes:
    """A capture with the named columns taken out of its header and every row (a sketch that logs fewer)."""
    header, *body = data.splitlines(keepends=True)
    fields = header.rstrip(b"\r\n").split(b",")
    keep = [j for j, f in enumerate(fields) if f not in names]
    out = []
    for line in (header, *body):
        values = line.rstrip(b"\r\n").split(b",")
        out.append(b",".join(values[j] for j in keep) + b"\n")
    return b"".join(out)
