"""The derive stage for a recording without an encoder (``columns.counts = ""``): what the current gives.

A motor step response logged as time and current, or a sketch that logs no encoder, has no
angle: no velocity, no guard overshoot, no cycles, and of the energy balance only the
electrical figures (the paper's estimate, copper loss, stored magnetic energy, and the input
energy when ``dir`` says which voltage was applied).  The commands cannot be inferred either
(that needs the guards), so phases exist only when ``dir`` is logged.  Everything left out is
named in ``not_computed``, never filled with NaN or 0.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.config import RigConfig
from pipeline.derive.current import CURRENT_NOTE, UNCERTAINTY_NOTE, current_summary, energy_refusal
from pipeline.derive.cycles import CYCLE_COLUMNS, cycle_summary
from pipeline.derive.energy import energy_uncertainty, motor_on_start, run_electrical_energy
from pipeline.derive.overshoot import OVERSHOOT_COLUMNS, overshoot_summary
from pipeline.derive.phases import MODE_OF_DIR, phase_bounds, phase_table, reversal_indices
from pipeline.derive.stats import describe
from pipeline.derive.tables import frame
from pipeline.derive.velocity import smooth_by_phase

NO_ANGLE = "no encoder column (columns.counts = \"\")"
SKIPPED = {
    "velocity": f"{NO_ANGLE}: no angle to differentiate",
    "overshoot": f"{NO_ANGLE}: the guard crossings and turning points need the angle",
    "cycles": f"{NO_ANGLE}: the turning points need the angle",
    "energy_mechanical": (f"{NO_ANGLE}: friction, spring, kinetic, back-EMF/torque mismatch, load work and the "
                          "balance residual need the angle and velocity"),
}
NO_DIR = "dir not logged, and without the angle the commands cannot be inferred from the guards"


def derive_current_only(signals: pd.DataFrame, cfg: RigConfig, t: np.ndarray, notes: list[str],
                        window: int, order: int) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame, pd.DataFrame,
                                                          dict[str, Any]]:
    """Kinematics (time, current, logged dir), phases (from a logged dir), empty overshoot and cycles
    tables, and the summary (same keys as with an encoder; what needs the angle is None and said so).

    ``window``/``order``: the stage's current smoother, so energy here is the same figure as with an encoder.
    """
    spec = cfg.plant_spec()
    not_computed = dict(SKIPPED)
    current = column(signals, "current_a", dtype=float)
    dirs = column(signals, "dir").astype(np.int8) if "dir" in signals else None
    bounds = phase_bounds(dirs) if dirs is not None else np.zeros(1, dtype=np.int64)
    smooth = smooth_by_phase(t, current, bounds, window, order)
    kin = {"t_s": t, "current_a": current, "current_smooth_a": smooth}
    if dirs is not None:
        kin |= {"dir": dirs, "dir_inferred": np.zeros(len(t), dtype=bool)}
        phases = phase_table(t, None, None, current, dirs, spec.guard_rad)
    else:
        not_computed["phases"] = NO_DIR
        phases = phase_table(t, None, None, current, np.zeros(0, dtype=np.int8), spec.guard_rad)
    overshoot = frame([], OVERSHOOT_COLUMNS, {"crossing": "int32", "direction": "int8", "trigger_sample": "int64",
                                              "at_guard": "bool", "turned": "bool"})
    cycles = pd.DataFrame({c: np.zeros(0, dtype=np.int32 if c == "cycle" else float) for c in CYCLE_COLUMNS})

    on = dirs if dirs is not None else np.ones(len(t), dtype=np.int8)   # without dir: the whole run counts
    stats = current_summary(current, smooth, on)
    if stats["stuck"]:
        notes.append(stats["stuck"])
    energy = uncertainty = None
    if refusal := energy_refusal(t, current, stats):
        not_computed["energy"] = refusal
    else:
        energy = run_electrical_energy(t, smooth, dirs, spec)
        energy["energy_paper_logged_current_j"] = run_electrical_energy(t, current, dirs, spec)["energy_paper_j"]
        if dirs is None:
            not_computed["input_energy"] = "dir not logged: the applied voltage is not known"
        # the stage's propagation, with the mechanical terms (zero velocity here) left out
        sigma = energy_uncertainty(t, smooth, np.zeros(len(t)), on, spec, stats["noise_a"],
                                   lambda g: smooth_by_phase(t, g, bounds, window, order))
        uncertainty = {k: v for k, v in sigma.items() if k in energy}
    k0 = motor_on_start(on)
    summary = {
        "samples": int(len(t)),
        "counts": {"samples": int(len(t)), "phases": int(len(phases)), "reversals": 0, "turns_observed": 0,
                   "cycles": 0, "encoder_counts_span": None},
        "duration_s": float(t[-1] - t[0]),
        "sample_interval_s": describe(np.diff(t)),
        "velocity": None,
        "dir_source": "logged" if dirs is not None else "not logged (no angle to infer it from)",
        "phases": {
            "count": int(len(phases)),
            "switches": int(len(reversal_indices(dirs))) if dirs is not None else 0,
            "mode_sequence": [MODE_OF_DIR[int(d)] for d in column(phases, "dir")],
            "ended_at_guard": None,
            "duration_s": {name: describe(column(phases, "duration_s", float)[column(phases, "dir") == d])
                           for d, name in ((1, "q1"), (-1, "q2"))},
        },
        "theta_rad": None,
        "omega_rad_s": None,
        "overshoot": overshoot_summary(overshoot, spec.guard_rad, spec.period_s, dirs is not None),
        "cycles": cycle_summary(cycles),
        "energy": energy,
        "energy_uncertainty_j": uncertainty,
        "energy_uncertainty_note": UNCERTAINTY_NOTE if uncertainty is not None else None,
        "energy_paper_window": ({"first_sample": k0, "samples": int(len(t) - k0),
                                 "why": "the motor-on run, as the paper's N = 500" if dirs is not None else
                                 "the whole run (dir not logged: the motor-on start is not known)"}
                                if energy is not None else None),
        "energy_current": CURRENT_NOTE,
        "current": stats,
        "not_computed": not_computed,
        "notes": notes,
    }
    return pd.DataFrame(kin), phases, overshoot, cycles, summary

