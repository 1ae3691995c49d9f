"""Compile the ingest stage's numba loops once, so no ingest pays for it: ``python -m pipeline.ingest.compile``.

From an empty cache the first large capture would compile ``plain_kernel`` and
``records_kernel`` (~4 s); ``make``'s set-up calls this after installing (beside
``pipeline.model.compile``).  Each call takes a distinct compiled path: the
plain reader on one piece and on two halves (their arrays differ in layout), the
signals reader (and its first-time read), the line count, and the record join.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pyarrow as pa


def compile_kernels() -> float:
    """Call every compiled ingest path once (compile, or load from the cache); returns the seconds it took."""
    from pipeline.ingest.plain_kernel import read_int_rows, read_signals
    from pipeline.ingest.records_kernel import join_records

    start = time.perf_counter()
    rows = memoryview(b"0,1,2,3\n1,1,2,3\n2,1,2,3\n")
    for split_min_bytes in (1 << 30, 0):
        assert read_int_rows(rows, 4, 0, split_min_bytes).shape == (4, 3)
    at = np.array([4, 0, 1, 2, 3, 1024], dtype=np.int64)
    signals = memoryview(b"0,1,2,1\n1,1,2,0\n2,1,2,-1\n")
    scale = [0.0, 1e-3, 2.0**32, 1e-3, 5e-3, 2.5, 0.185]
    assert read_signals(signals, at, scale, 2, True)["mode"].tolist() == [1, 0, 2]
    assert join_records(np.zeros((1, 31), dtype=np.uint8), [b"{", b"}"],
                        [pa.array([b"1"], pa.binary())]).to_pylist() == [bytes(31) + b"{1}"]
    return time.perf_counter() - start


if __name__ == "__main__":
    print(f"ingest kernels ready in {compile_kernels():.1f} s", file=sys.stderr)
