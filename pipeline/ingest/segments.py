"""Rows of one logging segment made fit for conversion: range rules, time order, resets, re-framing (pure).

Time must not go back inside a segment.  What looks like it is sorted out
here in order: a 32-bit counter wrap (undone), a lone sample with a garbled
time (quarantined), a board reset without a header line (time near boot and
the count back at 0: a new segment), phase-shifted rows (re-framed from the
field stream).  Anything else is refused with the line where time went back.
"""

from __future__ import annotations

import numpy as np

from pipeline.config import RigConfig
from pipeline.errors import IngestError
from pipeline.ingest.convert import range_violations
from pipeline.ingest.parse import Quarantined, Segment, reframe
from pipeline.ingest.plausible import lone_jumps, persistent_jumps, repeated_times
from pipeline.ingest.timing import COUNTER_RANGE, UNIT_S, first_backward, lone_out_of_order, unwrap

RESTART_WITHIN_S = 10.0       # time dropping to below this (s since boot) with no header: a board reset


def _quarantine(seg: Segment, bad: np.ndarray, reasons) -> None:
    """Move the rows in ``bad`` to the segment's quarantine (their values as the quoted text)."""
    if bad.any():
        for i in np.flatnonzero(bad):
            text = ", ".join(f"{k}={v[i]:g}" for k, v in seg.values.items())
            seg.quarantined.append(Quarantined(int(seg.line[i]), reasons(i), text))
        seg.select(~bad)


def _order_time(seg: Segment, cfg: RigConfig) -> tuple[np.ndarray, int, int | None]:
    """Range rules, lone out-of-order samples; the unwrapped time, wraps, and the first backward row."""
    bad, reason = range_violations(seg.values, cfg)
    _quarantine(seg, bad, lambda i: reason[int(i)])
    t_raw = seg.values["t_raw"]
    if not (t_raw[1:] < t_raw[:-1]).any():                  # the common case: nothing to undo
        return seg.values["t_raw"], 0, None
    # a lone row out of line before any wrap is undone: one timestamp near 2**32 between ordinary ones is a
    # glitch, not two wraps 49 days apart (a real wrap's neighbours are near 2**32 too)
    spike = lone_out_of_order(t_raw)
    _quarantine(seg, spike, lambda i: "time out of order (a lone sample between its neighbours' times)")
    t, wraps = unwrap(seg.values["t_raw"], cfg.columns.time_unit)
    lone = lone_out_of_order(t)
    _quarantine(seg, lone, lambda i: "time out of order (a lone sample between its neighbours' times)")
    t = t[~lone]
    return t, wraps, first_backward(t)


def restart_points(t: np.ndarray, counts: np.ndarray | None, unit: str) -> np.ndarray:
    """Rows where a sketch without a header line restarted: time drops to near boot, the encoder
    count starts again at 0 (when there is an encoder: ``counts`` None), and time keeps going from there.

    Not a counter wrap (the time before is not within RESTART_WITHIN_S of 2**32) and not a lone
    garbled time (the next sample continues from the low value).
    """
    if len(t) < 3:
        return np.zeros(0, dtype=np.int64)
    scale, span = UNIT_S[unit], COUNTER_RANGE[unit]
    k = np.flatnonzero(t[1:] < t[:-1]) + 1              # backward steps only (none in most captures)
    low = t[k] * scale < RESTART_WITHIN_S
    wrap = (t[k - 1] > span - RESTART_WITHIN_S / scale) if span else np.zeros(len(k), dtype=bool)
    k = k[low & ~wrap & ((counts[k] == 0) if counts is not None else True)]
    k = k[k + 1 < len(t)]
    return k[(t[k + 1] >= t[k]) & (t[k + 1] < t[k - 1])]


def split_restarts(seg: Segment, unit: str) -> list[Segment]:
    """One segment per logging session when the board reset without printing a header again."""
    cuts = restart_points(seg.values["t_raw"], seg.values.get("counts"), unit)
    if not len(cuts):
        return [seg]
    parts = []
    bounds = [0, *cuts.tolist(), len(seg.line)]
    for a, z in zip(bounds[:-1], bounds[1:]):
        first, nxt = seg.line[a], (seg.line[z] if z < len(seg.line) else np.inf)
        prev = seg.line[a - 1] if a else -np.inf
        notes = list(seg.notes) if a == 0 else [
            f"board reset without a header line: time restarted at {seg.values['t_raw'][a]:g} {unit} (line {first})"]
        parts.append(Segment(seg.index, seg.header_line if a == 0 else None, seg.layout, seg.width, z - a,
                             seg.line[a:z], {k: v[a:z] for k, v in seg.values.items()},
                             [q for q in seg.quarantined if prev < q.line < nxt], notes))
    return parts


def clean_segment(seg: Segment, cfg: RigConfig, source: str) -> tuple[np.ndarray, int]:
    """Make a segment's time increase strictly or refuse; the rows no rig can produce are quarantined
    or flagged (``plausible``)."""
    t, wraps = _ordered(seg, cfg, source)
    repeated = repeated_times(t)
    if 2 * repeated.sum() >= len(t):        # a stuck timer, not a repeated line: reported as such (timing)
        repeated[:] = False
    first_of = np.maximum.accumulate(np.where(repeated, 0, np.arange(len(t))))
    line = seg.line
    _quarantine(seg, repeated, lambda i: f"repeated timestamp: the same time as line {int(line[first_of[i]])} "
                                         f"(that row kept)")
    t = t[~repeated]
    if "counts" in seg.values:
        jumps = lone_jumps(t, seg.values["counts"], cfg.columns.time_unit, cfg)
        _quarantine(seg, jumps, lambda i: "encoder jump: the count leaves both neighbours faster than the "
                                          "declared motor can turn (drive.v_in / model.Ke)")
        t = t[~jumps]
        seg.notes.extend(persistent_jumps(t, seg.values["counts"], seg.line, cfg.columns.time_unit, cfg))
    return t, wraps


def _ordered(seg: Segment, cfg: RigConfig, source: str) -> tuple[np.ndarray, int]:
    """Make a segment's time non-decreasing or refuse; phase-shifted rows are re-framed first."""
    rows_before = len(seg.line)
    t, wraps, back = _order_time(seg, cfg)
    if back is None:
        return t, wraps
    at_line, t_from, t_to = int(seg.line[back]), t[back - 1], t[back]
    unit = cfg.columns.time_unit
    refusal = IngestError(f"time goes back from {t_from:g} to {t_to:g} {unit} without a repeated header "
                          f"(not a board reset, not a counter wrap); expected non-decreasing time",
                          path=source, line=at_line)
    if seg.raw_text is None:
        raise refusal
    line, values, quarantined, leftover = reframe(seg)
    trial = Segment(seg.index, seg.header_line, seg.layout, seg.width, seg.data_lines, line, values,
                    quarantined, list(seg.notes))
    t2, wraps2, back2 = _order_time(trial, cfg)
    if back2 is None and len(trial.line) >= 0.9 * rows_before:
        seg.line, seg.values, seg.quarantined = trial.line, trial.values, trial.quarantined
        seg.notes.append(f"phase-shifted rows: fields re-framed into {seg.width}-field records "
                         f"({len(trial.line)} records, {leftover} trailing field(s) left over)")
        return t2, wraps2
    raise refusal
