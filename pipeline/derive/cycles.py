"""Period and amplitude of the oscillation, cycle by cycle: what a reviewer checks first.

A cycle runs from one turning point at the upper guard to the next one; its
amplitude is half the peak-to-peak angle between those turns and the lower
turn in between, its centre the mid-point (a non-zero centre means the rig
is not symmetric: current-sensor offset, backlash, a spring that differs).
Turning points come from the overshoot table, so they are the sub-sample
vertices, not the sample grid.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.derive.stats import describe

CYCLE_COLUMNS = ["cycle", "start_s", "end_s", "period_s", "theta_max_rad", "theta_min_rad",
                 "amplitude_rad", "center_rad"]


def cycle_table(overshoot: pd.DataFrame) -> pd.DataFrame:
    """One row per complete cycle (schemas/cycles.json): upper turn -> lower turn -> upper turn."""
    turned = column(overshoot, "turned", bool)
    tt = column(overshoot, "turn_t_s", float)[turned]
    th = column(overshoot, "turn_theta_rad", float)[turned]
    up = column(overshoot, "direction")[turned] == 1
    up_t, up_th, down_t, down_th = tt[up], th[up], tt[~up], th[~up]
    keep, lows = [], []
    for a in range(len(up_t) - 1):
        between = np.flatnonzero((down_t > up_t[a]) & (down_t < up_t[a + 1]))
        if len(between) == 1:            # a turn not seen (phase cut off) leaves no honest cycle
            keep.append(a)
            lows.append(down_th[between[0]])
    keep = np.asarray(keep, dtype=np.int64)
    hi, lo = up_th[keep], np.asarray(lows, dtype=float)
    return pd.DataFrame({
        "cycle": np.arange(len(keep), dtype=np.int32), "start_s": up_t[keep], "end_s": up_t[keep + 1],
        "period_s": up_t[keep + 1] - up_t[keep], "theta_max_rad": hi, "theta_min_rad": lo,
        "amplitude_rad": (hi - lo) / 2.0, "center_rad": (hi + lo) / 2.0,
    }, columns=CYCLE_COLUMNS)


def log_decrement(amplitudes: np.ndarray) -> tuple[float | None, float | None, str | None]:
    """Mean logarithmic decrement of successive cycle amplitudes, the damping ratio it implies,
    zeta = delta / sqrt(4 pi^2 + delta^2), and why not when there are fewer than two cycles.

    The rig is driven (bang-bang), so this measures how fast the swing settles onto its
    limit cycle (positive: amplitudes shrink; ~0 once steady), not the plant's free damping.
    """
    a = np.asarray(amplitudes, dtype=float)
    if len(a) < 2:
        return None, None, f"{len(a)} cycle(s): a decrement needs two successive amplitudes"
    if np.any(a <= 0):
        return None, None, "a cycle without a positive amplitude"
    delta = float(np.mean(np.log(a[:-1] / a[1:])))
    return delta, float(delta / np.sqrt(4 * np.pi ** 2 + delta ** 2)), None


def cycle_summary(cycles: pd.DataFrame) -> dict:
    """Period, frequency and amplitude statistics; ``steady`` leaves out the first cycle (the swing from rest)."""
    steady = cycles.iloc[1:] if len(cycles) > 1 else cycles
    steady_period = describe(column(steady, "period_s", float))
    delta, zeta, why = log_decrement(column(cycles, "amplitude_rad", float))
    return {
        "n_cycles": int(len(cycles)),
        "period_s": describe(column(cycles, "period_s", float)),
        "amplitude_rad": describe(column(cycles, "amplitude_rad", float)),
        "center_rad": describe(column(cycles, "center_rad", float)),
        "steady_period_s": steady_period,
        "steady_amplitude_rad": describe(column(steady, "amplitude_rad", float)),
        "frequency_hz": 1.0 / steady_period["mean"] if steady_period["mean"] else None,
        "log_decrement": delta, "damping_ratio": zeta,
        "log_decrement_not_computed": why,
    }
