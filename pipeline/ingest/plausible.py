"""Rows no rig can produce: a repeated sample time, an encoder jump faster than the declared motor turns (pure).

A serial capture repeats a line now and then (a retransmitted buffer) and
garbles a digit now and then (``1302`` read as ``13022``).  The first gives
two samples at one instant, which no derivative survives; the second moves the
pinion 1.8 rad in 50 ms where the rig's motor cannot reach 0.3.  The speed
bound is the declared rig's no-load speed, ``drive.v_in / model.Ke`` (the
back-EMF alone balances the supply), times ``SPEED_MARGIN``, plus
``COUNT_SLACK`` counts of quantisation and sampling skew.

A repeated time keeps its first row and quarantines the rest (unless most
times repeat: a stuck timer, which the timing report names instead).  A lone jump
(the sample leaves its neighbours, which agree with each other) is
quarantined; a jump that stays (the count does not come back) cannot be told
apart from a real slip of the encoder and is flagged in the report with its
line, not hidden.
"""

from __future__ import annotations

import numpy as np

from pipeline.config import RigConfig
from pipeline.ingest.timing import UNIT_S

SPEED_MARGIN = 4.0            # times the no-load speed: no load, supply spikes and a light pinion stay inside
COUNT_SLACK = 8.0             # counts always allowed between two samples
LISTED = 10                   # persistent jumps listed in the report


def max_counts_per_second(cfg: RigConfig) -> float:
    """The fastest encoder rate the declared rig's motor could give, with ``SPEED_MARGIN``."""
    rad_per_s = cfg.drive.v_in / cfg.model.Ke
    return SPEED_MARGIN * rad_per_s * cfg.encoder.counts_per_rev / (2.0 * np.pi)


def _limit(dt_s: np.ndarray, cfg: RigConfig) -> np.ndarray:
    return COUNT_SLACK + max_counts_per_second(cfg) * np.abs(dt_s)


def repeated_times(t: np.ndarray) -> np.ndarray:
    """Mask of rows whose time equals the previous row's (the first of each run of equal times is kept)."""
    bad = np.zeros(len(t), dtype=bool)
    bad[1:] = t[1:] == t[:-1]
    return bad


def lone_jumps(t: np.ndarray, counts: np.ndarray, unit: str, cfg: RigConfig) -> np.ndarray:
    """Mask of samples whose count leaves both neighbours faster than the motor can turn, the neighbours
    themselves agreeing (the first and last sample are judged against their one neighbour and the next)."""
    n = len(t)
    bad = np.zeros(n, dtype=bool)
    if n < 3:
        return bad
    ts = np.asarray(t, dtype=np.float64) * UNIT_S[unit]
    c = np.asarray(counts, dtype=np.float64)
    step = np.abs(np.diff(c))
    too_fast = step > _limit(np.diff(ts), cfg)
    if not too_fast.any():                  # the common case: one vectorised pass
        return bad
    inner = too_fast[:-1] & too_fast[1:] & (np.abs(c[2:] - c[:-2]) <= _limit(ts[2:] - ts[:-2], cfg))
    bad[1:-1] = inner
    bad[0] = too_fast[0] and not too_fast[1] and not bad[1]
    bad[-1] = too_fast[-1] and not too_fast[-2] and not bad[-2]
    return bad


def persistent_jumps(t: np.ndarray, counts: np.ndarray, line: np.ndarray, unit: str, cfg: RigConfig) -> list[str]:
    """Report lines for the steps still faster than the motor once lone jumps are gone."""
    if len(t) < 2:
        return []
    ts = np.asarray(t, dtype=np.float64) * UNIT_S[unit]
    c = np.asarray(counts, dtype=np.float64)
    step = np.diff(c)
    at = np.flatnonzero(np.abs(step) > _limit(np.diff(ts), cfg))
    if not len(at):
        return []
    shown = ", ".join(f"line {int(line[i + 1])} ({step[i]:+.0f} counts in {ts[i + 1] - ts[i]:.3g} s)"
                      for i in at[:LISTED])
    more = f" and {len(at) - LISTED} more" if len(at) > LISTED else ""
    return [f"{len(at)} encoder jump(s) faster than the declared motor can turn (more than "
            f"{max_counts_per_second(cfg):.0f} counts/s = {SPEED_MARGIN:g} x drive.v_in / model.Ke): {shown}{more}"]


def needs_cleaning(t: np.ndarray, counts: np.ndarray, unit: str, cfg: RigConfig) -> bool:
    """Whether a capture read by a fast path has a repeated time or an impossible jump (then the general
    path, which quarantines and reports them, reads it instead)."""
    if len(t) < 2:
        return False
    if (t[1:] == t[:-1]).any():
        return True
    ts = np.asarray(t, dtype=np.float64) * UNIT_S[unit]
    return bool((np.abs(np.diff(np.asarray(counts, dtype=np.float64))) > _limit(np.diff(ts), cfg)).any())
