"""The plant with Coulomb friction (stick mode) and backlash, advanced exactly from event to event.

With ``Tc`` and ``gap`` the plant is piecewise affine, x' = A x + c, in regimes:

- spring zone ``z``: +1 (theta > gap/2), 0 (inside the play: no spring torque),
  -1 (theta < -gap/2); the springs act on ``Ks * dz(theta)`` (MODEL.md backlash),
  i.e. ``R (K1 + K2) (delta - z R gap/2)`` outside the play.  Without backlash z = +1.
- slip direction ``s``: +1/-1 while the pinion turns (``J dw/dt`` gains
  ``-Tc * s``), 0 while it sticks: w = 0, delta frozen, only the current moves,
  as long as the net torque ``|Kt I - spring| <= Tc``.

Within a regime the exact solution is modal, ``x(tau) = Re V (e^{L tau} y0 +
phi(L, tau) d)`` with ``y0 = V^-1 x``, ``d = V^-1 c`` and ``phi = (e^{L tau} - 1)/L``
(``tau`` for a zero eigenvalue, which the dead zone has).  Every switching
surface is affine in the state (theta = +/-gap/2, w = 0, net torque = +/-Tc,
theta = +/-guard), so each event function is a short sum of exponentials in
tau: it is scanned on a grid finer than the plant's fastest oscillation and
the first sign change is located with Brent's method on the closed form, to
~1e-15 s.  In stick the current is a single exponential, so break-away is
solved in closed form.  States are snapped onto the surface they reached
(w = 0 exactly, delta = +/-R gap/2 exactly), so a stuck pinion stays exactly
still and a regime never re-fires at its own entry point.
"""

from __future__ import annotations

import cmath
import math

import numpy as np
from scipy.optimize import brentq

from pipeline.model.effects import PlantSpec

# Longest grid step for the sign scan [s]; the plant's fastest mode (~3 rad/s for
# Table I) turns by < 0.05 rad over it, so a surface is not crossed twice unseen.
GRID_DT = 0.0125
MAX_ZERO_LENGTH_EVENTS = 50


class Modal:
    """Exact affine flow x' = A x + c through the eigendecomposition of A."""

    def __init__(self, A: np.ndarray) -> None:
        lam, V = np.linalg.eig(A)
        self.lam = lam.astype(complex)
        self.V = V.astype(complex)
        self.Vinv = np.linalg.inv(self.V)
        scale = max(1.0, float(np.max(np.abs(lam))))
        self.zero = np.abs(self.lam) < 1e-12 * scale
        self.lam_safe = np.where(self.zero, 1.0, self.lam)

    def coefficients(self, x: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.Vinv @ x, self.Vinv @ c

    def states(self, y0: np.ndarray, d: np.ndarray, taus: np.ndarray) -> np.ndarray:
        """x(tau) for each tau, shape (len(taus), 3)."""
        lt = np.outer(taus, self.lam)
        phi = np.where(self.zero, taus[:, None], np.expm1(lt) / self.lam_safe)
        return ((np.exp(lt) * y0 + phi * d) @ self.V.T).real

    def scalar(self, a: np.ndarray, b: float, y0: np.ndarray, d: np.ndarray):
        """tau -> a . x(tau) + b as a plain-Python closure (cheap inside Brent)."""
        w = a @ self.V
        terms = [(complex(w[j]), complex(self.lam[j]), complex(y0[j]), complex(d[j]), bool(self.zero[j]))
                 for j in range(3)]

        def f(tau: float) -> float:
            acc = b
            for wj, lj, yj, dj, zj in terms:
                e = cmath.exp(lj * tau)
                acc += (wj * (e * yj + (tau if zj else (e - 1.0) / lj) * dj)).real
            return acc
        return f


class NonsmoothPlant:
    """Carries the regime (z, s) between calls of ``advance``; the simulator owns the timing."""

    def __init__(self, spec: PlantSpec) -> None:
        p = spec.params
        self.La, self.Ra, self.Kt, self.J, self.R = p.La, p.Ra, p.Kt, p.J, p.R
        self.Kd = p.R * (p.K1 + p.K2)          # N m per m of delta: R (K1 + K2), eq. (4)
        self.Tc = spec.Tc
        self.gap = spec.gap
        self.db = p.R * spec.gap / 2.0          # m   half play in rack displacement
        A, _ = p.state_matrices()
        A_dead = A.copy()
        A_dead[1, 2] = 0.0                      # inside the play the springs exert nothing
        self.modal = {True: Modal(A), False: Modal(A_dead)}
        self.z = 1
        self.s = 1

    # -- regime bookkeeping -------------------------------------------------
    def spring_torque(self, delta: float) -> float:
        return 0.0 if self.z == 0 else self.Kd * (delta - self.z * self.db)

    def net_torque(self, x: np.ndarray) -> float:
        """Torque that Coulomb friction has to hold at w = 0: Kt I - spring."""
        return self.Kt * x[0] - self.spring_torque(x[2])

    def reset(self, x: np.ndarray) -> None:
        """Regime of a state given from outside (the initial state)."""
        if self.gap > 0.0:
            theta = x[2] / self.R
            self.z = 1 if theta > self.gap / 2.0 else (-1 if theta < -self.gap / 2.0 else 0)
        else:
            self.z = 1
        if self.Tc <= 0.0 or x[1] > 0.0:
            self.s = 1
        elif x[1] < 0.0:
            self.s = -1
        else:
            net = self.net_torque(x)
            self.s = 0 if abs(net) <= self.Tc else (1 if net > 0 else -1)

    # -- propagation --------------------------------------------------------
    def advance(self, x: np.ndarray, t0: float, t1: float, u: float, guard_mode: int = 0,
                guard_rad: float = 0.0) -> tuple[np.ndarray, float, bool]:
        """Hold motor voltage ``u`` from t0 towards t1; stop early if the continuous guard is hit.

        ``guard_mode`` +1/-1 arms the guard theta = +/-guard_rad (the continuous
        controller in that mode); 0 disarms it.  Returns (x, t reached, hit).
        """
        t = t0
        zero_run = 0
        while t1 - t > 0.0:
            L = t1 - t
            if self.s == 0:
                x, tau, event = self._stick(x, u, L)
            else:
                x, tau, event = self._slip(x, u, L, guard_mode, guard_rad)
            if event is None:
                return x, t1, False
            t = min(t + tau, t1)
            zero_run = zero_run + 1 if tau == 0.0 else 0
            if zero_run > MAX_ZERO_LENGTH_EVENTS:
                raise RuntimeError(f"nonsmooth plant: {zero_run} zero-length events at t={t:.9g} s (chattering)")
            kind, arg = event
            if kind == "guard":
                return x, t, True
            x = self._transition(x, kind, arg)
        return x, t1, False

    def _transition(self, x: np.ndarray, kind: str, arg: int) -> np.ndarray:
        x = x.copy()
        if kind == "zone":
            # crossing into/out of the play: snap delta onto the edge it reached
            edge = self.z if self.z != 0 else arg
            x[2] = edge * self.db
            self.z = arg
        elif kind == "vel":
            x[1] = 0.0
            net = self.net_torque(x)
            self.s = 0 if abs(net) <= self.Tc else (1 if net > 0 else -1)
        elif kind == "stick":
            x[1] = 0.0
            self.s = arg
        return x

    def _stick(self, x: np.ndarray, u: float, L: float):
        """w = 0, delta frozen, La dI/dt = u - Ra I: I(tau) = Iinf + (I0 - Iinf) e^{-tau Ra/La}."""
        te = self.La / self.Ra
        i0, delta = float(x[0]), float(x[2])
        i_inf = u / self.Ra
        spring = self.spring_torque(delta)
        best_tau, best = math.inf, None
        # leave stick when h = sign (Kt I - spring) - Tc turns positive (slip in direction sign);
        # I moves monotonically from i0 towards i_inf, so the crossing has a closed form
        for sign in (1, -1):
            h0 = sign * (self.Kt * i0 - spring) - self.Tc
            h_inf = sign * (self.Kt * i_inf - spring) - self.Tc
            if h0 > 0.0:
                tau = 0.0
            elif h_inf > 0.0:
                i_star = (spring + sign * self.Tc) / self.Kt
                tau = -te * math.log((i_star - i_inf) / (i0 - i_inf))
            else:
                continue
            if tau <= L and tau < best_tau:
                best_tau, best = tau, ("stick", sign)
        tau = L if best is None else best_tau
        xn = np.array([i_inf + (i0 - i_inf) * math.exp(-tau / te), 0.0, delta])
        return xn, tau, best

    def _events(self, guard_mode: int, guard_rad: float) -> list[tuple[np.ndarray, float, str, int]]:
        """Affine event functions a . x + b that stay >= 0 while the slip regime holds."""
        ev: list[tuple[np.ndarray, float, str, int]] = []
        if self.gap > 0.0:
            if self.z == 1:
                ev.append((np.array([0.0, 0.0, 1.0]), -self.db, "zone", 0))
            elif self.z == -1:
                ev.append((np.array([0.0, 0.0, -1.0]), -self.db, "zone", 0))
            else:
                ev.append((np.array([0.0, 0.0, -1.0]), self.db, "zone", 1))
                ev.append((np.array([0.0, 0.0, 1.0]), self.db, "zone", -1))
        if self.Tc > 0.0:
            ev.append((np.array([0.0, float(self.s), 0.0]), 0.0, "vel", 0))
        if guard_mode:
            ev.append((np.array([0.0, 0.0, -guard_mode / self.R]), guard_rad, "guard", 0))
        return ev

    def _slip(self, x: np.ndarray, u: float, L: float, guard_mode: int, guard_rad: float):
        modal = self.modal[self.z != 0]
        # c: input, Coulomb torque against the motion, spring offset outside the play
        c = np.array([u / self.La, (self.z * self.Kd * self.db - self.Tc * self.s) / self.J, 0.0])
        y0, d = modal.coefficients(x, c)
        ev = self._events(guard_mode, guard_rad)
        n_grid = max(1, math.ceil(L / GRID_DT - 1e-9))
        taus = L * np.arange(1, n_grid + 1) / n_grid
        X = modal.states(y0, d, taus)
        if not ev:
            return X[-1], L, None
        Aev = np.array([e[0] for e in ev])
        bev = np.array([e[1] for e in ev])
        G = X @ Aev.T + bev
        neg = G < 0.0
        rows = np.flatnonzero(neg.any(axis=1))
        if len(rows) == 0:
            return X[-1], L, None
        r = int(rows[0])
        lo = float(taus[r - 1]) if r > 0 else 0.0
        hi = float(taus[r])
        g_lo = G[r - 1] if r > 0 else Aev @ x + bev
        best_tau, best = math.inf, None
        for i in np.flatnonzero(neg[r]):
            f = modal.scalar(Aev[i], float(bev[i]), y0, d)
            tau = _first_root(f, lo, hi, float(g_lo[i]))
            if tau < best_tau:
                best_tau, best = tau, (ev[i][2], ev[i][3])
        xn = modal.states(y0, d, np.array([best_tau]))[0] if best_tau > 0.0 else x.copy()
        return xn, best_tau, best


def _first_root(f, lo: float, hi: float, f_lo: float) -> float:
    """First tau in [lo, hi] where f turns negative, given f(hi) < 0 on the grid.

    When the bracket starts on the surface itself (f(lo) <= 0 at lo = 0, the
    regime was just entered there) look for a positive point inside first;
    if f never leaves the surface towards positive, the event is immediate.
    """
    if f_lo <= 0.0:
        prev, found = hi, False
        for _ in range(60):
            probe = prev * 0.5
            if f(probe) > 0.0:
                found = True
                break
            prev = probe
        if not found:
            return lo
        lo, hi = probe, prev
    if f(hi) >= 0.0:             # the grid said negative; closed form is at rounding level: take hi
        return hi
    return brentq(f, lo, hi, xtol=1e-15, rtol=1e-15)
