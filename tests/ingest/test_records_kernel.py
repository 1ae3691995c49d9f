"""The compiled record join (``records_kernel``) gives Arrow's ``binary_join_element_wise`` byte for byte,
and an MCAP file written with it is the same file as one written with the Arrow join."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.config import default_config
from pipeline.ingest import mcap_bulk
from pipeline.ingest.records_kernel import MOVE, join_records
from pipeline.ingest.write import log_time_ns, mcap_channels

# shorter and longer than one move, and each length around it
piece = st.one_of(st.binary(min_size=0, max_size=2 * MOVE + 5),
                  st.integers(MOVE - 1, MOVE + 1).flatmap(lambda k: st.binary(min_size=k, max_size=k)))


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 40), st.integers(1, 3), st.data())
def test_join_records_is_arrows_join(n, fields, data):
    head_bytes = data.draw(st.sampled_from([1, 31, MOVE, MOVE + 3]))
    heads = np.frombuffer(data.draw(st.binary(min_size=n * head_bytes, max_size=n * head_bytes)),
                          dtype=np.uint8).reshape(n, head_bytes)
    literals = [data.draw(piece) for _ in range(fields + 1)]
    skip = data.draw(st.integers(0, 3))                      # texts that are slices (offsets not from 0)
    texts = [pa.array(data.draw(st.lists(piece, min_size=n + skip, max_size=n + skip)), pa.binary()).slice(skip)
             for _ in range(fields)]
    arrow_heads = pa.array([bytes(h) for h in heads], pa.binary())
    parts = [arrow_heads]
    for literal, text in zip(literals, texts):
        parts += [pa.scalar(literal, pa.binary()), text]
    expected = pc.binary_join_element_wise(*parts, pa.scalar(literals[-1], pa.binary()), pa.scalar(b"", pa.binary()))
    assert join_records(heads, literals, texts).to_pylist() == expected.to_pylist()


def _signals(n: int) -> pd.DataFrame:
    k = np.arange(n)
    special = np.tile([0.0, -0.0, 1e300, 5e-324, -2.5, 1 / 3], n // 6 + 1)[:n]
    return pd.DataFrame({"t_s": k * 0.001, "counts": (k * 7) % 5000 - 2500, "theta_rad": special,
                         "adc": (k % 1024).astype(np.int32), "current_v": special * 3, "current_a": -special,
                         "dir": (k % 3 - 1).astype(np.int8), "mode": (k % 3).astype(np.int8)})


def test_mcap_written_with_the_compiled_join_is_the_same_file(monkeypatch):
    df = _signals(3000)
    files = []
    for min_rows in (len(df) + 1, 0):                    # the Arrow join, then the compiled one
        monkeypatch.setattr(mcap_bulk, "JOIN_KERNEL_MIN_ROWS", min_rows)
        out = io.BytesIO()
        mcap_bulk.write_mcap(out, mcap_channels(df, default_config()), log_time_ns(df["t_s"].to_numpy()), {"m": {"k": "v"}},
                             chunk_bytes=8192)
        files.append(out.getvalue())
    assert files[0] == files[1] and len(files[0]) > 100_000
