"""Guard overshoot (the paper's Sec. IV-B, quantified): how far past the guard the pinion turns, and why.

The sketch samples the angle every 50 ms and reverses the command at the first
sample past the guard; the current then needs time to reverse (La/Ra = 7 s
time constant) and the pinion keeps going.  Per reversal of the command this
module measures the angle at the trigger sample, the turning point (vertex of
a local quadratic on the real time axis, so it is not limited to the sample
grid), the overshoot beyond the guard, the velocity and current at the
trigger, and the delays to the turn and to the current's zero crossing.

A rig that loses counts (encoder slip) shows it here first as a drifting
centre of the oscillation; a wrong counts-per-revolution, or a guard set in
counts for another decoding, as logged reversals away from the configured
guard.  The summary flags both (``drift_flag``, ``guard_offset_flag``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.derive.phases import reversal_indices
from pipeline.derive.stats import describe
from pipeline.derive.tables import frame

TURN_FIT_HALF = 2            # samples each side of the extreme sample in the vertex fit
DRIFT_LIMIT_RAD = 0.03       # rad: a centre shift larger than this over the run is flagged (3 % of the guard)

OVERSHOOT_COLUMNS = ["crossing", "direction", "trigger_sample", "trigger_t_s", "trigger_theta_rad",
                     "trigger_excess_rad", "at_guard", "turned", "turn_t_s", "turn_theta_rad", "overshoot_rad",
                     "turn_delay_s", "trigger_omega_rad_s", "trigger_current_a", "current_reversal_t_s",
                     "current_reversal_delay_s"]


def turning_point(t: np.ndarray, theta: np.ndarray, i: int, lo: int, hi: int) -> tuple[float, float]:
    """Vertex of a least-squares parabola through the samples around the extreme sample ``i`` (within [lo, hi]).

    Falls back to the sample itself when the fit has no vertex inside the
    fitted span (flat quantised plateau, too few samples).
    """
    a, b = max(lo, i - TURN_FIT_HALF), min(hi, i + TURN_FIT_HALF)
    if b - a < 2:
        return float(t[i]), float(theta[i])
    tt = t[a:b + 1] - t[i]
    c2, c1, c0 = np.polyfit(tt, theta[a:b + 1], 2)
    if c2 == 0.0:
        return float(t[i]), float(theta[i])
    tv = -c1 / (2.0 * c2)
    if not (tt[0] <= tv <= tt[-1]):
        return float(t[i]), float(theta[i])
    return float(t[i] + tv), float(c0 - c1 * c1 / (4.0 * c2))


CROSSING_FIT_HALF = 8        # samples each side of the current's sign change in the fit (0.8 s in all)


def current_reversal(t: np.ndarray, raw: np.ndarray, smooth: np.ndarray, k: int, end: int, d: int) -> float:
    """When the current, driven the other way since sample k, crosses zero (NaN when it does not before ``end``).

    The sign change is found on the smoothed current; its time comes from a
    straight line fitted to the raw samples around it (near its zero the current
    is a ramp of ~0.2 A/s, so a fit through 17 samples places the zero to a
    few hundredths of a second despite one-ADC-step noise).
    """
    neg = np.flatnonzero(d * smooth[k:end + 1] < 0)
    if len(neg) == 0:
        return np.nan
    j = k + int(neg[0])
    if j == k:
        return float(t[k])
    a, b = max(k, j - CROSSING_FIT_HALF), min(end, j + CROSSING_FIT_HALF)
    if b - a >= 3:
        # a line, not a quadratic: the current bends a little there (RMS error vs the truth 35 ms for the
        # line, 50 ms for a quadratic, on virtual-rig recordings: the quadratic's variance costs more)
        slope, icpt = np.polyfit(t[a:b + 1] - t[j], raw[a:b + 1], 1)
        if d * slope < 0 and t[a] <= t[j] - icpt / slope <= t[b]:
            return float(t[j] - icpt / slope)
    y0, y1 = d * smooth[j - 1], d * smooth[j]
    return float(t[j - 1] + (t[j] - t[j - 1]) * y0 / (y0 - y1))


def overshoot_table(t: np.ndarray, theta: np.ndarray, omega: np.ndarray, current: np.ndarray | None,
                    dirs: np.ndarray, guard_rad: float, current_smooth: np.ndarray | None = None) -> pd.DataFrame:
    """One row per command reversal (schemas/overshoot.json); ``direction`` +1 = upper guard, -1 = lower.

    ``current_smooth`` (``smooth_by_phase`` of ``current``) gives the current
    at the trigger and finds the zero crossing; without it the raw current does.
    """
    smooth = current_smooth if current_smooth is not None else current
    rev = reversal_indices(dirs)
    n = len(t)
    rows = []
    for j, k in enumerate(rev):
        k = int(k)
        end = int(rev[j + 1]) if j + 1 < len(rev) else n - 1
        d = int(dirs[k - 1])
        i = k + int(np.argmax(d * theta[k:end + 1]))
        # the turn was seen when the angle came back after its extreme within this phase
        turned = i < end and d * (theta[i] - theta[end]) > 0
        tt, th = turning_point(t, theta, i, k - 1, end) if turned else (np.nan, np.nan)
        crossing_t = current_reversal(t, current, smooth, k, end, d) if current is not None else np.nan
        rows.append({
            "crossing": j, "direction": d, "trigger_sample": k, "trigger_t_s": float(t[k]),
            "trigger_theta_rad": float(theta[k]), "trigger_excess_rad": float(d * theta[k] - guard_rad),
            "at_guard": bool(d * theta[k] >= guard_rad), "turned": bool(turned),
            "turn_t_s": tt, "turn_theta_rad": th, "overshoot_rad": d * th - guard_rad if turned else np.nan,
            "turn_delay_s": tt - float(t[k]) if turned else np.nan,
            "trigger_omega_rad_s": float(omega[k]),
            "trigger_current_a": float(smooth[k]) if current is not None else np.nan,
            "current_reversal_t_s": crossing_t, "current_reversal_delay_s": crossing_t - float(t[k]),
        })
    return frame(rows, OVERSHOOT_COLUMNS, {"crossing": "int32", "direction": "int8", "trigger_sample": "int64",
                                           "at_guard": "bool", "turned": "bool"})


def _trend(times: np.ndarray, values: np.ndarray) -> tuple[float, bool]:
    """Change of ``values`` over the span of ``times`` from a straight-line fit, and whether it is significant (> 3 SE)."""
    if len(values) < 3 or np.ptp(times) == 0:
        return float("nan"), False          # undefined (null in summary.json), never a 0 trend
    A = np.vstack([times - times.mean(), np.ones_like(times)]).T
    coef, *_ = np.linalg.lstsq(A, values, rcond=None)
    resid = values - A @ coef
    dof = len(values) - 2
    se = np.sqrt(np.sum(resid ** 2) / dof / np.sum((times - times.mean()) ** 2)) if dof > 0 else np.inf
    return float(coef[0] * np.ptp(times)), bool(abs(coef[0]) > 3 * se)


SETTLING_TURNS = 2           # turning-point pairs left out of the centre trend: the swing from rest is lopsided


def centre_drift(table: pd.DataFrame) -> tuple[float, bool, int]:
    """Trend of the oscillation centre over the run: (change in rad, significant, points used).

    The centre of two successive turns, (theta_turn[i] + theta_turn[i+1]) / 2,
    moves when counts are lost or gained (encoder slip, a miscounting
    decoder) but not when the amplitude settles after the start or under
    friction -- which moves the overshoot at both guards the same way and
    would fool a trend on the overshoot itself.
    """
    turned = np.flatnonzero(column(table, "turned", bool))
    th, tt = column(table, "turn_theta_rad", float)[turned], column(table, "turn_t_s", float)[turned]
    order = np.argsort(tt, kind="quicksort")          # what sort_values("turn_t_s") does
    th, tt = th[order], tt[order]
    centre, when = (th[:-1] + th[1:]) / 2.0, (tt[:-1] + tt[1:]) / 2.0
    centre, when = centre[SETTLING_TURNS:], when[SETTLING_TURNS:]
    change, significant = _trend(when, centre)
    return change, significant, int(len(centre))


def overshoot_summary(table: pd.DataFrame, guard_rad: float, period_s: float, dir_logged: bool) -> dict:
    """Statistics per direction (mean, spread, max; ``steady_overshoot_rad`` without the first swing
    from rest), the overshoot trend, and the drift / guard-offset flags.

    ``trend_rad`` per direction is the straight-line change of the overshoot
    over the run (the first reversal at each guard, a swing from rest, left
    out): settling and friction show there.  The drift flag looks at the
    oscillation centre instead (``centre_drift``).
    """
    out: dict = {"guard_rad": guard_rad, "crossings": int(len(table)), "directions": {}, "flags": []}
    # plain arrays and masks: pandas row selections cost more than the statistics here
    direction, turned = column(table, "direction"), column(table, "turned", bool)
    col = {c: column(table, c, float) for c in ("overshoot_rad", "trigger_excess_rad", "turn_delay_s",
                                                  "current_reversal_delay_s", "turn_t_s")}
    for d, name in ((1, "upper"), (-1, "lower")):
        sub = direction == d
        steady = np.flatnonzero(sub & turned)[1:]
        trend, _ = _trend(col["turn_t_s"][steady], col["overshoot_rad"][steady])
        out["directions"][name] = {
            "overshoot_rad": describe(col["overshoot_rad"][sub]),
            "steady_overshoot_rad": describe(col["overshoot_rad"][steady]),
            "trigger_excess_rad": describe(col["trigger_excess_rad"][sub]),
            "turn_delay_s": describe(col["turn_delay_s"][sub]),
            "current_reversal_delay_s": describe(col["current_reversal_delay_s"][sub]),
            "trend_rad": trend,
            "trend_not_computed": (None if np.isfinite(trend) else
                                   f"{len(steady)} turn(s) after the first at this guard: a trend needs 3"),
        }
    drift, significant, used = centre_drift(table)
    out["centre_drift_rad"] = drift
    out["centre_drift_not_computed"] = (None if np.isfinite(drift) else
                                        f"{used} turn pair(s) after the settling ones: a trend needs 3")
    out["drift_flag"] = bool(significant and abs(drift) > DRIFT_LIMIT_RAD)
    if out["drift_flag"]:
        out["flags"].append(f"the oscillation centre drifts by {drift:+.3f} rad over the run ({used} turn pairs): "
                            "counts lost or gained (encoder slip?)")
    out["guard_offset_flag"] = False
    if dir_logged and len(table):
        # the sketch reverses at the first sample past its guard: within one sample's travel beyond it
        reach = np.abs(column(table, "trigger_omega_rad_s", float)) * period_s * 1.5 + 0.01
        excess = column(table, "trigger_excess_rad", float)
        off = (excess < -0.01) | (excess > reach)
        out["guard_offset_flag"] = bool(off.mean() > 0.5)
        if out["guard_offset_flag"]:
            out["flags"].append(f"logged reversals at a median {np.median(np.abs(table['trigger_theta_rad'])):.3f} rad, "
                                f"guard is {guard_rad:.3f} rad (check encoder.counts_per_rev and controller.guard_rad)")
    return out
