"""Where each run of a capture sits on one time axis: the MCAP files' log_time.

A board reset restarts ``millis()``: every segment's ``t_s`` starts at 0, so their MCAP files, opened
together, would overlap.  Each segment is placed by what the capture says: a serial terminal's stamp
with a date puts it on the wall clock (nanoseconds since the Unix epoch); stamps with a time of day
alone give each segment's start after the first one's; without stamps the reset's gap is unknown and
the segments are placed back to back, one sample period apart, in the order logged.
"""

from __future__ import annotations

import re

TIME_NOTE = ("log_time = t_s, seconds since the segment's first sample; the capture's wall-clock start is not "
             "known (the rig's clock has no date)")
WALL_CLOCK_NOTE = ("log_time = nanoseconds since the Unix epoch: the serial terminal's stamp of the run's first "
                   "sample (UTC when the stamp gives no zone) plus t_s since that sample")
STAMPED = "the terminal's time-of-day stamp of each segment's first sample"
BACK_TO_BACK = "no stamp (the reset's gap is unknown): back to back, one sample period apart"
_CLOCK = re.compile(r"^(?:(?:[0-9]{4})?-?-?[0-9]{2}-[0-9]{2}T)?([0-9]{2}):([0-9]{2}):([0-9]{2}(?:\.[0-9]+)?)")
DAY_S = 86400.0


def epoch_ns(stamp: str | None) -> int | None:
    """Nanoseconds since the Unix epoch of an ISO 8601 date-time (UTC when it has no offset); None for a
    time of day alone (an Arduino IDE stamp has no date) or anything else."""
    import calendar
    from datetime import datetime, timezone

    try:
        dt = datetime.fromisoformat(stamp) if stamp else None
    except (TypeError, ValueError):
        return None
    if dt is None:
        return None
    dt = dt.replace(tzinfo=timezone.utc) if dt.tzinfo is None else dt.astimezone(timezone.utc)
    return calendar.timegm(dt.utctimetuple()) * 10**9 + dt.microsecond * 1000


def _time_of_day(stamp: str | None) -> float | None:
    m = _CLOCK.match(stamp or "")
    return None if m is None else int(m[1]) * 3600.0 + int(m[2]) * 60.0 + float(m[3])


def segment_offsets(starts: list[str | None], durations: list[float], period_s: float) -> tuple[list[float], str]:
    """Each kept segment's start in seconds after the first one's, and how it was placed.

    ``starts``: each segment's wall-clock stamp (or None), ``durations``: its span of ``t_s``.  Stamps
    are used when every segment has one and they leave no segment overlapping the one before (a
    midnight between two is a day); otherwise back to back."""
    clock = [_time_of_day(s) for s in starts]
    if all(c is not None for c in clock):
        offsets, day, previous = [0.0], 0.0, clock[0]
        for c in clock[1:]:
            if c + day < previous:          # past midnight
                day += DAY_S
            previous = c + day
            offsets.append(previous - clock[0])
        if all(offsets[k] >= offsets[k - 1] + durations[k - 1] for k in range(1, len(offsets))):
            return offsets, STAMPED
    offsets = [0.0]
    for k in range(1, len(durations)):
        offsets.append(offsets[-1] + durations[k - 1] + period_s)
    return offsets, BACK_TO_BACK


def log_time_origin(segment: dict | None) -> tuple[int, dict[str, str]]:
    """What to add to a run's sample times since its first sample (ns) to place it on its capture's one
    time axis, and the MCAP ``time`` metadata record that says which axis that is."""
    segment = segment or {}
    stamp = segment.get("wall_clock_start")
    start = epoch_ns(stamp)
    if start is not None:
        return start, {"log_time": WALL_CLOCK_NOTE, "wall_clock": stamp}
    offset = segment.get("time_offset_s")
    if not segment.get("time_axis"):            # one segment: its own first sample is t = 0
        return 0, {"log_time": TIME_NOTE, "wall_clock": "unknown"}
    return int(round(offset * 1e9)), {
        "log_time": f"seconds since the capture's first sample: this segment (after a board reset) starts "
                    f"{offset:.3f} s after it; placed by {segment['time_axis']}", "wall_clock": "unknown"}
