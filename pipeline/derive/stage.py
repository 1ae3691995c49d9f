"""The derive stage: signals.parquet + rig.json -> kinematics, phases, overshoot, cycles, summary.json.

``derive_tables`` is the pure core (a signals table and a RigConfig in,
tables and a summary dict out); ``derive_run`` is the shell that reads one
processed run and writes its outputs atomically.  Whatever cannot be
computed (no current logged, no guard reached, too few samples) is said in
``summary["not_computed"]`` instead of failing the run.
"""

from __future__ import annotations

import math
from pathlib import Path
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.config import RigConfig
from pipeline.derive.current import (CURRENT_NOTE, CURRENT_ORDER, CURRENT_WINDOW, UNCERTAINTY_NOTE, current_summary,
                                     energy_refusal)
from pipeline.derive.current_only import derive_current_only
from pipeline.derive.cycles import cycle_summary, cycle_table
from pipeline.derive.energy import energy_uncertainty, motor_on_start, paper_energy_j, run_energy
from pipeline.derive.overshoot import overshoot_summary, overshoot_table
from pipeline.derive.phases import MODE_OF_DIR, infer_dir, phase_bounds, phase_table, reversal_indices
from pipeline.derive.stats import describe
from pipeline.derive.tables import schema_table
from pipeline.derive.velocity import (DEFAULT_ESTIMATOR, SAVGOL_ORDER, SAVGOL_WINDOW, backward_difference,
                                      savgol_velocity, smooth_by_phase)
from pipeline.errors import PdrError
from pipeline.runs import RunPaths, load_config, load_signals

VELOCITY_NOTE = (f"omega_rad_s = omega_savgol_rad_s: slope of a local cubic through {SAVGOL_WINDOW} samples on the "
                 "real time axis; centred, so no half-sample lag, and it averages encoder quantisation "
                 "(RMS error vs true velocity on virtual-rig recordings: 0.004 rad/s, against "
                 "0.064 rad/s for the paper's backward difference)")
# a run whose angle spans less than this many encoder counts never moved
STALL_COUNTS = 3


@dataclass(frozen=True)
class DerivedTables:
    kinematics: pd.DataFrame     # schemas/kinematics.json
    phases: pd.DataFrame         # schemas/phases.json
    overshoot: pd.DataFrame      # schemas/overshoot.json
    cycles: pd.DataFrame         # schemas/cycles.json
    summary: dict[str, Any]


def time_axis(signals: pd.DataFrame, period_s: float, notes: list[str]) -> np.ndarray:
    """The time axis to differentiate on: the logged one, or the nominal one when the timer never advanced.

    A board whose timer is stuck (every step 0, a known serial-capture defect)
    still logged a usable angle at its loop rate; anything else that does not
    increase strictly is refused, naming the line.
    """
    if len(signals) == 0:
        raise PdrError("signals table has no samples: nothing to derive", key="t_s")
    t = column(signals, "t_s", dtype=float)
    steps = np.diff(t)
    if len(steps) and np.all(steps == 0):
        notes.append(f"timer stuck (t_s never advances): the nominal period {period_s:g} s is used as the time axis")
        return np.arange(len(t)) * period_s
    bad = np.flatnonzero(steps <= 0)
    if len(bad):
        k = int(bad[0]) + 1
        line = int(signals["line"].iloc[k]) if "line" in signals else None
        raise PdrError(f"t_s must increase strictly, but sample {k} is at {t[k]:.6g} s after {t[k - 1]:.6g} s",
                       line=line, key="t_s")
    return t


def derive_tables(signals: pd.DataFrame, cfg: RigConfig) -> DerivedTables:
    """All derived tables of one run (pure)."""
    spec = cfg.plant_spec()
    guard = spec.guard_rad
    not_computed: dict[str, str] = {}
    notes: list[str] = []
    t = time_axis(signals, spec.period_s, notes)
    if "theta_rad" not in signals:              # no encoder: what the current (and a logged dir) gives
        *tables, summary = derive_current_only(signals, cfg, t, notes, CURRENT_WINDOW, CURRENT_ORDER)
        return DerivedTables(*tables, _json_safe(summary))
    theta = column(signals, "theta_rad", dtype=float)
    current = column(signals, "current_a", dtype=float) if "current_a" in signals else None

    omega_b = backward_difference(t, theta)
    omega_sg = savgol_velocity(t, theta)
    omega = omega_sg
    dir_logged = "dir" in signals
    dirs = column(signals, "dir").astype(np.int8) if dir_logged else infer_dir(t, theta, guard)
    kin = {"t_s": t, "theta_rad": theta, "omega_rad_s": omega, "omega_backward_rad_s": omega_b,
           "omega_savgol_rad_s": omega_sg}
    smooth = None
    if current is not None:
        smooth = smooth_by_phase(t, current, phase_bounds(dirs), CURRENT_WINDOW, CURRENT_ORDER)
        kin |= {"current_a": current, "current_smooth_a": smooth}
    kin |= {"dir": dirs, "dir_inferred": np.full(len(t), not dir_logged)}
    kinematics = pd.DataFrame(kin)

    phases = phase_table(t, theta, omega, current, dirs, guard)
    over = overshoot_table(t, theta, omega, current, dirs, guard, current_smooth=smooth)
    cycles = cycle_table(over)

    count_rad = 2 * math.pi / cfg.encoder.counts_per_rev
    span = float(np.ptp(theta)) if len(theta) else 0.0
    if len(t) < 3:
        notes.append(f"only {len(t)} sample(s): velocities are differences, nothing periodic can be seen")
    if span < STALL_COUNTS * count_rad:
        notes.append(f"stalled: the angle spans {span:.4g} rad (< {STALL_COUNTS} encoder counts) over "
                     f"{t[-1] - t[0]:.3g} s")
    max_abs = float(np.max(np.abs(theta)))
    moving_off = _moving_while_off(dirs, theta, count_rad) if dir_logged else 0
    if moving_off:
        notes.append(f"the motor is logged off (dir = 0) while the pinion moves ({moving_off} encoder counts): "
                     "something else drives it, or the sketch logs dir wrongly (check columns.dir and the sketch)")
    if len(over) == 0:
        why = (f"the angle never reached a guard (max |theta| = {max_abs:.3f} rad, guard {guard:.3f} rad)"
               if max_abs < guard else "the command never reversed")
        if dir_logged and not np.any(dirs != 0):
            why = "the motor is logged off (dir = 0) for the whole run: the controller never acted"
        not_computed["overshoot"] = why
        if max_abs < guard and not moving_off and _turns_without_guard(omega, count_rad, spec.period_s):
            notes.append("the pinion reverses without reaching the guard: check encoder.counts_per_rev "
                         "and controller.guard_rad against the sketch")
    if len(cycles) == 0:
        not_computed["cycles"] = "fewer than two upper turning points with a lower one between them"

    energy, uncertainty, current_stats = None, None, None
    if current is None:
        not_computed["energy"] = "no current column: energy not computed"
    else:
        current_stats = current_summary(current, smooth, dirs)
        if current_stats["stuck"]:
            notes.append(current_stats["stuck"])
        if refusal := energy_refusal(t, current, current_stats):
            not_computed["energy"] = refusal
        else:
            energy = run_energy(t, smooth, omega, theta, dirs, spec)
            k0 = motor_on_start(dirs)
            energy["energy_paper_logged_current_j"] = paper_energy_j(current[k0:], spec.v_rms, spec.period_s)
            if k0 >= len(t) - 1:        # the paper's window is the motor-on run: none, or one sample
                not_computed["energy_paper"] = ("the motor is never logged on: the paper's estimate covers "
                                                "the motor-on window (the physical balance is computed)")
            bounds = phase_bounds(dirs)
            uncertainty = energy_uncertainty(t, smooth, omega, dirs, spec, current_stats["noise_a"],
                                             lambda g: smooth_by_phase(t, g, bounds, CURRENT_WINDOW, CURRENT_ORDER))

    phase_dir, phase_duration = column(phases, "dir"), column(phases, "duration_s", float)
    modes = [MODE_OF_DIR[int(d)] for d in phase_dir]
    summary = {
        "samples": int(len(t)),
        "counts": {"samples": int(len(t)), "phases": int(len(phases)), "reversals": int(len(over)),
                   "turns_observed": int(over["turned"].sum()), "cycles": int(len(cycles)),
                   "encoder_counts_span": int(round(span / count_rad))},
        "duration_s": float(t[-1] - t[0]),
        "sample_interval_s": describe(np.diff(t)),
        "velocity": {"default": DEFAULT_ESTIMATOR, "window_samples": SAVGOL_WINDOW, "order": SAVGOL_ORDER,
                     "why": VELOCITY_NOTE,
                     "columns": {"backward": "omega_backward_rad_s", "savgol": "omega_savgol_rad_s"}},
        "dir_source": "logged" if dir_logged else "inferred from the guards",
        "phases": {
            "count": int(len(phases)), "switches": int(len(reversal_indices(dirs))),
            "mode_sequence": modes,
            "ended_at_guard": int(column(phases, "ended_at_guard").sum()),
            "duration_s": {name: describe(phase_duration[phase_dir == d]) for d, name in ((1, "q1"), (-1, "q2"))},
        },
        "theta_rad": describe(theta),
        "omega_rad_s": describe(omega),
        "overshoot": overshoot_summary(over, guard, spec.period_s, dir_logged),
        "cycles": cycle_summary(cycles),
        "energy": energy,
        "energy_uncertainty_j": uncertainty,
        "energy_uncertainty_note": UNCERTAINTY_NOTE if uncertainty is not None else None,
        "energy_paper_window": ({"first_sample": motor_on_start(dirs), "samples": int(len(t) - motor_on_start(dirs)),
                                 "why": "the motor-on run, as the paper's N = 500"} if energy is not None else None),
        "energy_current": CURRENT_NOTE if current is not None else None,
        "current": current_stats,
        "not_computed": not_computed,
        "notes": notes,
    }
    return DerivedTables(kinematics, phases, over, cycles, _json_safe(summary))


def _moving_while_off(dirs: np.ndarray, theta: np.ndarray, count_rad: float) -> int:
    """Encoder counts travelled over samples logged motor-off after the motor first ran, or over a run
    logged off throughout (0 when below ``STALL_COUNTS``: sitting still, or coasting a count or two)."""
    dirs = np.asarray(dirs)
    off = dirs[1:] == 0
    if np.any(dirs != 0):
        off &= np.arange(1, len(dirs)) > motor_on_start(dirs)
    travel = float(np.sum(np.abs(np.diff(theta))[off])) / count_rad if len(theta) > 1 else 0.0
    return int(round(travel)) if travel >= 10 * STALL_COUNTS else 0




def _turns_without_guard(omega: np.ndarray, count_rad: float, period_s: float) -> bool:
    """Clear velocity reversals (both signs well beyond quantisation) although no guard was reached."""
    if len(omega) < 5:
        return False
    big = np.abs(omega) > 20 * count_rad / period_s            # 20 counts per sample
    signs = np.sign(omega[big])
    return bool(len(signs) and np.count_nonzero(np.diff(signs)) >= 2)


def _json_safe(obj: Any) -> Any:
    """NaN/inf become null (summary.json is strict JSON); numpy scalars become Python numbers."""
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def derive_run(paths: RunPaths) -> dict:
    """Read one processed run, write kinematics/phases/overshoot/cycles Parquet and summary.json; return the summary."""
    return derive_and_write(paths).summary


def derive_and_write(paths: RunPaths) -> DerivedTables:
    """``derive_run`` returning the tables it wrote (``summary`` with its ``run`` key), for ``pdr run``'s validate."""
    from pipeline.io.atomic import write_json, write_parquet

    for needed in (paths.signals, paths.rig_config):
        if not needed.is_file():
            raise PdrError(f"missing {needed.name}: run `pdr ingest` on this recording first", path=needed)
    try:
        signals = load_signals(paths)
    except Exception as err:  # a torn or foreign file: say which
        raise PdrError(f"cannot read as Parquet: {err}", path=paths.signals) from None
    if "t_s" not in signals:
        raise PdrError("expected column 't_s' (schemas/signals.json)", path=paths.signals, key="t_s")
    if "theta_rad" not in signals and "current_a" not in signals:
        raise PdrError("expected column 'theta_rad' or 'current_a' (schemas/signals.json): nothing to derive",
                       path=paths.signals, key="theta_rad")
    tables = derive_tables(signals, load_config(paths))
    for name, df, target in (("kinematics", tables.kinematics, paths.kinematics),
                             ("phases", tables.phases, paths.phases),
                             ("overshoot", tables.overshoot, paths.overshoot),
                             ("cycles", tables.cycles, paths.cycles)):
        write_parquet(target, schema_table(name, df, where=str(target)))
    summary = {"run": paths.name, **tables.summary}
    write_json(paths.summary, summary)
    return DerivedTables(tables.kinematics, tables.phases, tables.overshoot, tables.cycles, summary)


def ingest_and_derive(csv: Path, processed: Path) -> list[RunPaths]:
    """A raw CSV ingested into ``processed`` and each of its runs derived (what discover and calibrate
    do with a raw CSV given on the command line); the runs' paths."""
    from pipeline.ingest.stage import ingest_recording

    runs = ingest_recording(csv, processed).runs
    for paths in runs:
        derive_run(paths)
    return runs
