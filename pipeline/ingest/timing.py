"""Sample times: counter wrap, out-of-order samples, and the timing statistics of the report (pure).

``millis()`` and ``micros()`` are unsigned 32-bit counters: millis wraps after
2**32 ms = 49.7 days, micros after 71.6 minutes.  A backward step of more than
half the counter range is a wrap and is undone; a lone sample out of order
(serial noise in its time field) is quarantined; anything else backwards is
not a wrap and not a reset (resets print the header again) and is refused.
"""

from __future__ import annotations

import numpy as np

COUNTER_RANGE = {"ms": 2.0**32, "us": 2.0**32, "s": None}
UNIT_S = {"ms": 1e-3, "us": 1e-6, "s": 1.0}
GAP_FACTOR = 1.5             # a step longer than 1.5 median periods is a gap (a lost sample or more)
PERIOD_TOLERANCE = 0.10      # median period this far from controller.period_s contradicts it
LISTED = 10                  # gaps listed individually in the report


def unwrap(t_raw: np.ndarray, unit: str) -> tuple[np.ndarray, int]:
    """Undo 32-bit counter wraps: the time axis continues past 2**32."""
    span = COUNTER_RANGE[unit]
    if span is None or len(t_raw) < 2:
        return t_raw.astype(np.float64), 0
    wraps = np.diff(t_raw) < -span / 2
    if not wraps.any():
        return t_raw.astype(np.float64), 0
    return t_raw + span * np.concatenate(([0.0], np.cumsum(wraps))), int(wraps.sum())


def lone_out_of_order(t: np.ndarray) -> np.ndarray:
    """Mask of isolated samples whose time breaks an otherwise non-decreasing sequence."""
    bad = np.zeros(len(t), dtype=bool)
    for i in np.flatnonzero(np.diff(t) < 0):
        if bad[i]:
            continue
        before = t[i - 1] if i > 0 else -np.inf
        after = t[i + 2] if i + 2 < len(t) else np.inf
        if before <= t[i + 1]:          # t[i] jumped up on its own
            bad[i] = True
        elif after >= t[i]:             # t[i+1] jumped down on its own
            bad[i + 1] = True
    return bad


def first_backward(t: np.ndarray) -> int | None:
    back = np.flatnonzero(np.diff(t) < 0)
    return int(back[0]) + 1 if len(back) else None


def timing_stats(t: np.ndarray, unit: str, line: np.ndarray, period_s: float) -> dict:
    """Median period, jitter, gaps, repeated timestamps, and whether sampling contradicts ``period_s``.

    Steps are taken on the unwrapped raw times before scaling, so integer
    millis give exact periods (no 1e-15 s jitter from rounding).
    """
    dt = np.diff(t) * UNIT_S[unit]

    def t_s(i: int) -> float:           # seconds since the first sample, only where the report needs it
        return float((t[i] - t[0]) * UNIT_S[unit])

    out: dict = {"samples": int(len(t)), "duration_s": t_s(-1) - t_s(0) if len(t) else 0.0,
                 "nominal_period_s": period_s}
    if not len(dt):
        return out | {"median_period_s": None, "defects": ["a single sample: no timing"]}
    m = len(dt)
    kth = [int(0.05 * (m - 1)), (m - 1) // 2, m // 2, int(0.95 * (m - 1))]
    part = np.partition(dt, kth)                       # one pass for all three (nearest-rank 5 % and 95 %)
    p05, med, p95 = float(part[kth[0]]), float(part[kth[1]] + part[kth[2]]) / 2, float(part[kth[3]])
    defects = []
    gaps = dt > GAP_FACTOR * med if med > 0 else np.zeros(len(dt), dtype=bool)
    repeated = int(np.count_nonzero(dt == 0))
    out |= {
        "median_period_s": med,
        "jitter_std_s": float(np.std(dt)),
        "period_p05_s": p05,
        "period_p95_s": p95,
        "min_period_s": float(dt.min()),
        "max_period_s": float(dt.max()),
        "gaps": int(np.count_nonzero(gaps)),
        "gap_list": [{"line": int(line[i + 1]), "t_s": t_s(i + 1), "step_s": float(dt[i])}
                     for i in np.flatnonzero(gaps)[:LISTED]],
        "repeated_timestamps": repeated,
    }
    if med == 0:
        defects.append(f"time does not advance: {repeated} of {len(dt)} steps are 0 (timer stuck)")
    elif abs(med - period_s) > PERIOD_TOLERANCE * period_s:
        defects.append(f"median sampling period {med:.6g} s contradicts controller.period_s = {period_s:.6g} s")
    if gaps.any():
        defects.append(f"{int(gaps.sum())} gaps longer than {GAP_FACTOR} median periods (longest {dt.max():.6g} s)")
    if repeated and med > 0:
        defects.append(f"{repeated} repeated timestamps")
    out["defects"] = defects
    return out
