"""The plant with Coulomb friction (stick mode) and backlash, advanced exactly from event to event (numba).

The state is x = [I, w, delta]; the flow is affine in x, in regimes:

- spring zone ``z``: +1 (theta > gap/2), 0 (inside the play: no spring torque),
  -1 (theta < -gap/2); the springs act on ``Ks * dz(theta)`` (MODEL.md backlash),
  i.e. ``R (K1 + K2) (delta - z R gap/2)`` outside the play.  Without backlash z = +1.
- slip direction ``s``: +1/-1 while the pinion turns (``J dw/dt`` gains
  ``-Tc * s``), 0 while it sticks: w = 0, delta frozen, only the current moves,
  as long as the net torque ``|Kt I - spring| <= Tc``.

Within a regime the exact solution is modal, ``x(tau) = Re V (e^{L tau} y0 +
phi(L, tau) d)`` with ``y0 = V^-1 x``, ``d = V^-1 c`` and ``phi = (e^{L tau} - 1)/L``
(``tau`` for the zero eigenvalue the dead zone has; ``pipeline.model.modal``).  A step of a regime is
``x+ = Phi x + Psi c`` (Phi, Psi built once per plant and step length and kept across its runs).  Every switching
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

``pipeline.model.event_step`` is this plant's stepper for the controller loop
(``pipeline.model.loop``).  Everything is compiled with numba:
the plant is a ``Plant`` tuple of arrays and dicts that the functions share,
so one simulation is one compiled call.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from pipeline.model.linear import step_key
from pipeline.model.modal import (ModalData, coefficients, event_function, first_root, gd, modal_data, state,
                                  step_matrices, zero_of_derivative)
from pipeline.model.params import PlantSpec

MAX_ZERO_LENGTH_EVENTS = 50
# Step lengths kept per regime and plant, in an open-addressing table (a power of two, filled to 3/4):
# a recording with microsecond timestamps has a few hundred distinct spacings, each split by a delay.
STEP_CAPACITY = 1024
STEP_FILL = 3 * STEP_CAPACITY // 4
# Steps shorter than this [s] are advanced without event detection (x' * 1e-12 s is far below any tolerance).
MIN_EVENT_STEP = 1e-12

# event kinds
NONE, ZONE, VEL, STICK, GUARD = 0, 1, 2, 3, 4
# indices into Plant.p
LA, RA, KT, J, B, R, KD, TC, GAP, DB, MAX_STEP = range(11)


class StepCache(NamedTuple):
    """(Phi, Psi) per regime r (0: inside the play, 1: springs engaged) by rounded step length, kept across a
    plant's runs: a start estimate and a fit replay one plant thousands of times on the same instants.  A step
    from a sample or a command's arrival is always taken with its matrices (``step_matrices``), cached or not,
    and one after an event in closed form (``_slip``), so a run's result does not depend on the runs before it."""

    keys: np.ndarray         # (2, STEP_CAPACITY), -1 where empty
    mats: np.ndarray         # (2, STEP_CAPACITY, 18)
    counts: np.ndarray       # [lengths in regime 0, in regime 1]


class Plant(NamedTuple):
    """What ``advance`` carries between calls: constants, regime (z, s) and the plant's step cache."""

    p: np.ndarray            # LA, RA, KT, J, B, R, KD, TC, GAP, DB, MAX_STEP
    md: ModalData
    zs: np.ndarray           # [z, s]
    steps: StepCache


@functools.lru_cache(maxsize=64)
def plant_constants(spec: PlantSpec) -> tuple[np.ndarray, ModalData, StepCache]:
    """The plant's constants, the eigendecompositions of its two regimes and its step cache (numpy, once per
    plant: a start estimate and a fit simulate the same plant many times; the kernels read the first two
    and fill the third)."""
    p = spec.params
    A, _ = p.state_matrices()
    A_dead = A.copy()
    A_dead[1, 2] = 0.0                      # inside the play the springs exert nothing
    md = modal_data([A_dead, A])
    # longest step with at most one extremum of any event function: < 1/2 rad of the fastest mode
    max_step = min(0.06, 0.5 / md.fastest) if md.fastest > 0 else 0.06
    Kd = p.R * (p.K1 + p.K2)                # N m per m of delta: R (K1 + K2), eq. (4)
    const = np.array([p.La, p.Ra, p.Kt, p.J, p.b, p.R, Kd, spec.Tc, spec.gap, p.R * spec.gap / 2.0, max_step],
                     dtype=float)
    cache = StepCache(np.full((2, STEP_CAPACITY), -1.0), np.empty((2, STEP_CAPACITY, 18)), np.zeros(2, dtype=np.int64))
    return const, md, cache


@njit(cache=True)
def new_plant(p: np.ndarray, md: ModalData, steps: StepCache) -> Plant:
    """A plant from ``plant_constants`` (regime z = s = +1 until ``reset``)."""
    return Plant(p, md, np.array([1, 1], dtype=np.int64), steps)


# -- regime bookkeeping -----------------------------------------------------
@njit(cache=True)
def spring_torque(pl: Plant, delta: float) -> float:
    z = pl.zs[0]
    return 0.0 if z == 0 else pl.p[KD] * (delta - z * pl.p[DB])


@njit(cache=True)
def slip_at_rest(pl: Plant, I: float, delta: float) -> int:
    """The slip direction at w = 0: stick (0) while Coulomb friction holds the net torque Kt I - spring,
    else the way that torque turns the pinion."""
    net = pl.p[KT] * I - spring_torque(pl, delta)
    return 0 if abs(net) <= pl.p[TC] else (1 if net > 0 else -1)


@njit(cache=True)
def reset(pl: Plant, x: tuple[float, float, float]) -> None:
    """Regime of a state given from outside (the initial state)."""
    p = pl.p
    if p[GAP] > 0.0:
        theta = x[2] / p[R]
        pl.zs[0] = 1 if theta > p[GAP] / 2.0 else (-1 if theta < -p[GAP] / 2.0 else 0)
    else:
        pl.zs[0] = 1
    if p[TC] <= 0.0 or x[1] > 0.0:
        pl.zs[1] = 1
    elif x[1] < 0.0:
        pl.zs[1] = -1
    else:
        pl.zs[1] = slip_at_rest(pl, x[0], x[2])


@njit(cache=True)
def step_for(pl: Plant, r: int, key: float) -> np.ndarray:
    """(Phi, Psi) of regime r for a rounded step length: from the plant's cache, else built (and kept while
    the table has room)."""
    keys = pl.steps.keys[r]
    i = (int(key * 1e9) * 2654435761) & (STEP_CAPACITY - 1)      # the length in ns, scattered
    while keys[i] >= 0.0:
        if keys[i] == key:
            return pl.steps.mats[r, i]
        i = (i + 1) & (STEP_CAPACITY - 1)
    PS = step_matrices(pl.md, r, key)
    if pl.steps.counts[r] < STEP_FILL:
        keys[i] = key
        pl.steps.mats[r, i] = PS
        pl.steps.counts[r] += 1
    return PS


# -- propagation --------------------------------------------------------------
@njit(cache=True)
def advance(pl: Plant, x: tuple[float, float, float], t0: float, t1: float, u: float, guard_mode: int,
            guard_rad: float):
    """Hold motor voltage ``u`` from t0 towards t1; stop early if the continuous guard is hit.

    ``guard_mode`` +1/-1 arms the guard theta = +/-guard_rad (the continuous
    controller in that mode); 0 disarms it.  Returns (x, t reached, hit).
    """
    t = t0
    zero_run = 0
    after_event = False          # the pieces after an event have one-off lengths: closed form, not cached
    max_step = pl.p[MAX_STEP]
    while t1 - t > 0.0:
        L = t1 - t
        if L > max_step:
            L = (t1 - t) / math.ceil((t1 - t) / max_step)
        if L < MIN_EVENT_STEP:
            # a sliver left by an event that landed within rounding of t1: at a stick/slip
            # threshold the sign of dw/dt is rounding noise there, so events are not resolved
            return _drift(pl, x, u, L), t1, False
        if pl.zs[1] == 0:
            x, tau, kind, arg = _stick(pl, x, u, L)
        else:
            x, tau, kind, arg = _slip(pl, x, u, L, guard_mode, guard_rad, after_event)
        if kind == NONE:
            t = t + L if L < t1 - t else t1
            continue
        t = min(t + tau, t1)
        after_event = True
        zero_run = zero_run + 1 if tau == 0.0 else 0
        if zero_run > MAX_ZERO_LENGTH_EVENTS:
            raise RuntimeError("nonsmooth plant: too many zero-length events in a row (chattering)")
        if kind == GUARD:
            return x, t, True
        x = _transition(pl, x, kind, arg)
    return x, t1, False


@njit(cache=True)
def _drift(pl: Plant, x, u: float, L: float):
    """Advance L in the current regime, ignoring events."""
    p = pl.p
    z, s = pl.zs[0], pl.zs[1]
    if s == 0:
        i_inf = u / p[RA]
        return (i_inf + (x[0] - i_inf) * math.exp(-L * p[RA] / p[LA]), 0.0, x[2])
    r = 1 if z != 0 else 0
    c1 = (z * p[KD] * p[DB] - p[TC] * s) / p[J]
    y0, d = coefficients(pl.md, r, x[0], x[1], x[2], u / p[LA], c1, 0.0)
    return state(pl.md, r, y0, d, L)


@njit(cache=True)
def _transition(pl: Plant, x, kind: int, arg: int):
    I, w, dl = x
    if kind == ZONE:
        # crossing into/out of the play: snap delta onto the edge it reached
        z = pl.zs[0]
        edge = z if z != 0 else arg
        dl = edge * pl.p[DB]
        pl.zs[0] = arg
    elif kind == VEL:
        w = 0.0
        pl.zs[1] = slip_at_rest(pl, I, dl)
    elif kind == STICK:
        w = 0.0
        pl.zs[1] = arg
    return (I, w, dl)


@njit(cache=True)
def _stick(pl: Plant, x, u: float, L: float):
    """w = 0, delta frozen, La dI/dt = u - Ra I: I(tau) = Iinf + (I0 - Iinf) e^{-tau Ra/La}."""
    p = pl.p
    te = p[LA] / p[RA]
    i0, delta = x[0], x[2]
    i_inf = u / p[RA]
    spring = spring_torque(pl, delta)
    best_tau, best_kind, best_arg = math.inf, NONE, 0
    # leave stick when h = sign (Kt I - spring) - Tc turns positive (slip in direction sign);
    # I moves monotonically from i0 towards i_inf, so the crossing has a closed form
    for sign in (1, -1):
        h0 = sign * (p[KT] * i0 - spring) - p[TC]
        h_inf = sign * (p[KT] * i_inf - spring) - p[TC]
        if h0 > 0.0:
            tau = 0.0
        elif h_inf > 0.0:
            i_star = (spring + sign * p[TC]) / p[KT]
            tau = -te * math.log((i_star - i_inf) / (i0 - i_inf))
        else:
            continue
        if tau <= L and tau < best_tau:
            best_tau, best_kind, best_arg = tau, STICK, sign
    tau = L if best_kind == NONE else best_tau
    return (i_inf + (i0 - i_inf) * math.exp(-tau / te), 0.0, delta), tau, best_kind, best_arg


@njit(cache=True)
def _event_row(ev: np.ndarray, n: int, a2: float, b: float, kind: int, arg: int, aR: float) -> int:
    """Row n of ``_events`` for a position surface a2 delta + b >= 0; returns n + 1."""
    ev[n, 0], ev[n, 1], ev[n, 2], ev[n, 3], ev[n, 4], ev[n, 5], ev[n, 6] = 0.0, 0.0, a2, b, kind, arg, aR
    return n + 1


@njit(cache=True)
def _events(pl: Plant, guard_mode: int, guard_rad: float) -> np.ndarray:
    """Affine event functions, rows (a0, a1, a2, b, kind, arg, aR): a . x + b >= 0 while the slip regime holds.

    ``aR`` = a2 * R gives g' = aR * w for the position surfaces (edges, guard);
    for ``vel`` g' = s * dw/dt.
    """
    p = pl.p
    z, s = pl.zs[0], pl.zs[1]
    db, Rr = p[DB], p[R]
    ev = np.empty((4, 7))
    n = 0
    if p[GAP] > 0.0:
        if z == 1:
            n = _event_row(ev, n, 1.0, -db, ZONE, 0, Rr)
        elif z == -1:
            n = _event_row(ev, n, -1.0, -db, ZONE, 0, -Rr)
        else:
            n = _event_row(ev, n, -1.0, db, ZONE, 1, -Rr)
            n = _event_row(ev, n, 1.0, db, ZONE, -1, Rr)
    if p[TC] > 0.0:
        ev[n, 0], ev[n, 1], ev[n, 2], ev[n, 3], ev[n, 4], ev[n, 5], ev[n, 6] = 0.0, float(s), 0.0, 0.0, VEL, 0, 0.0
        n += 1
    if guard_mode:
        n = _event_row(ev, n, -guard_mode / Rr, guard_rad, GUARD, 0, -guard_mode)
    return ev[:n]


@njit(cache=True)
def _suspect(pl: Plant, ev: np.ndarray, x, xe, c1: float) -> bool:
    """May event ``ev`` have fired within a step x -> xe: g(end) < 0, or a dip (g' - then +)?"""
    p = pl.p
    I, w, dl = x
    a1, a2, b = ev[1], ev[2], ev[3]
    ge = a1 * xe[1] + a2 * xe[2] + b
    if ge < 0.0:
        return True
    if a1 * w + a2 * dl + b < 0.0:
        return False
    if ev[4] == VEL:
        spring0 = p[KD] * dl if pl.zs[0] != 0 else 0.0
        springe = p[KD] * xe[2] if pl.zs[0] != 0 else 0.0
        gp0 = a1 * ((p[KT] * I - p[B] * w - spring0) / p[J] + c1)
        gpe = a1 * ((p[KT] * xe[0] - p[B] * xe[1] - springe) / p[J] + c1)
    else:
        gp0, gpe = ev[6] * w, ev[6] * xe[1]
    return gp0 < 0.0 < gpe                       # otherwise no crossing and no dip: the regime holds


@njit(cache=True)
def _slip(pl: Plant, x, u: float, L: float, guard_mode: int, guard_rad: float, one_off: bool):
    p = pl.p
    z = pl.zs[0]
    r = 1 if z != 0 else 0
    # c: input, Coulomb torque against the motion, spring offset outside the play
    c0 = u / p[LA]
    c1 = (z * p[KD] * p[DB] - p[TC] * pl.zs[1]) / p[J]
    # a step from a sample or a command's arrival has a length the run meets again: the plant's step matrices;
    # one that ends what an event began has a length of its own: the closed form.  Which one is taken depends on
    # the step alone, never on what the cache holds, so a run's bits do not depend on the runs before it.
    if one_off:
        y0, d = coefficients(pl.md, r, x[0], x[1], x[2], c0, c1, 0.0)
        have_coeffs = True
        xe = state(pl.md, r, y0, d, L)
    else:
        PS = step_for(pl, r, step_key(L))
        y0 = d = np.empty(0, dtype=np.complex128)
        have_coeffs = False
        I, w, dl = x
        xe = (PS[0] * I + PS[1] * w + PS[2] * dl + PS[9] * c0 + PS[10] * c1,
              PS[3] * I + PS[4] * w + PS[5] * dl + PS[12] * c0 + PS[13] * c1,
              PS[6] * I + PS[7] * w + PS[8] * dl + PS[15] * c0 + PS[16] * c1)
    events = _events(pl, guard_mode, guard_rad)
    best_tau, best_kind, best_arg = math.inf, NONE, 0
    for i in range(len(events)):
        ev = events[i]
        if not _suspect(pl, ev, x, xe, c1):
            continue
        if not have_coeffs:
            y0, d = coefficients(pl.md, r, x[0], x[1], x[2], c0, c1, 0.0)
            have_coeffs = True
        a0, a1, a2, b = ev[0], ev[1], ev[2], ev[3]
        F = event_function(pl.md, r, a0, a1, a2, b, y0, d)
        g0, gp0 = a1 * x[1] + a2 * x[2] + b, gd(F, 0.0)[1]
        ge = a1 * xe[1] + a2 * xe[2] + b
        if ge >= 0.0:
            t_min = zero_of_derivative(F, 0.0, L)
            # a dip below the surface by rounding only (e.g. break-away with the net torque
            # exactly at Tc, where g'(0) is 0 up to rounding) is not an event
            tol = max(1e-12 * (abs(a1 * x[1]) + abs(a2 * x[2]) + abs(a1 * xe[1]) + abs(a2 * xe[2]) + abs(b)), F[2])
            if gd(F, t_min)[0] >= -tol:
                continue                      # the dip stays above the surface
            hi = t_min
        else:
            hi = L
        tau = first_root(F, hi, g0, gp0)
        if tau < best_tau:
            best_tau, best_kind, best_arg = tau, int(ev[4]), int(ev[5])
    if best_kind == NONE:
        return xe, L, NONE, 0
    xn = state(pl.md, r, y0, d, best_tau) if best_tau > 0.0 else x
    return xn, best_tau, best_kind, best_arg
