"""Closed-form flow of an affine regime x' = A x + c, and root finding on it (compiled, numba).

``modal_data`` holds the eigendecompositions A = V diag(lam) V^-1 of the
plant's regimes (springs engaged, inside the backlash play), stacked on a
leading regime axis.  From them: the step matrices Phi(L) = e^{A L} and
Psi(L) = int_0^L e^{A s} ds (``step_matrices``), the state at any tau
(``state``) and, for an affine event function g = a.x + b, g(tau) and
g'(tau) as a short sum of exponentials in real arithmetic (``event_function``,
evaluated by ``gd``).  The root finders locate the first crossing of such a g
on that closed form.  Plain float/complex arithmetic compiled with numba: at
3x3, numpy's per-call overhead would dominate, and CPython's ~1 us per operation.
"""

from __future__ import annotations

import cmath
import math
from typing import NamedTuple

import numpy as np
from numba import njit

State = tuple[float, float, float]     # [I, w, delta]

# An event function as one array: [const, slope, noise, n_terms, then per term (lr, li, ar, ai, br, bi)].
EV_TERMS = 4


class ModalData(NamedTuple):
    """Eigendecompositions per regime r (axis 0): lam (r, 3), V and V^-1 (r, 3, 3), complex.

    ``zero`` marks a zero eigenvalue (the dead zone has one); ``mult`` is 2 for
    the upper member of a conjugate pair (counted for both), 1 for a real mode,
    0 for the lower member (skipped).
    """

    lam: np.ndarray
    V: np.ndarray
    Vinv: np.ndarray
    zero: np.ndarray
    mult: np.ndarray
    fastest: float


def modal_data(matrices: list[np.ndarray]) -> ModalData:
    """Decompose each regime's A (numpy, once per simulation)."""
    lams, Vs, Vis, zeros, mults = [], [], [], [], []
    for A in matrices:
        lam, V = np.linalg.eig(A)
        lam = lam.astype(complex)
        V = V.astype(complex)
        scale = max(1.0, float(np.max(np.abs(lam))))
        lams.append(lam)
        Vs.append(V)
        Vis.append(np.linalg.inv(V))
        zeros.append(np.abs(lam) < 1e-12 * scale)
        # a real matrix has conjugate eigenpairs with conjugate eigenvectors: keep one, count it twice
        mults.append(np.where(lam.imag > 0.0, 2.0, np.where(lam.imag == 0.0, 1.0, 0.0)))
    fastest = max(float(np.max(np.abs(lam))) for lam in lams)
    return ModalData(np.array(lams), np.array(Vs), np.array(Vis), np.array(zeros), np.array(mults), fastest)


@njit(cache=True)
def cexpm1(z: complex) -> complex:
    """e^z - 1 without cancellation for small |z| (cmath has no expm1)."""
    x, y = z.real, z.imag
    s = math.sin(0.5 * y)
    return complex(math.expm1(x) * math.cos(y) - 2.0 * s * s, math.exp(x) * math.sin(y))


@njit(cache=True)
def step_matrices(md: ModalData, r: int, key: float) -> np.ndarray:
    """(Phi row-major, Psi row-major) for length ``key`` in regime r: V diag(f(lam)) V^-1, 18 floats."""
    lam, V, Vi, zero = md.lam[r], md.V[r], md.Vinv[r], md.zero[r]
    e = np.empty(3, dtype=np.complex128)
    phi = np.empty(3, dtype=np.complex128)
    for j in range(3):
        if zero[j]:
            e[j] = 1.0
            phi[j] = key
        else:
            e[j] = cmath.exp(lam[j] * key)
            phi[j] = cexpm1(lam[j] * key) / lam[j]
    out = np.empty(18)
    for i in range(3):
        for j in range(3):
            out[3 * i + j] = (V[i, 0] * e[0] * Vi[0, j] + V[i, 1] * e[1] * Vi[1, j] + V[i, 2] * e[2] * Vi[2, j]).real
            out[9 + 3 * i + j] = (V[i, 0] * phi[0] * Vi[0, j] + V[i, 1] * phi[1] * Vi[1, j]
                                  + V[i, 2] * phi[2] * Vi[2, j]).real
    return out


@njit(cache=True)
def coefficients(md: ModalData, r: int, x0: float, x1: float, x2: float,
                 c0: float, c1: float, c2: float) -> tuple[np.ndarray, np.ndarray]:
    """y0 = V^-1 x and d = V^-1 c for the modes ``state`` uses (a conjugate mode is left at 0)."""
    Vi = md.Vinv[r]
    y0 = np.zeros(3, dtype=np.complex128)
    d = np.zeros(3, dtype=np.complex128)
    for j in range(3):
        if md.mult[r, j] > 0.0:
            y0[j] = Vi[j, 0] * x0 + Vi[j, 1] * x1 + Vi[j, 2] * x2
            d[j] = Vi[j, 0] * c0 + Vi[j, 1] * c1 + Vi[j, 2] * c2
    return y0, d


@njit(cache=True)
def state(md: ModalData, r: int, y0: np.ndarray, d: np.ndarray, tau: float) -> State:
    """x(tau) = Re V (e^{lam tau} y0 + phi d); a conjugate pair is one mode counted twice."""
    V, lam = md.V[r], md.lam[r]
    x0 = x1 = x2 = 0.0
    for j in range(3):
        mult = md.mult[r, j]
        if mult == 0.0:
            continue
        if md.zero[r, j]:
            m = y0[j] + tau * d[j]
        else:
            lt = lam[j] * tau
            m = cmath.exp(lt) * y0[j] + cexpm1(lt) / lam[j] * d[j]
        x0 += mult * (V[0, j] * m).real
        x1 += mult * (V[1, j] * m).real
        x2 += mult * (V[2, j] * m).real
    return (x0, x1, x2)


@njit(cache=True)
def event_function(md: ModalData, r: int, a0: float, a1: float, a2: float, b: float,
                   y0: np.ndarray, d: np.ndarray) -> np.ndarray:
    """g = a . x(tau) + b as an array for ``gd``, in real arithmetic.

    A mode with lam != 0 contributes Re(e^{lam tau} A) - Re(w d / lam) with
    A = w (y0 + d / lam) (and Re(e^{lam tau} lam A) to g'); a conjugate pair
    is one term counted twice; the zero mode contributes Re(w (y0 + tau d)).
    ``noise``: the size of the terms summed times 64 eps -- g is only known to
    that (a dip smaller is noise).
    """
    V, lam = md.V[r], md.lam[r]
    F = np.zeros(EV_TERMS + 18)
    const, slope = b, 0.0
    nt = 0
    size = 0.0
    for j in range(3):
        wj = a0 * V[0, j] + a1 * V[1, j] + a2 * V[2, j]
        lj = lam[j]
        if md.zero[r, j]:
            const += (wj * y0[j]).real
            slope += (wj * d[j]).real
            continue
        mult = md.mult[r, j]
        if mult == 0.0:
            continue                          # the conjugate of a mode already counted
        A = wj * (y0[j] + d[j] / lj)
        const -= mult * (wj * d[j] / lj).real
        B = lj * A
        o = EV_TERMS + 6 * nt
        F[o], F[o + 1], F[o + 2], F[o + 3], F[o + 4], F[o + 5] = (
            lj.real, lj.imag, mult * A.real, mult * A.imag, mult * B.real, mult * B.imag)
        size += abs(mult * A.real) + abs(mult * A.imag)
        nt += 1
    F[0], F[1], F[3] = const, slope, nt
    F[2] = 64.0 * 2.220446049250313e-16 * (abs(b) + abs(const - b) + size)
    return F


@njit(cache=True)
def gd(F: np.ndarray, tau: float) -> tuple[float, float]:
    """(g, dg/dtau) of the event function ``F`` at tau."""
    g, dg = F[0] + F[1] * tau, F[1]
    for q in range(int(F[3])):
        o = EV_TERMS + 6 * q
        lr, li, ar, ai, br, bi = F[o], F[o + 1], F[o + 2], F[o + 3], F[o + 4], F[o + 5]
        e = math.exp(lr * tau)
        if li:
            c, s_ = math.cos(li * tau), math.sin(li * tau)
            g += e * (ar * c - ai * s_)
            dg += e * (br * c - bi * s_)
        else:
            g += e * ar
            dg += e * br
    return g, dg


@njit(cache=True)
def zero_of_derivative(F: np.ndarray, lo: float, hi: float) -> float:
    """Where g' = 0 inside [lo, hi] given g'(lo) < 0 < g'(hi): Illinois regula falsi.

    Only g at that point matters (is the dip below the surface?), and g is flat
    there, so 1e-12 of the step is far more than enough.
    """
    d_lo, d_hi = gd(F, lo)[1], gd(F, hi)[1]
    span = hi - lo
    mid = lo
    side = 0
    for _ in range(100):
        new = lo - d_lo * (hi - lo) / (d_hi - d_lo)
        if not (lo <= new <= hi):
            new = 0.5 * (lo + hi)
        d_new = gd(F, new)[1]
        if abs(new - mid) <= 1e-12 * span or d_new == 0.0:
            return new
        mid = new
        if d_new < 0.0:
            lo, d_lo = new, d_new
            if side == -1:
                d_hi *= 0.5
            side = -1
        else:
            hi, d_hi = new, d_new
            if side == 1:
                d_lo *= 0.5
            side = 1
    return mid


@njit(cache=True)
def first_root(F: np.ndarray, hi: float, g0: float, gp0: float) -> float:
    """First tau in [0, hi] where g turns negative, given g(hi) < 0.

    When the regime was entered on the surface itself (g(0) <= 0), the event is
    immediate unless g first rises (g'(0) > 0): then a positive point inside is
    found first.  The root is polished by Newton safeguarded by the bracket.
    """
    lo = 0.0
    if g0 <= 0.0:
        if gp0 <= 0.0:
            return 0.0
        prev, found = hi, False
        probe = hi
        for _ in range(60):
            probe = 0.5 * prev
            if gd(F, probe)[0] > 0.0:
                found = True
                break
            prev = probe
        if not found:
            return 0.0
        lo, hi = probe, prev
    g_lo, g_hi = gd(F, lo)[0], gd(F, hi)[0]
    if g_hi >= 0.0:
        return hi
    if g_lo <= 0.0:
        # no bracket left in floating point: the surface lies within the closed form's rounding of the
        # start (a dead zone 1e-17 rad wide, its edges 1e-19 m from a state of 0.1), so the event is there
        return lo
    tau = lo + (hi - lo) * g_lo / (g_lo - g_hi)
    for _ in range(100):
        g, dg = gd(F, tau)
        if g > 0.0:
            lo = tau
        elif g < 0.0:
            hi = tau
        else:
            return tau
        new = tau - g / dg if dg != 0.0 else 0.5 * (lo + hi)
        if not (lo < new < hi):
            new = 0.5 * (lo + hi)
        if abs(new - tau) <= 1e-14 or hi - lo <= 1e-14:
            return new
        tau = new
    return 0.5 * (lo + hi)
