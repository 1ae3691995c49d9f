"""Rows of integers straight from the capture's bytes: one compiled pass per half of the file (pure).

``pyarrow.csv.read_csv`` spends ~130 ms of CPU per million rows on tokenising, type
conversion and its thread pool; a capture the plain path takes is only digits, commas,
minus signs and line breaks, which one compiled loop reads in ~20 ms (two halves on
two threads: ~10 ms wall) while checking the layout as it goes.  The loop accepts a
strict subset of what the general path (``parse.INT_RE``/``TIME_RE``) reads alike —
every field ``-?[0-9]{1,18}``, the time field ``[0-9]{1,15}`` (exact as float64),
``width`` fields per line, ``\\n`` or ``\\r\\n`` endings, time never going back — and
declines anything else (a decimal time, a space, a blank line, ...), so the caller
falls back to the slower readers; tests hold it to the general path's values.

Two loops share that line reader (``_line``): ``signal_rows`` writes each row's final
signals columns as it reads it (``convert.to_signals``' arithmetic, in its order, so the
same bits), and declines a row a range rule would quarantine; ``parse_rows`` keeps the
raw integers, for a capture with such rows.

Importing this module imports numba (~0.3 s once per process), so ``plain`` imports it only
for a capture of ``KERNEL_MIN_BYTES`` or more.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

MAX_DIGITS, MAX_TIME_DIGITS = 18, 15     # INT_RE's limit; 10**15 < 2**53, so every time is exact as float64
SPLIT_MIN_BYTES = 1 << 20                # below this one thread reads the whole body (the readers' default)
CUT_WINDOW = 1 << 16


@numba.njit(nogil=True, cache=True, boundscheck=False)
def count_lines(buf: np.ndarray) -> int:
    n = 0
    for c in buf:
        n += c == 10
    return n


@numba.njit(inline="always")
def _line(buf: np.ndarray, i: int, time_field: int, fields: np.ndarray) -> int:
    """The line from ``buf[i]`` into ``fields``; the position after its line feed, or -1 where it is not plain."""
    width, end = len(fields), len(buf)
    for j in range(width):
        if i == end:
            return -1
        negative = buf[i] == 45 and j != time_field
        i += negative
        value, digits = 0, 0
        while i < end and 48 <= buf[i] <= 57:
            value = value * 10 + (buf[i] - 48)
            digits += 1
            i += 1
        if digits == 0 or digits > (MAX_TIME_DIGITS if j == time_field else MAX_DIGITS) or i == end:
            return -1
        fields[j] = -value if negative else value
        c = buf[i]
        i += 1
        if j + 1 < width:
            if c != 44:
                return -1
        elif c == 13 and i < end and buf[i] == 10:
            i += 1
        elif c != 10:
            return -1
    return i


@numba.njit(nogil=True, cache=True, boundscheck=False)
def parse_rows(buf: np.ndarray, time_field: int, out: np.ndarray) -> int:
    """Fill out[field, row] from ``buf``; the rows read, or -1 where a line is not plain."""
    width, rows = out.shape
    fields = np.empty(width, dtype=np.int64)
    i, end, n = 0, len(buf), 0
    previous = -1
    while i < end:                      # this loop shape (not ``while n < rows``) compiles to the faster code
        if n == rows:
            return -1
        i = _line(buf, i, time_field, fields)
        if i < 0 or fields[time_field] < previous:
            return -1
        previous = fields[time_field]
        for j in range(width):
            out[j, n] = fields[j]
        n += 1
    return n if n == rows else -1


@numba.njit(nogil=True, cache=True, boundscheck=False)
def signal_rows(buf: np.ndarray, at: np.ndarray, scale: np.ndarray, line0: int, t_s: np.ndarray, t_raw: np.ndarray,
                line: np.ndarray, counts: np.ndarray, theta: np.ndarray, adc: np.ndarray, volts: np.ndarray,
                current: np.ndarray, dirs: np.ndarray, mode: np.ndarray) -> int:
    """Each line of ``buf`` as one row of the signals columns; the rows written, or -1 where a line is not
    plain or breaks a range rule (time below t_span, adc in 0..steps-1, dir in -1..1).

    ``at``: width, the fields of time, counts, adc and dir (-1: not logged, and ``adc``/``dirs`` empty),
    adc steps.  ``scale``: t0, t_scale, t_span, rad_per_count, volts_per_step, zero_v, sensitivity;
    ``current`` is empty while the zero is not known (``zero_v = "auto"``).  The arithmetic of
    ``convert.to_signals`` in its order: t_s = (t - t0) * t_scale, theta = counts * rad_per_count,
    v = adc * volts_per_step, current = (v - zero_v) / sensitivity, mode = dir + 3 * (dir < 0).
    """
    width, tf, cf, af, df, steps = at[0], at[1], at[2], at[3], at[4], at[5]
    t0, t_scale, t_span, rad_per_count, volts_per_step, zero_v, sensitivity = (
        scale[0], scale[1], scale[2], scale[3], scale[4], scale[5], scale[6])
    with_current = len(current) > 0
    rows = len(t_raw)
    fields = np.zeros(width, dtype=np.int64)
    i, end, n = 0, len(buf), 0
    previous = -1
    while i < end:
        if n == rows:
            return -1
        i = _line(buf, i, tf, fields)
        t = fields[tf]
        if i < 0 or t < previous or t >= t_span:
            return -1
        previous = t
        c = fields[cf]
        t_raw[n] = raw = float(t)
        t_s[n] = (raw - t0) * t_scale
        line[n] = line0 + n
        counts[n] = c
        theta[n] = c * rad_per_count
        if af >= 0:
            a = fields[af]
            if a < 0 or a >= steps:
                return -1
            adc[n] = a
            volts[n] = v = a * volts_per_step
            if with_current:
                current[n] = (v - zero_v) / sensitivity
        if df >= 0:
            d = fields[df]
            if d < -1 or d > 1:
                return -1
            dirs[n] = d
            mode[n] = d + 3 * (d < 0)
        n += 1
    return n if n == rows else -1


@numba.njit(nogil=True, cache=True, boundscheck=False)
def first_time(buf: np.ndarray, width: int, time_field: int) -> int:
    """The time of the first line of ``buf`` as ``signal_rows`` reads it (-1 where it is not plain)."""
    fields = np.zeros(width, dtype=np.int64)
    return fields[time_field] if _line(buf, 0, time_field, fields) > 0 else -1


def _halves(buf: np.ndarray, split_min_bytes: int) -> list[np.ndarray]:
    """``buf`` cut after the first line feed from its middle on (one piece when small, or when no
    line feed follows the middle within ``CUT_WINDOW`` bytes: no line of a plain capture is that long)."""
    if len(buf) < max(split_min_bytes, 2):
        return [buf]
    mid = len(buf) // 2
    cut = int(np.argmax(buf[mid:mid + CUT_WINDOW] == 10)) + mid + 1
    return [buf[:cut], buf[cut:]] if buf[cut - 1] == 10 and cut < len(buf) else [buf]


def _by_halves(rows: memoryview, split_min_bytes: int | None, allocate, read, times):
    """``read(piece, out, first_row, end_row)`` on each of ``_halves(rows)`` into ``out = allocate(rows)``, the
    halves counted, then read on two threads (the loops release the GIL); ``out`` and the row each half
    starts at, or None when a half is declined, is empty, or time (``times(out)``) goes back where they meet."""
    split = SPLIT_MIN_BYTES if split_min_bytes is None else split_min_bytes
    parts = _halves(np.frombuffer(rows, dtype=np.uint8), split)
    with ThreadPoolExecutor(max_workers=2) as pool:
        starts = np.cumsum([0, *pool.map(count_lines, parts)])
        out = allocate(int(starts[-1]))
        rows_read = list(pool.map(lambda k: read(parts[k], out, starts[k], starts[k + 1]), range(len(parts))))
    if rows_read != list(np.diff(starts)) or not starts[-1]:
        return None
    t, meet = times(out), starts[1:-1]
    return None if (t[meet - 1] > t[meet]).any() else (out, starts)


def read_int_rows(rows: memoryview, width: int, time_field: int, split_min_bytes: int | None = None
                  ) -> np.ndarray | None:
    """``rows`` (whole lines, each ending in a line feed) -> int64 array (width, rows); None if not plain.

    From ``split_min_bytes`` on, the halves are read on two threads into their slices of one array.
    """
    done = _by_halves(rows, split_min_bytes, lambda n: np.empty((width, n), dtype=np.int64),
                      lambda part, out, a, z: parse_rows(part, time_field, out[:, a:z]), lambda out: out[time_field])
    return done and done[0]


# signal_rows' output arrays in its argument order; an array of length 0 stands for one not filled
SIGNAL_ARRAYS = {"t_s": np.float64, "t_raw": np.float64, "line": np.int64, "counts": np.int64, "theta_rad": np.float64,
                 "adc": np.int32, "current_v": np.float64, "current_a": np.float64, "dir": np.int8, "mode": np.int8}


def read_signals(rows: memoryview, at: np.ndarray, scale: list[float], line0: int, with_current: bool,
                 split_min_bytes: int | None = None) -> dict[str, np.ndarray] | None:
    """``rows`` (whole lines) -> the columns ``signal_rows`` fills (without adc, current_v, current_a when
    adc is not logged, current_a unless ``with_current``, dir and mode when dir is not logged); None
    where it declines.  Halves on two threads as ``read_int_rows``; ``scale[0]`` (t0) is filled in
    here from the first row.
    """
    width, time_field, _, adc_field, dir_field, _ = at
    scale = np.array(scale, dtype=np.float64)
    scale[0] = first_time(np.frombuffer(rows, dtype=np.uint8), width, time_field)
    if scale[0] < 0:
        return None
    absent = {"adc", "current_v", "current_a"} if adc_field < 0 else set() if with_current else {"current_a"}
    absent |= {"dir", "mode"} if dir_field < 0 else set()

    def allocate(n: int) -> list[np.ndarray]:
        return [np.empty(0 if k in absent else n, dtype=dtype) for k, dtype in SIGNAL_ARRAYS.items()]

    def read(part: np.ndarray, arrays: list[np.ndarray], a: int, z: int) -> int:
        return signal_rows(part, at, scale, line0 + a, *(x[a:z] if len(x) else x for x in arrays))

    done = _by_halves(rows, split_min_bytes, allocate, read, lambda arrays: arrays[1])
    return done and {k: x for k, x in zip(SIGNAL_ARRAYS, done[0]) if k not in absent}
