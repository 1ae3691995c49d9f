"""Exact discretisation of the linear plant x' = A x + B u (eqs. 2, 4/8, 5) and its stepper, compiled (numba).

Between two instants the input is held (zero-order hold), so the state moves
by ``x(t+h) = Phi(h) x + Gamma(h) u`` with ``Phi = e^{A h}`` and
``Gamma = int_0^h e^{A s} ds B``, both read off one matrix exponential of the
augmented system ``[[A, B], [0, 0]] h`` (Van Loan).  The sample spacing of a
recording jitters between a couple of values (50/51 ms), so a whole recording
needs a few exponentials (one per distinct rounded length, ``step_lengths``)
and then 500 small matrix-vector products.  A motor-voltage change at ``a``
inside a step adds ``Gamma(h - a) * du`` (superposition of a step input), which
is how the loop delay ``Td`` is handled without losing exactness (``zoh_step``,
the linear plant's stepper for the controller loop of ``pipeline.model.loop``).

These are plain-float loops compiled with numba: at 3x3, numpy's per-call
overhead would cost more than the arithmetic, and CPython ~1 us per operation.
"""

from __future__ import annotations

import math

import numpy as np
from typing import NamedTuple

from numba import njit

from pipeline.model.loop import STEPPERS, TIME_EPS, run

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
def _scaling(A: np.ndarray, B: np.ndarray, h: float) -> tuple[int, float]:
    """Squarings s and the scaled length h / 2^s that bring ||[[A, B], [0, 0]] h||_inf to <= 0.25."""
    norm = max(abs(A[0, 0]) + abs(A[0, 1]) + abs(A[0, 2]) + abs(B[0]),
               abs(A[1, 0]) + abs(A[1, 1]) + abs(A[1, 2]) + abs(B[1]),
               abs(A[2, 0]) + abs(A[2, 1]) + abs(A[2, 2]) + abs(B[2])) * abs(h)
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
    s, hs = _scaling(A, B, h)
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


@njit(cache=True)
def step_lengths(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rounded step lengths of instants ``t`` and, per step, the index of its length.

    The exponentials are then one per distinct length, ~2 for a millis()
    recording.  Found by a search through the few lengths met so far (a sort
    would cost seconds of JIT compile); instants with more than
    MAX_DISTINCT_LENGTHS different spacings get one exponential per step
    instead, which stays linear in the samples.
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


# Split lengths remembered in the delayed steps (a Td landing inside steps of a few lengths).
MAX_SPLIT_LENGTHS = 8


class Zoh(NamedTuple):
    """The linear plant as ``zoh_step`` carries it: step matrices per distinct length, and the
    input matrices Gamma(h - a) of the split lengths met so far (``n_split[0]`` of them, a ring)."""

    P: np.ndarray               # (lengths, 12): Phi row-major, Gamma
    idx: np.ndarray             # per step, the row of P
    A: np.ndarray
    B: np.ndarray
    split_keys: np.ndarray      # (MAX_SPLIT_LENGTHS,)
    split_gamma: np.ndarray     # (MAX_SPLIT_LENGTHS, 3)
    n_split: np.ndarray         # (1,) int


@njit(cache=True)
def _split_gamma(zp: Zoh, key: float) -> int:
    """Row of ``zp.split_gamma`` holding Gamma(key), computing it if not cached (few: Td is fixed)."""
    n = zp.n_split[0]
    c = 0
    while c < n and zp.split_keys[c] != key:
        c += 1
    if c == n:
        if n == MAX_SPLIT_LENGTHS:
            c = n = 0
        G = np.empty(12)
        phi_gamma_into(zp.A, zp.B, key, G)
        zp.split_keys[c] = key
        zp.split_gamma[c, 0], zp.split_gamma[c, 1], zp.split_gamma[c, 2] = G[9], G[10], G[11]
        zp.n_split[0] = n + 1
    return c


@njit(cache=True)
def zoh_step(zp: Zoh, x, k, tk, t_next, u_m, arrive, volts, head, tail, armed, guard):
    """One sample step: x+ = Phi(h) x + Gamma(h) u0 + sum over commands landing at a inside the
    step of Gamma(h - a) du (superposition of step inputs), exact for a piecewise constant input."""
    P, j = zp.P, zp.idx[k]             # indexing P[j, .] directly: a row view would cost a refcount per step
    I, w, dl = x
    h = t_next - tk
    u0 = u_m
    e0 = e1 = e2 = 0.0
    changed = False
    while head < tail and arrive[head] < t_next - TIME_EPS:
        du = volts[head] - u_m
        u_m = volts[head]
        a = arrive[head] - tk
        head += 1
        if du != 0.0:
            changed = True
            c = _split_gamma(zp, step_key(h - a))
            e0 += zp.split_gamma[c, 0] * du
            e1 += zp.split_gamma[c, 1] * du
            e2 += zp.split_gamma[c, 2] * du
    if changed:
        x = (P[j, 0] * I + P[j, 1] * w + P[j, 2] * dl + P[j, 9] * u0 + e0,
             P[j, 3] * I + P[j, 4] * w + P[j, 5] * dl + P[j, 10] * u0 + e1,
             P[j, 6] * I + P[j, 7] * w + P[j, 8] * dl + P[j, 11] * u0 + e2)
    else:                                # most steps: adding e = 0 would only lengthen the chain
        x = (P[j, 0] * I + P[j, 1] * w + P[j, 2] * dl + P[j, 9] * u0,
             P[j, 3] * I + P[j, 4] * w + P[j, 5] * dl + P[j, 10] * u0,
             P[j, 6] * I + P[j, 7] * w + P[j, 8] * dl + P[j, 11] * u0)
    return x, t_next, u_m, head, False


STEPPERS[Zoh] = zoh_step


@njit(cache=True)
def zoh_steps(A: np.ndarray, B: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Phi and Gamma per distinct step length of the instants ``t`` (rows of 12), and each step's row: what
    a replay at these instants needs whatever its start and command (``simulate.Prepared`` keeps them)."""
    lengths, idx = step_lengths(t)
    P = np.empty((len(lengths), 12))
    for j in range(len(lengths)):
        phi_gamma_into(A, B, lengths[j], P[j])
    return P, idx


@njit(cache=True)
def run_zoh(A, B, P, idx, c, t, x0, out, dirs) -> None:
    """The automaton on the linear plant (``loop.run``), with the step matrices of ``zoh_steps(A, B, t)``."""
    zp = Zoh(P, idx, A, B, np.empty(MAX_SPLIT_LENGTHS), np.empty((MAX_SPLIT_LENGTHS, 3)), np.zeros(1, dtype=np.int64))
    run(zp, c, t, x0, out, dirs)
