"""A small Python API for notebooks: the pipeline's results and its model without the command line.

    from pipeline import api
    run = api.load_run("paper_clean")                 # one processed run: tables, summary, validation, config
    runs = api.load_runs()                            # every processed run, by name
    kin = api.concat(runs, "kinematics")              # one table, with a ``run`` column
    sim = api.simulate_rig({"backlash": {"gap": 0.08}}, duration=10.0)    # the model alone
    rec = api.record_rig({"backlash": {"gap": 0.08}}, seed=11)            # the virtual rig, through ingest
    found = api.discover_frame(rec)                   # what is the model missing?

Everything here calls the stages' own functions (the same code ``pdr`` runs), so a figure
computed in a notebook is the figure in ``processed/``.  Nothing here writes to ``processed/``.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline.config import RigConfig, default_config, resolve_config
from pipeline.errors import PdrError
from pipeline.model.effects import Effect, make_effect

TABLES = ("signals", "kinematics", "phases", "overshoot", "cycles", "comparison")
Effects = Mapping[str, Mapping[str, float]]          # {"backlash": {"gap": 0.08}, ...} as in a TOML [effects]


@dataclass(frozen=True)
class Run:
    """One processed run as the stages left it; a table or document a stage did not write is None."""

    name: str
    root: Path
    config: RigConfig
    signals: pd.DataFrame | None
    kinematics: pd.DataFrame | None
    phases: pd.DataFrame | None
    overshoot: pd.DataFrame | None
    cycles: pd.DataFrame | None
    comparison: pd.DataFrame | None
    summary: dict[str, Any] | None          # derive's summary.json
    validation: dict[str, Any] | None       # validate's validation.json


def _json(path: Path) -> dict | None:
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


def load_run(run: str | Path, processed: str | Path = "processed") -> Run:
    """A run by name (in ``processed``) or by its folder."""
    from pipeline.io.atomic import read_parquet
    from pipeline.runs import RunPaths, load_config, run_paths

    folder = Path(run)
    paths = RunPaths(folder) if folder.is_dir() else run_paths(Path(processed), str(run))
    if not paths.rig_config.is_file():
        raise PdrError("not a processed run (no rig.json): run `pdr run` or give the run's folder", path=paths.root)
    tables = {name: read_parquet(getattr(paths, name)) if getattr(paths, name).is_file() else None
              for name in TABLES}
    return Run(name=paths.name, root=paths.root, config=load_config(paths), **tables,
               summary=_json(paths.summary), validation=_json(paths.validation))


def load_runs(processed: str | Path = "processed") -> dict[str, Run]:
    """Every processed run in ``processed``, by name, sorted."""
    from pipeline.validate.gate import run_dirs

    return {p.name: load_run(p) for p in run_dirs(Path(processed))}


def concat(runs: Mapping[str, Run], table: str = "kinematics") -> pd.DataFrame:
    """One of ``TABLES`` of every run stacked, with a leading ``run`` column (runs without it are left out)."""
    if table not in TABLES:
        raise PdrError(f"unknown table, expected one of {', '.join(TABLES)}", key=table)
    parts = [getattr(r, table).assign(run=name) for name, r in runs.items() if getattr(r, table) is not None]
    if not parts:
        return pd.DataFrame({"run": pd.Series(dtype=str)})
    out = pd.concat(parts, ignore_index=True)
    return out[["run", *[c for c in out.columns if c != "run"]]]


def _effects(effects: Effects | None) -> tuple[Effect, ...]:
    return tuple(make_effect(name, dict(params)) for name, params in (effects or {}).items())


def _config(config: RigConfig | str | Path | None) -> RigConfig:
    if config is None:
        return default_config()
    if isinstance(config, RigConfig):
        return config
    return resolve_config([Path(config)])


def simulate_rig(effects: Effects | None = None, *, duration: float = 24.95,
                 config: RigConfig | str | Path | None = None) -> pd.DataFrame:
    """The hybrid model alone, closed loop from rest, sampled every control period: one row per sample
    (t_s, theta_rad, omega_rad_s, current_a as the sensor would read it, dir)."""
    from pipeline.model.simulate import simulate

    spec = _config(config).plant_spec(_effects(effects))
    r = simulate(spec, duration=duration)
    return pd.DataFrame({"t_s": r.t, "theta_rad": r.theta, "omega_rad_s": r.omega,
                         "current_a": r.current_measured, "dir": r.dir.astype("int8")})


def record_rig(effects: Effects | None = None, *, seed: int = 0, duration: float = 24.95,
               config: RigConfig | None = None) -> pd.DataFrame:
    """A virtual-rig recording (sensor noise, encoder counts, ADC, millis() jitter) with hidden ``effects``,
    read back by the ingest stage: its signals table (schemas/signals.json)."""
    from pipeline.ingest.stage import ingest_recording
    from pipeline.rig.recording import RigSetup, make_recording, write_recording

    setup = RigSetup(effects=_effects(effects), config=config or default_config(), duration_s=duration)
    with tempfile.TemporaryDirectory(prefix="pdr-api-") as tmp:
        write_recording(make_recording(setup, seed=seed), Path(tmp) / "raw", "rec")
        result = ingest_recording(Path(tmp) / "raw" / "rec.csv", Path(tmp) / "processed", config=setup.config)
        return result.tables[result.runs[0].name]


@dataclass(frozen=True)
class Found:
    """What discovery says: the verdict, the effects added (name -> parameters) and the whole JSON."""

    verdict: str
    effects: dict[str, dict[str, float]]
    report: dict[str, Any]        # the object ``pdr discover --json`` prints


def discover_frame(df: pd.DataFrame, config: RigConfig | str | Path | None = None, *,
                   name: str = "notebook") -> Found:
    """Discovery on a table: a signals table (t_s, theta_rad, [current_a], [dir]), derived here first,
    or a kinematics table (with omega_rad_s) used as it is.  ``config``: the rig believed in."""
    from pipeline.derive.stage import derive_tables
    from pipeline.discover.stage import discover, discovery_json

    cfg = _config(config)
    for col in ("t_s", "theta_rad"):
        if col not in df.columns:
            raise PdrError(f"expected column '{col}' (schemas/signals.json)", key=col)
    kin = df if "omega_rad_s" in df.columns else derive_tables(df, cfg).kinematics
    d = discover(kin, cfg, name)
    doc = json.loads(json.dumps(discovery_json(d, name), default=float))
    return Found(verdict=d.verdict, effects={e.name: dict(e.parameters) for e in d.effects}, report=doc)
