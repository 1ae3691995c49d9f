"""Exact discretisation of the linear plant x' = A x + B u (eqs. 2, 4/8, 5), compiled (numba).

Between two instants the input is held (zero-order hold), so the state moves
by ``x(t+h) = Phi(h) x + Gamma(h) u`` with ``Phi = e^{A h}`` and
``Gamma = int_0^h e^{A s} ds B``, both read off one matrix exponential of the
augmented system ``[[A, B], [0, 0]] h`` (Van Loan).  The sample spacing of a
recording jitters between a couple of values (50/51 ms), so a whole recording
needs a few exponentials (one per distinct rounded length, ``step_lengths``)
and then 500 small matrix-vector products.  A motor-voltage change at ``a``
inside a step adds ``Gamma(h - a) * du`` (superposition of a step input), which
is how the loop delay ``Td`` is handled without losing exactness.

These are plain-float loops compiled with numba: at 3x3, numpy's per-call
overhead would cost more than the arithmetic, and CPython ~1 us per operation.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array

from pipeline.model.simd import V8, VEC, Lanes, splat

# Lengths closer than this share a cache entry: millis() spacing differences carry
# ~1e-15 s of float noise, far below any physical effect.
KEY_DECIMALS = 12
# More distinct spacings than this in one recording: no sharing of step matrices between steps.
MAX_DISTINCT_LENGTHS = 64


@njit(cache=True)
def step_key(h: float) -> float:
    """``h`` rounded to KEY_DECIMALS: the length the step matrices are computed for."""
    return round(h, KEY_DECIMALS)


@njit(cache=True)
def _scaling(A: np.ndarray, B: np.ndarray, q: int, h: float) -> tuple[int, float]:
    """Squarings s and the scaled length h / 2^s that bring ||[[A[q], B[q]], [0, 0]] h||_inf to <= 0.25
    (A (m, 3, 3), B (m, 3): indexed in place, no per-set views)."""
    norm = max(abs(A[q, 0, 0]) + abs(A[q, 0, 1]) + abs(A[q, 0, 2]) + abs(B[q, 0]),
               abs(A[q, 1, 0]) + abs(A[q, 1, 1]) + abs(A[q, 1, 2]) + abs(B[q, 1]),
               abs(A[q, 2, 0]) + abs(A[q, 2, 1]) + abs(A[q, 2, 2]) + abs(B[q, 2])) * abs(h)
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    return s, h / (2.0 ** s)


@njit(cache=True)
def _horner(x, b, p, g, r):
    """One Horner step on (P, g): P <- I + X P r, g <- (X g + b) r (3x3 unrolled, tuples in registers)."""
    x0, x1, x2, x3, x4, x5, x6, x7, x8 = x
    p0, p1, p2, p3, p4, p5, p6, p7, p8 = p
    g0, g1, g2 = g
    return ((1.0 + (x0 * p0 + x1 * p3 + x2 * p6) * r, (x0 * p1 + x1 * p4 + x2 * p7) * r,
             (x0 * p2 + x1 * p5 + x2 * p8) * r,
             (x3 * p0 + x4 * p3 + x5 * p6) * r, 1.0 + (x3 * p1 + x4 * p4 + x5 * p7) * r,
             (x3 * p2 + x4 * p5 + x5 * p8) * r,
             (x6 * p0 + x7 * p3 + x8 * p6) * r, (x6 * p1 + x7 * p4 + x8 * p7) * r,
             1.0 + (x6 * p2 + x7 * p5 + x8 * p8) * r),
            ((x0 * g0 + x1 * g1 + x2 * g2 + b[0]) * r, (x3 * g0 + x4 * g1 + x5 * g2 + b[1]) * r,
             (x6 * g0 + x7 * g1 + x8 * g2 + b[2]) * r))


@njit(cache=True)
def _square(p, g):
    """One squaring of [[P, g], [0, 1]]: (P, g) <- (P P, P g + g)."""
    p0, p1, p2, p3, p4, p5, p6, p7, p8 = p
    g0, g1, g2 = g
    return ((p0 * p0 + p1 * p3 + p2 * p6, p0 * p1 + p1 * p4 + p2 * p7, p0 * p2 + p1 * p5 + p2 * p8,
             p3 * p0 + p4 * p3 + p5 * p6, p3 * p1 + p4 * p4 + p5 * p7, p3 * p2 + p4 * p5 + p5 * p8,
             p6 * p0 + p7 * p3 + p8 * p6, p6 * p1 + p7 * p4 + p8 * p7, p6 * p2 + p7 * p5 + p8 * p8),
            (p0 * g0 + p1 * g1 + p2 * g2 + g0, p3 * g0 + p4 * g1 + p5 * g2 + g1, p6 * g0 + p7 * g1 + p8 * g2 + g2))


@njit(cache=True)
def phi_gamma_into(A: np.ndarray, B: np.ndarray, h: float, out: np.ndarray) -> None:
    """out[:] = (Phi row-major, Gamma) for one step: degree-12 Taylor with scaling and squaring.

    The augmented matrix [[A h, B h], [0, 0]] keeps its shape under products,
    so its exponential is carried as (P, g) with [[P, g], [0, 1]]: Horner
    P <- I + X P / j, g <- (X g + b) / j, then squaring (P, g) <- (P P, P g + g).
    With ||X||_inf <= 0.25 after scaling the truncation error is below 3e-18
    relative, so this matches ``scipy.linalg.expm`` to rounding.
    """
    s, hs = _scaling(A.reshape(1, 3, 3), B.reshape(1, 3), 0, h)
    x = (A[0, 0] * hs, A[0, 1] * hs, A[0, 2] * hs, A[1, 0] * hs, A[1, 1] * hs, A[1, 2] * hs,
         A[2, 0] * hs, A[2, 1] * hs, A[2, 2] * hs)
    b = (B[0] * hs, B[1] * hs, B[2] * hs)
    p = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    g = (0.0, 0.0, 0.0)
    for j in range(12, 0, -1):
        p, g = _horner(x, b, p, g, 1.0 / j)
    for _ in range(s):
        p, g = _square(p, g)
    for i in range(9):
        out[i] = p[i]
    out[9], out[10], out[11] = g


# Sets whose exponentials ``phi_gamma_lanes`` computes side by side (their working arrays stay in L1).
LANE_CHUNK = 64


@njit(cache=True)
def phi_gamma_lanes(A: np.ndarray, B: np.ndarray, sets: np.ndarray, h: np.ndarray, out: np.ndarray) -> None:
    """out[:, i] = ``phi_gamma_into(A[sets[i]], B[sets[i]], h[i])`` for every i, the lanes side by side.

    The same scaling, Horner steps and squarings in the same order per lane
    (``_scaling``, ``_horner``, ``_square``), so the same bits (tested); a lane
    needing fewer squarings than the most of its eight keeps its value by a
    select.
    One exponential on its own is a chain of dependent operations (~300 ns);
    lanes side by side fill the vector units (a few times faster each).
    """
    c = len(sets)
    W = np.zeros(25 * LANE_CHUNK)    # rows of LANE_CHUNK lanes: x (9), b (3), p (9), g (3), squarings
    # (zeros: the lanes past the last set of a chunk are computed too, on finite numbers)
    for c0 in range(0, c, LANE_CHUNK):
        w = min(LANE_CHUNK, c - c0)
        for i in range(w):
            q = sets[c0 + i]
            s, hs = _scaling(A, B, q, h[c0 + i])
            for r in range(3):
                for col in range(3):
                    W[(3 * r + col) * LANE_CHUNK + i] = A[q, r, col] * hs
                W[(9 + r) * LANE_CHUNK + i] = B[q, r] * hs
            W[24 * LANE_CHUNK + i] = s
        for i0 in range(0, w, VEC):                     # eight lanes at a time, in registers
            smax = 0
            for i in range(i0, min(i0 + VEC, w)):
                smax = max(smax, int(W[24 * LANE_CHUNK + i]))
            _expm_lanes(W, i0, smax)
        for i in range(w):
            for e in range(12):
                out[e, c0 + i] = W[(12 + e) * LANE_CHUNK + i]


@intrinsic
def _expm_lanes(typingctx, W, i0, smax):
    """Lanes i0..i0+7 of ``phi_gamma_lanes``' rows: P = I, g = 0, the twelve Horner steps of ``_horner``,
    then ``_square`` while a lane needs more squarings (row 24; the others keep theirs by a select).

    LLVM vector code with the 24 numbers of eight lanes in registers (a loop
    over lanes reloaded them at every step), emitted by ``_horner`` and
    ``_square`` themselves on ``simd.Lanes``: the same operations in the same
    order per lane, so the same bits.
    """
    sig = types.void(W, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        data = make_array(signature.args[0])(context, builder, args[0]).data
        i0, smax = args[1], args[2]

        def ptr(row):
            at = builder.add(i0, ir.Constant(ir.IntType(64), row * LANE_CHUNK))
            return builder.bitcast(builder.gep(data, [at]), V8.as_pointer())

        def lanes(values):
            return tuple(Lanes(builder, v) for v in values)

        x = lanes(builder.load(ptr(r), align=8) for r in range(9))
        b = lanes(builder.load(ptr(9 + r), align=8) for r in range(3))
        p, g = lanes(1.0 if i in (0, 4, 8) else 0.0 for i in range(9)), lanes([0.0] * 3)
        for j in range(12, 0, -1):
            p, g = _horner.py_func(x, b, p, g, Lanes(builder, 1.0 / j))
        squarings = builder.load(ptr(24), align=8)
        cells = [cgutils.alloca_once_value(builder, v.v) for v in p + g]
        with cgutils.for_range(builder, smax) as loop:   # squaring number k where the lane needs it
            cur = [builder.load(c) for c in cells]
            p2, g2 = _square.py_func(lanes(cur[:9]), lanes(cur[9:]))
            use = builder.fcmp_ordered("<", splat(builder, builder.sitofp(loop.index, ir.DoubleType())), squarings)
            for c, new, old in zip(cells, p2 + g2, cur):
                builder.store(builder.select(use, new.v, old), c)
        for e, c in enumerate(cells):
            builder.store(builder.load(c), ptr(12 + e), align=8)
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True)
def phi_gamma(A: np.ndarray, B: np.ndarray, h: float) -> np.ndarray:
    """(P00, P01, P02, P10, ..., P22, G0, G1, G2) for length ``h`` as a new array."""
    out = np.empty(12)
    phi_gamma_into(A, B, h, out)
    return out


@njit(cache=True)
def step_lengths(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rounded step lengths of instants ``t`` and, per step, the index of its length.

    Shared by every parameter set of a batch: the exponentials are then one per
    (set, distinct length), ~2 per set for a millis() recording.  Found by a
    search through the few lengths met so far (a sort would cost seconds of JIT
    compile); instants with more than MAX_DISTINCT_LENGTHS different spacings
    get one exponential per step instead, which stays linear in the samples.
    """
    n = max(len(t) - 1, 0)
    lengths = np.empty(n)
    idx = np.empty(n, dtype=np.int64)
    found = 0
    last = -1
    for k in range(n):
        key = step_key(t[k + 1] - t[k])
        if last >= 0 and lengths[last] == key:          # the common case: the previous spacing again
            idx[k] = last
            continue
        j = 0
        while j < found and lengths[j] != key:
            j += 1
        if j == found:
            if found == MAX_DISTINCT_LENGTHS:
                for q in range(n):
                    lengths[q] = step_key(t[q + 1] - t[q])
                    idx[q] = q
                return lengths, idx
            lengths[found] = key
            found += 1
        idx[k] = last = j
    return lengths[:found], idx
