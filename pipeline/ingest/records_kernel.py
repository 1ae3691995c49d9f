"""MCAP message records glued row by row in one compiled pass (pure).

``pyarrow.compute.binary_join_element_wise`` glues each record's header, JSON
literals and value texts at ~1.6 ms per MB of records here, about a third of the
MCAP writer's CPU on a million samples: most of it is spent deciding, piece by
piece, how many bytes to copy.  This loop copies every piece as one fixed
32-byte move (``llvm.memcpy`` of constant size: two vector loads and stores, no
length-dependent branch) and lets the next piece overwrite the excess, so a
record costs a few nanoseconds per piece: ~0.3 ms per MB.  Pieces longer than 32
bytes are copied byte by byte.  The sources are padded and the output has room
for the last piece's excess, so no move reaches outside an array.

Byte for byte what the Arrow join gives (tests hold it to that); ``mcap_bulk``
uses it from ``JOIN_KERNEL_MIN_ROWS`` samples on, where the numba import is
already paid by ``plain_kernel`` or worth it.
"""

from __future__ import annotations

import numba
import numpy as np
import pyarrow as pa
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

MOVE = 32                 # bytes per piece move; sources padded and output over-allocated by this much


@intrinsic
def _move32(_typingctx, dst, dst_at, src, src_at):
    """``dst[dst_at:dst_at + 32] = src[src_at:src_at + 32]`` as one constant-size memcpy (no bounds check)."""
    def codegen(context, builder, sig, args):
        d, d_at, s, s_at = args
        d_ptr = builder.gep(context.make_array(sig.args[0])(context, builder, d).data, [d_at])
        s_ptr = builder.gep(context.make_array(sig.args[2])(context, builder, s).data, [s_at])
        cgutils.raw_memcpy(builder, d_ptr, s_ptr, ir.Constant(ir.IntType(64), MOVE), 1)
        return context.get_dummy_value()
    return types.void(dst, dst_at, src, src_at), codegen


@numba.njit(inline="always")
def _piece(out, at, src, start, length):
    if length <= MOVE:
        _move32(out, at, src, start)
    else:
        for b in range(length):
            out[at + b] = src[start + b]


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _join(heads, head_bytes, literals, literal_offsets, text_offsets, texts, text_bases, out, out_offsets):
    fields = text_offsets.shape[0]
    for r in range(out_offsets.shape[0] - 1):
        at = out_offsets[r]
        _piece(out, at, heads, r * head_bytes, head_bytes)
        at += head_bytes
        for f in range(fields + 1):
            start = literal_offsets[f]
            length = literal_offsets[f + 1] - start
            _piece(out, at, literals, start, length)
            at += length
            if f < fields:
                start = text_bases[f] + text_offsets[f, r]
                length = text_offsets[f, r + 1] - text_offsets[f, r]
                _piece(out, at, texts, start, length)
                at += length


def _padded(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([*parts, np.zeros(MOVE, dtype=np.uint8)])


def join_records(heads: np.ndarray, literals: list[bytes], texts: list[pa.Array]) -> pa.Array:
    """Per row: ``heads[row]``, ``literals[0]``, ``texts[0][row]``, ..., ``literals[-1]``, as one binary array:
    ``binary_join_element_wise(heads, literals[0], texts[0], ..., literals[-1], "")`` for binary ``texts``
    without nulls (``len(literals) == len(texts) + 1``; ``heads`` uint8 of shape (rows, header bytes))."""
    n, head_bytes = heads.shape
    offsets = np.empty((len(texts), n + 1), dtype=np.int64)
    data, bases, base = [], np.zeros(len(texts), dtype=np.int64), 0
    for f, text in enumerate(texts):
        assert text.null_count == 0 and len(text) == n
        offsets[f] = np.frombuffer(text.buffers()[1], dtype=np.int32, count=text.offset + n + 1)[text.offset:]
        body = text.buffers()[2]
        data.append(np.frombuffer(body, dtype=np.uint8, count=offsets[f, -1]) if body is not None and offsets[f, -1]
                    else np.zeros(0, dtype=np.uint8))
        bases[f], base = base, base + int(offsets[f, -1])
    literal_offsets = np.cumsum([0, *map(len, literals)], dtype=np.int64)
    lengths = head_bytes + int(literal_offsets[-1]) + (offsets[:, 1:] - offsets[:, :-1]).sum(axis=0)
    out_offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(lengths, out=out_offsets[1:])
    total = int(out_offsets[-1])
    out = np.empty(total + MOVE, dtype=np.uint8)
    _join(_padded([heads.reshape(-1)]), head_bytes, _padded([np.frombuffer(b"".join(literals), dtype=np.uint8)]),
          literal_offsets, offsets, _padded(data), bases, out, out_offsets)
    return pa.Array.from_buffers(pa.binary(), n, [None, pa.py_buffer(out_offsets.astype(np.int32)),
                                                  pa.py_buffer(out[:total])])
