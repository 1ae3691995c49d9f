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
from numba import njit

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
def phi_gamma_into(A: np.ndarray, B: np.ndarray, h: float, out: np.ndarray) -> None:
    """out[:] = (Phi row-major, Gamma) for one step: degree-12 Taylor with scaling and squaring.

    The augmented matrix [[A h, B h], [0, 0]] keeps its shape under products,
    so its exponential is carried as (P, g) with [[P, g], [0, 1]]: Horner
    P <- I + X P / j, g <- (X g + b) / j, then squaring (P, g) <- (P P, P g + g).
    With ||X||_inf <= 0.25 after scaling the truncation error is below 3e-18
    relative, so this matches ``scipy.linalg.expm`` to rounding.
    """
    a0, a1, a2 = A[0, 0], A[0, 1], A[0, 2]
    a3, a4, a5 = A[1, 0], A[1, 1], A[1, 2]
    a6, a7, a8 = A[2, 0], A[2, 1], A[2, 2]
    norm = max(abs(a0) + abs(a1) + abs(a2) + abs(B[0]), abs(a3) + abs(a4) + abs(a5) + abs(B[1]),
               abs(a6) + abs(a7) + abs(a8) + abs(B[2])) * abs(h)
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    hs = h / (2.0 ** s)
    x0, x1, x2, x3, x4, x5, x6, x7, x8 = a0 * hs, a1 * hs, a2 * hs, a3 * hs, a4 * hs, a5 * hs, a6 * hs, a7 * hs, a8 * hs
    b0, b1, b2 = B[0] * hs, B[1] * hs, B[2] * hs
    p0, p1, p2, p3, p4, p5, p6, p7, p8 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    g0 = g1 = g2 = 0.0
    for j in range(12, 0, -1):                  # Horner on (P, g), unrolled 3x3
        r = 1.0 / j
        g0, g1, g2 = ((x0 * g0 + x1 * g1 + x2 * g2 + b0) * r, (x3 * g0 + x4 * g1 + x5 * g2 + b1) * r,
                      (x6 * g0 + x7 * g1 + x8 * g2 + b2) * r)
        p0, p1, p2, p3, p4, p5, p6, p7, p8 = (
            1.0 + (x0 * p0 + x1 * p3 + x2 * p6) * r, (x0 * p1 + x1 * p4 + x2 * p7) * r,
            (x0 * p2 + x1 * p5 + x2 * p8) * r,
            (x3 * p0 + x4 * p3 + x5 * p6) * r, 1.0 + (x3 * p1 + x4 * p4 + x5 * p7) * r,
            (x3 * p2 + x4 * p5 + x5 * p8) * r,
            (x6 * p0 + x7 * p3 + x8 * p6) * r, (x6 * p1 + x7 * p4 + x8 * p7) * r,
            1.0 + (x6 * p2 + x7 * p5 + x8 * p8) * r)
    for _ in range(s):                          # squaring: (P, g) <- (P P, P g + g)
        g0, g1, g2 = (p0 * g0 + p1 * g1 + p2 * g2 + g0, p3 * g0 + p4 * g1 + p5 * g2 + g1,
                      p6 * g0 + p7 * g1 + p8 * g2 + g2)
        p0, p1, p2, p3, p4, p5, p6, p7, p8 = (
            p0 * p0 + p1 * p3 + p2 * p6, p0 * p1 + p1 * p4 + p2 * p7, p0 * p2 + p1 * p5 + p2 * p8,
            p3 * p0 + p4 * p3 + p5 * p6, p3 * p1 + p4 * p4 + p5 * p7, p3 * p2 + p4 * p5 + p5 * p8,
            p6 * p0 + p7 * p3 + p8 * p6, p6 * p1 + p7 * p4 + p8 * p7, p6 * p2 + p7 * p5 + p8 * p8)
    out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7], out[8] = p0, p1, p2, p3, p4, p5, p6, p7, p8
    out[9], out[10], out[11] = g0, g1, g2


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
