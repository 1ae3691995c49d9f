"""Exact discretisation of the linear plant x' = A x + B u (eqs. 2, 4/8, 5).

Between two instants the input is held (zero-order hold), so the state moves
by ``x(t+h) = Phi(h) x + Gamma(h) u`` with ``Phi = e^{A h}`` and
``Gamma = int_0^h e^{A s} ds B``, both read off one matrix exponential of the
augmented system ``[[A, B], [0, 0]] h`` (Van Loan).  The sample spacing of a
recording jitters between a couple of values (50/51 ms), so a per-length cache
turns a whole recording into a few exponentials and 500 small matrix-vector
products.  A motor-voltage change at ``a`` inside a step adds
``Gamma(h - a) * du`` (superposition of a step input), which is how the loop
delay ``Td`` is handled without losing exactness.
"""

from __future__ import annotations

import math

import numpy as np

# Lengths closer than this share a cache entry: millis() spacing differences carry
# ~1e-15 s of float noise, far below any physical effect.
KEY_DECIMALS = 12


def step_key(h: float) -> float:
    return round(h, KEY_DECIMALS)


def phi_gamma(A: tuple[tuple[float, ...], ...], B: tuple[float, ...], h: float) -> tuple[float, ...]:
    """(Phi row-major, Gamma) for one step, in plain floats: the same Taylor/squaring as ``expm_batch``.

    The augmented matrix [[A h, B h], [0, 0]] keeps its shape under products,
    so its exponential is carried as (P, g) with [[P, g], [0, 1]]: Horner
    P <- I + X P / j, g <- (X g + b) / j, then squaring (P, g) <- (P P, P g + g).
    A 3x3 in Python floats beats numpy's per-call overhead ~5x at this size,
    which is most of a single simulation's set-up.
    """
    (a0, a1, a2), (a3, a4, a5), (a6, a7, a8) = A
    norm = max(abs(a0) + abs(a1) + abs(a2) + abs(B[0]), abs(a3) + abs(a4) + abs(a5) + abs(B[1]),
               abs(a6) + abs(a7) + abs(a8) + abs(B[2])) * abs(h)
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    hs = h / (2.0 ** s)
    x0, x1, x2, x3, x4, x5, x6, x7, x8 = (v * hs for v in (a0, a1, a2, a3, a4, a5, a6, a7, a8))
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
    return (p0, p1, p2, p3, p4, p5, p6, p7, p8, g0, g1, g2)


class StepCache:
    """Phi and Gamma per step length as flat Python floats (the fast loop's arithmetic)."""

    def __init__(self, A: np.ndarray, B: np.ndarray) -> None:
        self.A = tuple(tuple(float(v) for v in row) for row in A)
        self.B = tuple(float(v) for v in B)
        self._cache: dict[float, tuple[float, ...]] = {}
        self.raw: dict[float, tuple[float, ...]] = {}     # exact float -> entry, skips rounding on hits

    def __call__(self, h: float) -> tuple[float, ...]:
        """(P00, P01, P02, P10, ..., P22, G0, G1, G2) for length ``h``."""
        hit = self.raw.get(h)
        if hit is None:
            key = step_key(h)
            hit = self._cache.get(key)
            if hit is None:
                hit = phi_gamma(self.A, self.B, key)
                self._cache[key] = hit
            self.raw[h] = hit
        return hit


def expm_batch(M: np.ndarray) -> np.ndarray:
    """e^M for a stack of small matrices (..., k, k): scaling and squaring with a degree-12 Taylor series.

    One common scaling for the stack keeps it to a few dozen batched matmuls;
    with ||M / 2^s||_inf <= 0.25 the truncation error is below 3e-18 relative, so
    the result matches ``scipy.linalg.expm`` to rounding (~1e-14) while costing
    ~1 ms for a thousand 4x4 matrices instead of ~25 ms (and ~0.1 ms for one).
    """
    M = np.asarray(M, dtype=float)
    eye = np.eye(M.shape[-1])
    norm = float(np.max(np.sum(np.abs(M), axis=-1))) if M.size else 0.0
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    X = M / (2.0 ** s)
    E = eye + X / 12.0
    for j in range(11, 0, -1):                      # Horner: I + X/1 (I + X/2 (I + ...))
        E = eye + (X @ E) / j
    for _ in range(s):
        E = E @ E
    return E


def augmented_batch(A: np.ndarray, B: np.ndarray, h: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Phi(h), Gamma(h) for stacks A (m, 3, 3), B (m, 3) and step lengths h (scalar or (m,))."""
    cols = phi_gamma_columns(A, B, h)
    return cols[:, :3].transpose(2, 0, 1), cols[:, 3].T


def phi_gamma_columns(A: np.ndarray, B: np.ndarray, h: np.ndarray | float) -> np.ndarray:
    """[Phi(h) | Gamma(h)] as (3, 4, m), sets last: ``phi_gamma``'s Taylor/squaring for a whole stack.

    With the sets on the last axis every product is one einsum over contiguous
    rows (a stacked (m, 4, 4) matmul loops over tiny matrices instead), and
    carrying (P, g) skips the augmented matrix's constant last row: together
    ~4x less time than ``expm_batch`` on the augmented stack.  One scaling for
    the whole stack (the largest norm), so the truncation bound of
    ``expm_batch`` holds for every set.
    """
    m = A.shape[0]
    hh = np.broadcast_to(np.asarray(h, dtype=float), (m,))
    norm = float(np.max((np.abs(A).sum(axis=2) + np.abs(B)).max(axis=1) * np.abs(hh))) if m else 0.0
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    scale = hh / (2.0 ** s)
    X = np.ascontiguousarray(A.transpose(1, 2, 0)) * scale          # (3, 3, m)
    b = np.ascontiguousarray(B.T) * scale                           # (3, m)
    eye = np.eye(3)[:, :, None]
    P = eye + X / 12.0
    g = b / 12.0
    for j in range(11, 0, -1):                                      # Horner on (P, g), as phi_gamma
        g = (np.einsum("ijm,jm->im", X, g) + b) / j
        P = np.einsum("ijm,jkm->ikm", X, P)
        P /= j
        P += eye
    for _ in range(s):                                              # squaring: (P, g) <- (P P, P g + g)
        g = np.einsum("ijm,jm->im", P, g) + g
        P = np.einsum("ijm,jkm->ikm", P, P)
    return np.concatenate([P, g[:, None, :]], axis=1)
