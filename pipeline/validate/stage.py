"""The validate stage's shell: read a derived run, rerun the model, write the outputs.

``validate_run(paths)`` reads ``kinematics.parquet`` and the rig configuration
stored at ingest (``rig.json``), runs the pure comparison (``compare.py``) and
writes ``validation.json``, ``comparison.parquet``, ``comparison.mcap``
(Foxglove), ``<run>.rrd`` and ``overview.png`` into ``processed/<run>/``, each
atomically.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.config import RigConfig, resolve_config
from pipeline.errors import PdrError
from pipeline.io.atomic import read_parquet, write_json, write_parquet
from pipeline.model.effects import PlantSpec
from pipeline.runs import RunPaths, ingest_segment, load_config
from pipeline.derive.tables import schema_table
from pipeline.validate.compare import (comparison_table, compare, initial_state, possible_ways, settled_timing,
                                      simulate_both, timing_json)

ModelOverride = Path | str | RigConfig | PlantSpec | None


def finite_or_none(obj):
    """JSON has no NaN: undefined figures (e.g. no switches, so no period) become null."""
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def resolve_model(cfg: RigConfig, override: ModelOverride) -> tuple[PlantSpec, str]:
    """The plant to run and where it came from: the rig's [model]+[effects], or a model file/object."""
    if override is None:
        return cfg.plant_spec(), "rig configuration ([model] and [effects] stored at ingest)"
    if isinstance(override, PlantSpec):
        return override, "model given by the caller"
    if isinstance(override, RigConfig):
        return override.plant_spec(), "rig configuration given by the caller"
    path = Path(override)
    if not path.is_file():
        raise PdrError("model file not found (expected a TOML with [model] and/or [effects])", path=path)
    return resolve_config([path], base=cfg).plant_spec(), str(path)


def _model_json(spec: PlantSpec, source: str) -> dict:
    return {"source": source, "params": asdict(spec.params), "v_drive": spec.v_drive,
            "guard_rad": spec.guard_rad, "period_s": spec.period_s,
            "nonsmooth": {"Tc": spec.Tc, "gap": spec.gap, "Td": spec.Td, "I0": spec.I0},
            "torque": spec.torque}


def load_kinematics(paths: RunPaths) -> pd.DataFrame:
    if not paths.kinematics.is_file():
        raise PdrError("no kinematics.parquet: run the derive stage first (pdr derive or pdr run)",
                       path=paths.root)
    return checked_kinematics(read_parquet(paths.kinematics), paths)


def checked_kinematics(kin: pd.DataFrame, paths: RunPaths) -> pd.DataFrame:
    """The columns and rows validation needs, whether the table was read back or handed over by derive."""
    needed = ("t_s", "theta_rad", "omega_rad_s", "dir") if "theta_rad" in kin.columns else ("t_s", "current_a")
    missing = [c for c in needed if c not in kin.columns]       # without an encoder: the current, and what exists
    if missing:
        raise PdrError(f"kinematics table lacks column '{missing[0]}'", path=paths.kinematics)
    if len(kin) < 2:
        raise PdrError(f"kinematics table has {len(kin)} rows, at least 2 are needed to validate",
                       path=paths.kinematics)
    return kin


# The derive stage's tables shown in the viewer's statistics panel, with the columns worth reading there.
DERIVED_COLUMNS = {
    "phases": ("phase", "start_s", "duration_s", "mode", "peak_omega_rad_s", "peak_current_a",
               "theta_extreme_rad", "end_reason"),
    "overshoot": ("crossing", "direction", "trigger_t_s", "trigger_theta_rad", "overshoot_rad", "turn_delay_s",
                  "current_reversal_delay_s"),
}


def derived_tables(paths: RunPaths) -> dict[str, dict[str, np.ndarray]]:
    """Per-phase and per-crossing statistics of the derive stage, when it wrote them."""
    out = {}
    for key in DERIVED_COLUMNS:
        path = getattr(paths, key)
        if path.is_file():
            out[key] = read_parquet(path)
    return panel_tables(out)


def panel_tables(tables: dict[str, pd.DataFrame]) -> dict[str, dict[str, np.ndarray]]:
    """The first 40 rows of the columns worth reading in the viewer's statistics panel, column by column.

    Plain arrays, not DataFrames: a column selection plus ``head`` costs pandas
    3 about 2 ms per table, more than writing the panel.
    """
    return {key: {c: column(tables[key], c)[:40] for c in columns if c in tables[key].columns}
            for key, columns in DERIVED_COLUMNS.items() if key in tables}


def write_comparison(target: Path, table: pd.DataFrame) -> None:
    write_parquet(target, schema_table("comparison", table, where=str(target)))


def validate_run(paths: RunPaths, model_override: ModelOverride = None, *, rrd: bool = True,
                 png: bool = True, mcap: bool = True, derived: dict[str, pd.DataFrame] | None = None, verify: bool = True) -> dict:
    """Validate one derived run; returns the summary row (``summary_row``) plus ``timing_s``.

    ``derived``: the derive stage's tables just written for this run (keys
    ``kinematics``, ``phases``, ``overshoot``), handed over by ``pdr run`` so
    they are not read back from the Parquet files it has just written.
    ``verify=False`` leaves ``rerun rrd verify`` of the ``.rrd`` to the caller
    (``pdr run`` verifies a worker's files in one call before stamping them).
    """
    from pipeline.validate.mcap_log import write_comparison_mcap
    from pipeline.validate.plots import write_overview
    from pipeline.validate.rerun_log import write_rrd

    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    kin = load_kinematics(paths) if derived is None else checked_kinematics(derived["kinematics"], paths)
    cfg = load_config(paths)
    spec, source = resolve_model(cfg, model_override)
    t1 = time.perf_counter()
    try:
        ways = possible_ways(kin)
        switches, start = None, None
        if "replay" in ways:
            switches, start = settled_timing(kin, spec, np.pi / cfg.encoder.counts_per_rev)
        elif ways:
            start = initial_state(kin, spec)
        sims = simulate_both(spec, kin, start, switches)
    except ValueError as err:
        raise PdrError(f"the model cannot be simulated: {err}", path=paths.root) from None
    t2 = time.perf_counter()
    result = compare(kin, spec, sims)
    validation = finite_or_none({
        "run": paths.name, "model": _model_json(spec, source),
        "n_samples": int(len(kin)), "duration_s": float(kin["t_s"].iloc[-1] - kin["t_s"].iloc[0]),
        "dir_inferred": bool(kin["dir_inferred"].any()) if "dir_inferred" in kin.columns else False,
        "initial_state": start.to_json() if sims else None,
        "switch_timing": timing_json(kin, switches),
        **result,
    })
    t3 = time.perf_counter()
    write_json(paths.validation, validation)
    table = comparison_table(kin, sims)
    write_comparison(paths.comparison, table)
    if mcap:
        write_comparison_mcap(paths.comparison_mcap, paths.name, kin, table, validation["model"],
                              segment=ingest_segment(paths))
    t4 = time.perf_counter()
    if rrd:
        panels = derived_tables(paths) if derived is None else panel_tables(derived)
        write_rrd(paths.rrd, paths.name, kin, sims, validation, spec.guard_rad, panels, verify=verify,
                  period=spec.period_s)
    t5 = time.perf_counter()
    if png:
        write_overview(paths.overview_png, overview_title(paths.name, validation), kin, sims, spec.guard_rad)
    t6 = time.perf_counter()
    timing.update(load=t1 - t0, simulate=t2 - t1, metrics=t3 - t2, write_tables=t4 - t3, rrd=t5 - t4, png=t6 - t5)
    return {**summary_row(validation), "timing_s": timing}


_MSE_UNITS = {"theta": "rad²", "omega": "(rad/s)²", "current": "A²"}


def overview_title(run: str, validation: dict) -> str:
    """The overview's title: the run and the MSE of each way per signal, units once.

    Both ways, since the replay can be close while the closed loop, the model's
    own switching, is far off; one figure for both when they coincide."""
    if not validation.get("replay"):
        return f"{run}   not compared with the model (no angle, no dir): what was logged"
    units = ", ".join(_MSE_UNITS.values())

    def mses(way: str) -> str:
        signals = (validation.get(way) or {}).get("signals", {})
        return ", ".join("-" if (e := signals.get(sig)) is None or e["mse"] is None else f"{e['mse']:.3g}"
                         for sig in _MSE_UNITS)

    ways = [("replay", mses("replay"))]
    if validation.get("closed_loop"):
        closed = mses("closed_loop")
        ways = [("closed loop = replay", closed)] if closed == ways[0][1] else [*ways, ("closed loop", closed)]
    return f"{run}   MSE theta, omega, current [{units}]   " + "   ".join(f"{w}: {v}" for w, v in ways)


def summary_row(validation: dict) -> dict:
    """One flat row per run for ``processed/summary.csv`` and the console table."""
    row: dict = {"run": validation["run"], "n_samples": validation["n_samples"]}
    measured_switches = None
    for way in ("replay", "closed_loop"):
        block = validation.get(way) or {}         # a way skipped (no encoder) has no block
        for sig in ("theta", "omega", "current"):
            e = block.get("signals", {}).get(sig)
            row[f"{way}_{sig}_mse"] = None if e is None else e["mse"]
            row[f"{way}_{sig}_fit_pct"] = None if e is None else e["fit_pct"]
        sw = block.get("switches") or {}
        row[f"{way}_switches"] = sw.get("n_simulated")
        row[f"{way}_max_slip_s"] = sw.get("max_abs_s")
        measured_switches = sw.get("n_measured", measured_switches)
        ee = block.get("energy_error")
        row[f"{way}_energy_error_pct"] = None if ee is None else ee["paper_pct"]
    row["measured_switches"] = measured_switches
    return row
