"""Closed-form flow of an affine regime x' = A x + c, and root finding on it.

``Modal`` holds A's eigendecomposition A = V diag(lam) V^-1 (cached per
regime): the step matrices Phi(L) = e^{A L} and Psi(L) = int_0^L e^{A s} ds,
the state at any tau and, for an affine event function g = a.x + b, g(tau)
and g'(tau) as a short sum of exponentials in real arithmetic.  The root
finders locate the first crossing of such a g on that closed form.
Everything is plain Python float/complex arithmetic: at 3x3, numpy's
per-call overhead would dominate (see ``benchmarks/bench_model.py``).
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from pipeline.model.linear import step_key

State = tuple[float, float, float]     # [I, w, delta]


def cexpm1(z: complex) -> complex:
    """e^z - 1 without cancellation for small |z| (cmath has no expm1)."""
    x, y = z.real, z.imag
    s = math.sin(0.5 * y)
    return complex(math.expm1(x) * math.cos(y) - 2.0 * s * s, math.exp(x) * math.sin(y))


class Modal:
    """Exact affine flow x' = A x + c through the eigendecomposition A = V diag(lam) V^-1."""

    def __init__(self, A: np.ndarray) -> None:
        lam, V = np.linalg.eig(A)
        lam = lam.astype(complex)
        V = V.astype(complex)
        Vinv = np.linalg.inv(V)
        scale = max(1.0, float(np.max(np.abs(lam))))
        zero = np.abs(lam) < 1e-12 * scale
        self.lam = [complex(v) for v in lam]
        self.zero = [bool(v) for v in zero]
        self.V = [[complex(v) for v in row] for row in V]
        self.Vinv = [[complex(v) for v in row] for row in Vinv]
        self.fastest = float(np.max(np.abs(lam)))
        # a real matrix has conjugate eigenpairs with conjugate eigenvectors: keep one, count it twice
        self.modes = [(j, 2.0 if self.lam[j].imag > 0.0 else 1.0) for j in range(3) if self.lam[j].imag >= 0.0]
        self._steps: dict[float, tuple[tuple[float, ...], tuple[float, ...]]] = {}
        self.raw: dict[float, tuple[tuple[float, ...], tuple[float, ...]]] = {}   # exact float -> entry
        self._requests: set[float] = set()

    def cached(self, L: float):
        """(Phi, Psi) for L if already built (under its rounded key), else None."""
        return self._steps.get(step_key(L))

    def seen(self, L: float) -> bool:
        """True from the second request of a length on: only repeated lengths earn cached matrices."""
        key = step_key(L)
        if key in self._steps or key in self._requests:
            return True
        self._requests.add(key)
        return False

    def step(self, L: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Phi(L) = e^{A L} and Psi(L) = int_0^L e^{A s} ds, row-major floats, cached per length."""
        hit = self.raw.get(L)
        if hit is not None:
            return hit
        key = step_key(L)
        hit = self._steps.get(key)
        if hit is None:
            # V diag(f(lam)) V^-1 in plain complex arithmetic (a few dozen products beat numpy's call overhead)
            e = [1.0 if z else cmath.exp(lj * key) for lj, z in zip(self.lam, self.zero)]
            phi = [key if z else cexpm1(lj * key) / lj for lj, z in zip(self.lam, self.zero)]
            V, Vi = self.V, self.Vinv
            Phi = tuple((V[i][0] * e[0] * Vi[0][j] + V[i][1] * e[1] * Vi[1][j] + V[i][2] * e[2] * Vi[2][j]).real
                        for i in range(3) for j in range(3))
            Psi = tuple((V[i][0] * phi[0] * Vi[0][j] + V[i][1] * phi[1] * Vi[1][j]
                         + V[i][2] * phi[2] * Vi[2][j]).real for i in range(3) for j in range(3))
            hit = (Phi, Psi)
            self._steps[key] = hit
        self.raw[L] = hit
        return hit

    def coefficients(self, x: State, c: State) -> tuple[list[complex], list[complex]]:
        """y0 = V^-1 x and d = V^-1 c for the modes ``state`` uses (a conjugate mode is left at 0)."""
        Vi = self.Vinv
        y0 = [0j, 0j, 0j]
        d = [0j, 0j, 0j]
        for j, _ in self.modes:
            r = Vi[j]
            y0[j] = r[0] * x[0] + r[1] * x[1] + r[2] * x[2]
            d[j] = r[0] * c[0] + r[1] * c[1] + r[2] * c[2]
        return y0, d

    def state(self, y0: list[complex], d: list[complex], tau: float) -> State:
        """x(tau) = Re V (e^{lam tau} y0 + phi d); a conjugate pair is one mode counted twice."""
        V = self.V
        x0 = x1 = x2 = 0.0
        for j, mult in self.modes:
            if self.zero[j]:
                m = y0[j] + tau * d[j]
            else:
                lt = self.lam[j] * tau
                m = cmath.exp(lt) * y0[j] + cexpm1(lt) / self.lam[j] * d[j]
            x0 += mult * (V[0][j] * m).real
            x1 += mult * (V[1][j] * m).real
            x2 += mult * (V[2][j] * m).real
        return (x0, x1, x2)

    def event_function(self, a: tuple[float, float, float], b: float, y0: list[complex], d: list[complex]):
        """tau -> (g, dg/dtau) for g = a . x(tau) + b, in real arithmetic.

        A mode with lam != 0 contributes Re(e^{lam tau} A) - Re(w d / lam) with
        A = w (y0 + d / lam) (and Re(e^{lam tau} lam A) to g'); a conjugate pair
        is one term counted twice; the zero mode contributes Re(w (y0 + tau d)).
        """
        V = self.V
        const, slope = b, 0.0
        terms = []
        for j in range(3):
            wj = a[0] * V[0][j] + a[1] * V[1][j] + a[2] * V[2][j]
            lj = self.lam[j]
            if self.zero[j]:
                const += (wj * y0[j]).real
                slope += (wj * d[j]).real
                continue
            if lj.imag < 0.0:
                continue                          # the conjugate of a mode already counted
            mult = 2.0 if lj.imag > 0.0 else 1.0
            A = wj * (y0[j] + d[j] / lj)
            const -= mult * (wj * d[j] / lj).real
            B = lj * A
            terms.append((lj.real, lj.imag, mult * A.real, mult * A.imag, mult * B.real, mult * B.imag))
        exp, cos, sin = math.exp, math.cos, math.sin
        # size of the terms summed: g is only known to ~eps times this (a dip smaller is noise)
        scale = abs(b) + abs(const - b) + sum(abs(ar) + abs(ai) for _, _, ar, ai, _, _ in terms)

        def gd(tau: float) -> tuple[float, float]:
            g, dg = const + slope * tau, slope
            for lr, li, ar, ai, br, bi in terms:
                e = exp(lr * tau)
                if li:
                    c, s_ = cos(li * tau), sin(li * tau)
                    g += e * (ar * c - ai * s_)
                    dg += e * (br * c - bi * s_)
                else:
                    g += e * ar
                    dg += e * br
            return g, dg
        gd.noise = 64.0 * 2.220446049250313e-16 * scale      # type: ignore[attr-defined]
        return gd


def zero_of_derivative(gd, lo: float, hi: float) -> float:
    """Where g' = 0 inside [lo, hi] given g'(lo) < 0 < g'(hi): Illinois regula falsi.

    Only g at that point matters (is the dip below the surface?), and g is flat
    there, so 1e-12 of the step is far more than enough.
    """
    d_lo, d_hi = gd(lo)[1], gd(hi)[1]
    span = hi - lo
    mid = lo
    side = 0
    for _ in range(100):
        new = lo - d_lo * (hi - lo) / (d_hi - d_lo)
        if not (lo <= new <= hi):
            new = 0.5 * (lo + hi)
        d_new = gd(new)[1]
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


def first_root(gd, hi: float, g0: float, gp0: float) -> float:
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
        for _ in range(60):
            probe = 0.5 * prev
            if gd(probe)[0] > 0.0:
                found = True
                break
            prev = probe
        if not found:
            return 0.0
        lo, hi = probe, prev
    g_lo, g_hi = gd(lo)[0], gd(hi)[0]
    if g_hi >= 0.0:
        return hi
    tau = lo + (hi - lo) * g_lo / (g_lo - g_hi)
    for _ in range(100):
        g, dg = gd(tau)
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
