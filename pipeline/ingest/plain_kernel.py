"""Rows of integers straight from the capture's bytes: one compiled pass per half of the file (pure).

``pyarrow.csv.read_csv`` spends ~130 ms of CPU per million rows on tokenising, type
conversion and its thread pool; a capture the plain path takes is only digits, commas,
minus signs and line breaks, which one compiled loop reads in ~35 ms (two halves on
two threads: ~20 ms wall) while checking the layout as it goes.  The loop accepts a
strict subset of what the general path (``parse.INT_RE``/``TIME_RE``) reads alike —
every field ``-?[0-9]{1,18}``, the time field ``[0-9]{1,15}`` (exact as float64),
``width`` fields per line, ``\\n`` or ``\\r\\n`` endings, time never going back — and
declines anything else (a decimal time, a space, a blank line, ...), so the caller
falls back to the slower readers; tests hold it to the general path's values.

Importing this module imports numba (~0.3 s once per process), so ``plain`` imports it only
for a capture of ``KERNEL_MIN_BYTES`` or more.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

MAX_DIGITS, MAX_TIME_DIGITS = 18, 15     # INT_RE's limit; 10**15 < 2**53, so every time is exact as float64
SPLIT_MIN_BYTES = 1 << 20                # below this one thread reads the whole body
CUT_WINDOW = 1 << 16


@numba.njit(nogil=True, cache=True, boundscheck=False)
def count_lines(buf: np.ndarray) -> int:
    n = 0
    for c in buf:
        n += c == 10
    return n


@numba.njit(nogil=True, cache=True, boundscheck=False)
def parse_rows(buf: np.ndarray, time_field: int, out: np.ndarray) -> int:
    """Fill out[field, row] from ``buf``; the rows read, or -1 where a line is not plain."""
    width, rows = out.shape
    i, end, n = 0, len(buf), 0
    previous = -1
    while i < end:
        if n == rows:
            return -1
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
            out[j, n] = -value if negative else value
            c = buf[i]
            i += 1
            if j + 1 < width:
                if c != 44:
                    return -1
            elif c == 13 and i < end and buf[i] == 10:
                i += 1
            elif c != 10:
                return -1
        if out[time_field, n] < previous:
            return -1
        previous = out[time_field, n]
        n += 1
    return n if n == rows else -1


def _halves(buf: np.ndarray, split_min_bytes: int) -> list[np.ndarray]:
    """``buf`` cut after the first line feed from its middle on (one piece when small, or when no
    line feed follows the middle within ``CUT_WINDOW`` bytes: no line of a plain capture is that long)."""
    if len(buf) < max(split_min_bytes, 2):
        return [buf]
    mid = len(buf) // 2
    cut = int(np.argmax(buf[mid:mid + CUT_WINDOW] == 10)) + mid + 1
    return [buf[:cut], buf[cut:]] if buf[cut - 1] == 10 and cut < len(buf) else [buf]


def read_int_rows(rows: memoryview, width: int, time_field: int, split_min_bytes: int = SPLIT_MIN_BYTES
                  ) -> np.ndarray | None:
    """``rows`` (whole lines, each ending in a line feed) -> int64 array (width, rows); None if not plain.

    From ``split_min_bytes`` on, the halves are counted and read on two threads (the loops
    release the GIL) into their slices of one array; time order is then checked where they meet.
    """
    parts = _halves(np.frombuffer(rows, dtype=np.uint8), split_min_bytes)
    with ThreadPoolExecutor(max_workers=len(parts)) as pool:
        counts = list(pool.map(count_lines, parts))
        out = np.empty((width, sum(counts)), dtype=np.int64)
        starts = np.cumsum([0, *counts])
        read = list(pool.map(lambda k: parse_rows(parts[k], time_field, out[:, starts[k]:starts[k + 1]]),
                             range(len(parts))))
    if read != counts or not sum(counts):
        return None
    if len(parts) > 1 and out[time_field, starts[1] - 1] > out[time_field, starts[1]]:
        return None                     # time goes back where the halves meet
    return out
