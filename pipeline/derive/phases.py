"""Phases of the hybrid automaton: maximal runs of one command (q1 = +1, q2 = -1, off = 0).

The command comes from the logged ``dir`` column when the sketch prints it;
otherwise it is reconstructed with the sketch's own rule (``next_dir``, shared
with the simulator) from the logged angle, which is what the Arduino decided
on.  ``dir[k]`` is the command applied *after* sample k, so a phase starts at
the sample that decided it and ends at the sample that decided the next one.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.derive.tables import frame
from pipeline.model.simulate import next_dir

MODE_OF_DIR = {1: 1, -1: 2, 0: 0}      # schemas/signals.json: 1 = q1, 2 = q2, 0 = motor off


def infer_dir(t_s: np.ndarray, theta_rad: np.ndarray, guard_rad: float) -> np.ndarray:
    """The command the sketch must have applied at each sample, from the guards (int8 -1/0/1).

    The run starts in q1 (the sketch's initial mode, MODEL.md) unless the data
    say otherwise: when the first guard the angle reaches is the lower one (or,
    no guard being reached, the first motion is downwards) the motor was
    driving down; and when the pinion sits still for a while before it starts
    to move, the motor was off (0) until the onset found by ``motor_onset``.
    """
    t = np.asarray(t_s, dtype=float)
    theta = np.asarray(theta_rad, dtype=float)
    if len(t) != len(theta):
        raise ValueError("infer_dir: t_s and theta_rad must have the same length")
    out = np.empty(len(theta), dtype=np.int8)
    if len(theta) == 0:
        return out
    moved = _departure(theta)
    beyond = np.flatnonzero(np.abs(theta) >= guard_rad)
    if len(beyond):
        d = -1 if theta[beyond[0]] <= -guard_rad else 1
    else:
        d = -1 if len(moved) and theta[moved[0]] < theta[0] else 1
    onset = motor_onset(t, theta)
    out[:onset] = 0
    for k in range(onset, len(theta)):
        d = next_dir(d, float(theta[k]), guard_rad)
        out[k] = d
    return out


# The drive has taken over once the angle is this far from where the recording started: further
# than a pinion settling on its springs creeps (a few counts over seconds, after a board reset's
# unpowered gap), and reached within a few tenths of a second of a motor start.
DEPARTURE_RAD = 0.05
DEPARTURE_COUNTS = 4
# Faster than this before the onset is motion, not creep (settling creeps at ~0.01 rad/s, a drive moves
# at rad/s): a recording whose angle is best fitted with a faster drift was already moving.
MAX_CREEP_RAD_S = 0.1
# Candidate onsets before the first sample (in periods): a recording already moving fits one of these.
BEFORE_START = 3


def _departure(theta: np.ndarray) -> np.ndarray:
    """Samples at which the angle is at least ``DEPARTURE_RAD`` (and ``DEPARTURE_COUNTS`` counts) from
    its first value, or, when it never gets so far, at which it differs from it at all."""
    steps = np.abs(np.diff(theta))
    count = float(np.min(steps[steps > 0])) if np.any(steps > 0) else 0.0
    away = np.flatnonzero(np.abs(theta - theta[0]) >= max(DEPARTURE_RAD, DEPARTURE_COUNTS * count))
    return away if len(away) else np.flatnonzero(theta != theta[0])


def motor_onset(t: np.ndarray, theta: np.ndarray) -> int:
    """First sample of a recording at which the motor was on, when it starts at rest.

    From rest the current ramps as u/La t, so the angle grows as c (t - t_on)^3
    for the first few tenths of a second (back-EMF and springs are still
    negligible): one count shows only ~2 samples after the command.  Before the
    onset the pinion may still creep (settling on its springs after a board
    reset's unpowered gap: a count or two, either way), so the angle up to its
    departure (``DEPARTURE_RAD``) is fitted as a + b t + c (t - t_on)_+^3, linear
    in (a, b, c), for every candidate t_on; the best one with a creep's drift b
    (``MAX_CREEP_RAD_S``) and a departure mostly the cube's is the onset.  A recording already moving at its start
    (or never departing) has onset 0.
    Coulomb stiction or a loop delay hide the first samples of drive, so on
    such rigs the onset comes out one or two samples late (virtual rig:
    exact without them, 1-2 samples late with Tc = 6e-4 N m or Td = 50 ms).
    """
    away = _departure(theta)
    if len(away) == 0 or away[0] <= 2:
        return 0
    big = int(away[0])
    tt, y = t[:big + 1] - t[0], theta[:big + 1] - theta[0]
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    candidates = np.concatenate([-period * np.arange(BEFORE_START, 0, -1), tt[:big]])
    best, best_sse = 0.0, np.inf
    for t_on in candidates:
        X = np.column_stack([np.ones_like(tt), tt, np.clip(tt - t_on, 0.0, None) ** 3])
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        sse = float(np.sum((X @ coef - y) ** 2))
        drive = coef[2] * max(tt[-1] - t_on, 0.0) ** 3         # the cube's share of the departure
        if sse < best_sse and drive / y[-1] >= 0.5 and abs(coef[1]) <= MAX_CREEP_RAD_S:
            best, best_sse = float(t_on), sse
    return int(np.clip(np.argmin(np.abs(tt - best)), 0, big - 1))


def phase_bounds(dirs: np.ndarray) -> np.ndarray:
    """Index of the first sample of each phase (a new phase starts where the command changes)."""
    dirs = np.asarray(dirs)
    if len(dirs) == 0:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([[0], np.flatnonzero(dirs[1:] != dirs[:-1]) + 1]).astype(np.int64)


def reversal_indices(dirs: np.ndarray) -> np.ndarray:
    """Samples at which the command reversed (+1 -> -1 or -1 -> +1): the guard triggers."""
    dirs = np.asarray(dirs)
    return (np.flatnonzero((dirs[1:] == -dirs[:-1]) & (dirs[1:] != 0)) + 1).astype(np.int64)


def _signed_peak(x: np.ndarray) -> float:
    return float(x[np.argmax(np.abs(x))])


PEAK_FIT_ORDER = 3      # cubic through a phase's raw current samples (a phase is 20-50 samples)


def peak_current(t: np.ndarray, current: np.ndarray, d: int) -> float:
    """The current's extreme in the commanded direction (q1: max, q2: min; off: largest |I|).

    A phase's current runs from the previous phase's extreme (the other sign) to its
    own, so the two ends are nearly equal in magnitude and "largest |I|" picks either
    by noise.  The command's own extreme is the one it drove; it sits at the phase's
    end, where a moving-window smoother is one-sided, so it is read from one cubic
    through all the phase's raw samples (virtual rig, 88 phases: 16 mA RMS against
    the true current, 21 mA from the phase-wise smoothed current; sensor noise 27 mA).
    """
    t = np.asarray(t, dtype=float)
    i = np.asarray(current, dtype=float)
    fit = i
    if len(i) > PEAK_FIT_ORDER + 1 and np.ptp(t) > 0:
        x = t - t[0]
        fit = np.polyval(np.polyfit(x, i, PEAK_FIT_ORDER), x)
    return _signed_peak(fit) if d == 0 else float(d * np.max(d * fit))


def phase_table(t: np.ndarray, theta: np.ndarray | None, omega: np.ndarray | None, current: np.ndarray | None,
                dirs: np.ndarray, guard_rad: float) -> pd.DataFrame:
    """One row per phase (schemas/phases.json).

    A phase's samples run from the sample that started it to the one that ended
    it (inclusive: the command held over that whole span).  ``current``: the
    logged (raw) current, or None when not logged.  ``ended_at_guard``:
    the next phase reverses the command and its first sample is at or beyond
    the guard the phase was driving towards.  ``theta``/``omega`` None (no
    encoder): the angle columns are left out and a reversal's end reason is
    "reversed" (whether at the guard is not known).
    """
    starts = phase_bounds(dirs)
    n = len(t)
    rows = []
    for j, s in enumerate(starts):
        nxt = int(starts[j + 1]) if j + 1 < len(starts) else None
        e = nxt if nxt is not None else n - 1
        d = int(dirs[s])
        sl = slice(s, e + 1)
        if nxt is None:
            reason = "end of recording"
        elif dirs[nxt] == -d and d != 0 and theta is None:
            reason = "reversed"
        elif dirs[nxt] == -d and d != 0:
            reason = "guard" if d * theta[nxt] >= guard_rad else "reversed before guard"
        elif dirs[nxt] == 0:
            reason = "motor off"
        else:
            reason = "motor on"
        row = {
            "phase": j, "start_s": float(t[s]), "end_s": float(t[e]), "duration_s": float(t[e] - t[s]),
            "dir": d, "mode": MODE_OF_DIR[d], "first_sample": int(s), "n_samples": int(e - s + (nxt is None)),
            "peak_current_a": peak_current(t[sl], current[sl], d) if current is not None else np.nan,
            "end_reason": reason,
        }
        if theta is not None:
            th = theta[sl]
            row |= {"peak_omega_rad_s": _signed_peak(omega[sl]),
                    "theta_extreme_rad": float(th[np.argmax(d * th)] if d != 0 else _signed_peak(th)),
                    "ended_at_guard": reason == "guard"}
        rows.append(row)
    columns = PHASE_COLUMNS if theta is not None else [c for c in PHASE_COLUMNS if c not in ANGLE_COLUMNS]
    return frame(rows, columns, PHASE_DTYPES)


PHASE_COLUMNS = ["phase", "start_s", "end_s", "duration_s", "dir", "mode", "first_sample", "n_samples",
                 "peak_omega_rad_s", "peak_current_a", "theta_extreme_rad", "ended_at_guard", "end_reason"]
ANGLE_COLUMNS = ("peak_omega_rad_s", "theta_extreme_rad", "ended_at_guard")      # absent without an encoder
PHASE_DTYPES = {"phase": "int32", "dir": "int8", "mode": "int8", "first_sample": "int64", "n_samples": "int64",
                "ended_at_guard": "bool", "end_reason": "str"}
