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
(``tau`` for the zero eigenvalue the dead zone has; ``pipeline.model.modal``).  A step of a regime is
``x+ = Phi x + Psi c`` (Phi, Psi cached per step length).  Every switching
surface is affine in the state (theta = +/-gap/2, w = 0, net torque = +/-Tc,
theta = +/-guard), so each event function g = a.x + b is a sum of three
exponentials in tau.  A step is accepted when g stays >= 0 at its end and shows
no dip (g' < 0 at the start and > 0 at the end with g(min) < 0); steps are
never longer than a fraction of the plant's fastest period, so g has at most
one extremum inside.  Otherwise the first root is found by safeguarded Newton
on the closed form (to ~1e-15 s).  In stick the current is a single
exponential, so break-away is solved in closed form.  States are snapped onto
the surface they reached (w = 0 exactly, delta = +/-R gap/2 exactly), so a
stuck pinion stays exactly still and a regime never re-fires at its entry.

Everything per step is plain Python float arithmetic: numpy's per-call
overhead would dominate 3x3 work (see ``benchmarks/bench_model.py``).
"""

from __future__ import annotations

import math

from pipeline.model.effects import PlantSpec
from pipeline.model.modal import Modal, State, first_root, zero_of_derivative

MAX_ZERO_LENGTH_EVENTS = 50
# Steps shorter than this [s] are advanced without event detection (x' * 1e-12 s is far below any tolerance).
MIN_EVENT_STEP = 1e-12


class NonsmoothPlant:
    """Carries the regime (z, s) between calls of ``advance``; the simulator owns the timing."""

    def __init__(self, spec: PlantSpec) -> None:
        p = spec.params
        self.La, self.Ra, self.Ke, self.Kt, self.J, self.b, self.R = p.La, p.Ra, p.Ke, p.Kt, p.J, p.b, p.R
        self.Kd = p.R * (p.K1 + p.K2)          # N m per m of delta: R (K1 + K2), eq. (4)
        self.Tc = spec.Tc
        self.gap = spec.gap
        self.db = p.R * spec.gap / 2.0          # m   half play in rack displacement
        A, _ = p.state_matrices()
        A_dead = A.copy()
        A_dead[1, 2] = 0.0                      # inside the play the springs exert nothing
        self.modal = {True: Modal(A), False: Modal(A_dead)}
        # longest step with at most one extremum of any event function: < 1/2 rad of the fastest mode
        fastest = max(m.fastest for m in self.modal.values())
        self.max_step = min(0.06, 0.5 / fastest) if fastest > 0 else 0.06
        self.z = 1
        self.s = 1
        self._event_cache: dict[tuple[int, int, int], list[tuple]] = {}
        self._quick: dict[tuple, tuple | None] = {}

    # -- regime bookkeeping -------------------------------------------------
    def spring_torque(self, delta: float) -> float:
        return 0.0 if self.z == 0 else self.Kd * (delta - self.z * self.db)

    def net_torque(self, x: State) -> float:
        """Torque that Coulomb friction has to hold at w = 0: Kt I - spring."""
        return self.Kt * x[0] - self.spring_torque(x[2])

    def reset(self, x: State) -> None:
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
    def advance(self, x: State, t0: float, t1: float, u: float, guard_mode: int = 0,
                guard_rad: float = 0.0) -> tuple[State, float, bool]:
        """Hold motor voltage ``u`` from t0 towards t1; stop early if the continuous guard is hit.

        ``guard_mode`` +1/-1 arms the guard theta = +/-guard_rad (the continuous
        controller in that mode); 0 disarms it.  Returns (x, t reached, hit).
        """
        t = t0
        zero_run = 0
        while t1 - t > 0.0:
            L = t1 - t
            if L > self.max_step:
                L = (t1 - t) / math.ceil((t1 - t) / self.max_step)
            if L < MIN_EVENT_STEP:
                # a sliver left by an event that landed within rounding of t1: at a stick/slip
                # threshold the sign of dw/dt is rounding noise there, so events are not resolved
                return self._drift(x, u, L), t1, False
            if self.s == 0:
                x, tau, event = self._stick(x, u, L)
            else:
                x, tau, event = self._slip(x, u, L, guard_mode, guard_rad)
            if event is None:
                t = t + L if L < t1 - t else t1
                continue
            t = min(t + tau, t1)
            zero_run = zero_run + 1 if tau == 0.0 else 0
            if zero_run > MAX_ZERO_LENGTH_EVENTS:
                raise RuntimeError(f"nonsmooth plant: {zero_run} zero-length events at t={t:.9g} s (chattering)")
            kind, arg = event
            if kind == "guard":
                return x, t, True
            x = self._transition(x, kind, arg)
        return x, t1, False

    def _drift(self, x: State, u: float, L: float) -> State:
        """Advance L in the current regime, ignoring events."""
        if self.s == 0:
            i_inf = u / self.Ra
            return (i_inf + (x[0] - i_inf) * math.exp(-L * self.Ra / self.La), 0.0, x[2])
        modal = self.modal[self.z != 0]
        c1 = (self.z * self.Kd * self.db - self.Tc * self.s) / self.J
        return modal.state(*modal.coefficients(x, (u / self.La, c1, 0.0)), L)

    def _transition(self, x: State, kind: str, arg: int) -> State:
        I, w, dl = x
        if kind == "zone":
            # crossing into/out of the play: snap delta onto the edge it reached
            edge = self.z if self.z != 0 else arg
            dl = edge * self.db
            self.z = arg
        elif kind == "vel":
            w = 0.0
            net = self.net_torque((I, w, dl))
            self.s = 0 if abs(net) <= self.Tc else (1 if net > 0 else -1)
        elif kind == "stick":
            w = 0.0
            self.s = arg
        return (I, w, dl)

    def _stick(self, x: State, u: float, L: float):
        """w = 0, delta frozen, La dI/dt = u - Ra I: I(tau) = Iinf + (I0 - Iinf) e^{-tau Ra/La}."""
        te = self.La / self.Ra
        i0, delta = x[0], x[2]
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
        return (i_inf + (i0 - i_inf) * math.exp(-tau / te), 0.0, delta), tau, best

    def _events(self, guard_mode: int, guard_rad: float) -> list[tuple]:
        """Affine event functions (a0, a1, a2, b, kind, arg, aR): a . x + b >= 0 while the slip regime holds.

        Cached per regime.  ``aR`` = a2 * R gives g' = aR * w for the position
        surfaces (edges, guard); for ``vel`` g' = s * dw/dt.
        """
        key = (self.z, self.s, guard_mode)
        ev = self._event_cache.get(key)
        if ev is not None:
            return ev
        ev = []
        db, R = self.db, self.R
        if self.gap > 0.0:
            if self.z == 1:
                ev.append((0.0, 0.0, 1.0, -db, "zone", 0, R))
            elif self.z == -1:
                ev.append((0.0, 0.0, -1.0, -db, "zone", 0, -R))
            else:
                ev.append((0.0, 0.0, -1.0, db, "zone", 1, -R))
                ev.append((0.0, 0.0, 1.0, db, "zone", -1, R))
        if self.Tc > 0.0:
            ev.append((0.0, float(self.s), 0.0, 0.0, "vel", 0, 0.0))
        if guard_mode:
            ev.append((0.0, 0.0, -guard_mode / R, guard_rad, "guard", 0, -guard_mode))
        self._event_cache[key] = ev
        return ev

    def _suspects(self, x: State, xe: State, c1: float, events: list[tuple]) -> list[tuple]:
        """Event functions that may have fired within a step x -> xe: g(end) < 0, or a dip (g' - then +)."""
        out = []
        I, w, dl = x
        for ev in events:
            a1, a2, b = ev[1], ev[2], ev[3]
            ge = a1 * xe[1] + a2 * xe[2] + b
            if ge >= 0.0:
                if a1 * w + a2 * dl + b < 0.0:
                    continue
                if ev[4] == "vel":
                    spring0 = self.Kd * dl if self.z != 0 else 0.0
                    springe = self.Kd * xe[2] if self.z != 0 else 0.0
                    gp0 = a1 * ((self.Kt * I - self.b * w - spring0) / self.J + c1)
                    gpe = a1 * ((self.Kt * xe[0] - self.b * xe[1] - springe) / self.J + c1)
                else:
                    gp0, gpe = ev[6] * w, ev[6] * xe[1]
                if not (gp0 < 0.0 < gpe):
                    continue                      # no crossing and no dip: the regime holds
            out.append((ev, ge))
        return out

    def quick_entry(self, u: float, L: float, guard_mode: int, guard_rad: float) -> tuple | None:
        """The whole-step shortcut for the current regime, or None when only ``advance`` will do.

        Returns ``(P0..P8, q0, q1, q2, lo, hi, s, k0, k1, k2, k3)``: the step is
        ``x+ = P x + q``; it is event-free when delta+ stays in [lo, hi] (backlash
        edges and the armed guard are all bounds on delta) with w keeping its sign
        when a bound is finite (delta monotone, so the ends bound the step), and,
        with Coulomb friction, s w+ >= 0 without a dip of s w (s dw/dt = s (k0 I +
        k1 w + k2 delta + k3) not going from - to +).  In stick (s = 0) the step is
        the current's exponential, event-free when |Kt I+ - spring| <= Tc (I is
        monotone, so the end bounds the step): then lo = hi = the frozen delta's
        spring torque and k0 = Kt.  The simulator inlines the test; entries are
        cached per (regime, u, L, guard).
        """
        key = (self.z, self.s, u, L, guard_mode)
        entry = self._quick.get(key)
        if entry is not None or key in self._quick:
            return entry
        z, s = self.z, self.s
        if L > self.max_step:
            entry = None
        elif s == 0:
            e = math.exp(-L * self.Ra / self.La)
            entry = (e, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, (1.0 - e) * u / self.Ra, 0.0, 0.0,
                     -math.inf, math.inf, 0, self.Kt, 0.0, 0.0, 0.0)
        else:
            modal = self.modal[z != 0]
            PS = modal.raw.get(L) or modal.cached(L)
            if PS is None:
                return None                       # not cached yet: ``advance`` builds it on repeat
            P, S = PS
            c0 = u / self.La
            c1 = (z * self.Kd * self.db - self.Tc * s) / self.J
            q = (S[0] * c0 + S[1] * c1, S[3] * c0 + S[4] * c1, S[6] * c0 + S[7] * c1)
            lo, hi = -math.inf, math.inf
            if self.gap > 0.0:
                lo, hi = {1: (self.db, math.inf), 0: (-self.db, self.db), -1: (-math.inf, -self.db)}[z]
            if guard_mode > 0:
                hi = min(hi, guard_rad * self.R)
            elif guard_mode < 0:
                lo = max(lo, -guard_rad * self.R)
            kd = self.Kd if z != 0 else 0.0
            slip = s if self.Tc > 0.0 else 0
            entry = (*P, *q, lo, hi, slip, self.Kt / self.J, -self.b / self.J, -kd / self.J, c1)
        self._quick[key] = entry
        return entry

    def _slip(self, x: State, u: float, L: float, guard_mode: int, guard_rad: float):
        z = self.z
        modal = self.modal[z != 0]
        # c: input, Coulomb torque against the motion, spring offset outside the play
        c0 = u / self.La
        c1 = (z * self.Kd * self.db - self.Tc * self.s) / self.J
        coeffs = None
        PS = modal.raw.get(L)
        if PS is None and not modal.seen(L):
            coeffs = modal.coefficients(x, (c0, c1, 0.0))      # a one-off length: closed form, no matrices
            xe = modal.state(*coeffs, L)
        else:
            P, S = PS or modal.step(L)
            I, w, dl = x
            xe = (P[0] * I + P[1] * w + P[2] * dl + S[0] * c0 + S[1] * c1,
                  P[3] * I + P[4] * w + P[5] * dl + S[3] * c0 + S[4] * c1,
                  P[6] * I + P[7] * w + P[8] * dl + S[6] * c0 + S[7] * c1)
        events = self._events(guard_mode, guard_rad)
        suspects = self._suspects(x, xe, c1, events) if events else ()
        if not suspects:
            return xe, L, None
        if coeffs is None:
            coeffs = modal.coefficients(x, (c0, c1, 0.0))
        best_tau, best = math.inf, None
        for (a0, a1, a2, b, kind, arg, _), ge in suspects:
            gd = modal.event_function((a0, a1, a2), b, *coeffs)
            g0, gp0 = a1 * x[1] + a2 * x[2] + b, gd(0.0)[1]
            if ge >= 0.0:
                t_min = zero_of_derivative(gd, 0.0, L)
                # a dip below the surface by rounding only (e.g. break-away with the net torque
                # exactly at Tc, where g'(0) is 0 up to rounding) is not an event
                tol = max(1e-12 * (abs(a1 * x[1]) + abs(a2 * x[2]) + abs(a1 * xe[1]) + abs(a2 * xe[2]) + abs(b)),
                          gd.noise)
                if gd(t_min)[0] >= -tol:
                    continue                      # the dip stays above the surface
                hi = t_min
            else:
                hi = L
            tau = first_root(gd, hi, g0, gp0)
            if tau < best_tau:
                best_tau, best = tau, (kind, arg)
        if best is None:
            return xe, L, None
        xn = modal.state(*coeffs, best_tau) if best_tau > 0.0 else x
        return xn, best_tau, best
