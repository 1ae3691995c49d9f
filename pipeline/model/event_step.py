"""The event-driven plant's stepper for the controller loop (``pipeline.model.loop``), compiled (numba).

Most steps of a run hold no event: ``quick_entry``/``quick_step`` take the
regime's cached whole step and check, from its two ends, that no switching
surface was crossed; only otherwise does ``nonsmooth.advance`` locate the
events.  ``run_events`` is the automaton on this plant.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pipeline.model.linear import step_key
from pipeline.model.loop import STEPPERS, TIME_EPS, run
from pipeline.model.nonsmooth import (B, DB, GAP, KD, KT, LA, MAX_STEP, RA, TC, J, R, Plant, advance, new_plant,
                                      reset, spring_torque, step_for)


@njit(cache=True)
def quick_entry(pl: Plant, u: float, L: float, guard_mode: int, guard_rad: float) -> np.ndarray:
    """The whole-step shortcut for the current regime, or an empty array when only ``advance`` will do.

    Returns ``(P0..P8, q0, q1, q2, lo, hi, s, k0, k1, k2, k3)``: the step is
    ``x+ = P x + q``; it is event-free when delta+ stays in [lo, hi] (backlash
    edges and the armed guard are all bounds on delta) with w keeping its sign
    when a bound is finite (delta monotone, so the ends bound the step), and,
    with Coulomb friction, s w+ >= 0 without a dip of s w (s dw/dt = s (k0 I +
    k1 w + k2 delta + k3) not going from - to +).  In stick (s = 0) the step is
    the current's exponential, event-free when |Kt I+ - spring| <= Tc (I is
    monotone, so the end bounds the step).  ``quick_step`` applies the test.
    """
    p = pl.p
    z, s = pl.zs[0], pl.zs[1]
    if L > p[MAX_STEP]:
        return np.empty(0)
    if s == 0:
        e = math.exp(-L * p[RA] / p[LA])
        return np.array([e, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, (1.0 - e) * u / p[RA], 0.0, 0.0,
                         -math.inf, math.inf, 0.0, p[KT], 0.0, 0.0, 0.0])
    PS = step_for(pl, 1 if z != 0 else 0, step_key(L))
    c0 = u / p[LA]
    c1 = (z * p[KD] * p[DB] - p[TC] * s) / p[J]
    lo, hi = -math.inf, math.inf
    if p[GAP] > 0.0:
        if z == 1:
            lo = p[DB]
        elif z == 0:
            lo, hi = -p[DB], p[DB]
        else:
            hi = -p[DB]
    if guard_mode > 0:
        hi = min(hi, guard_rad * p[R])
    elif guard_mode < 0:
        lo = max(lo, -guard_rad * p[R])
    kd = p[KD] if z != 0 else 0.0
    slip = s if p[TC] > 0.0 else 0
    return np.array([PS[0], PS[1], PS[2], PS[3], PS[4], PS[5], PS[6], PS[7], PS[8],
                     PS[9] * c0 + PS[10] * c1, PS[12] * c0 + PS[13] * c1, PS[15] * c0 + PS[16] * c1,
                     lo, hi, float(slip), p[KT] / p[J], -p[B] / p[J], -kd / p[J], c1])


@njit(cache=True)
def quick_step(pl: Plant, e: np.ndarray, x):
    """x+ of a quick entry and whether the step is event-free (see ``quick_entry``)."""
    I, w, dl = x
    Ie = e[0] * I + e[1] * w + e[2] * dl + e[9]
    we = e[3] * I + e[4] * w + e[5] * dl + e[10]
    de = e[6] * I + e[7] * w + e[8] * dl + e[11]
    p = pl.p
    lo, hi, sl = e[12], e[13], e[14]
    if pl.zs[1] == 0:
        net = p[KT] * Ie - spring_torque(pl, dl)
        ok = -p[TC] <= net <= p[TC]
    else:
        ok = lo <= de <= hi and ((w > 0.0) == (we > 0.0) or (lo == -math.inf and hi == math.inf))
        if ok and sl:
            k0, k1, k2, k3 = e[15], e[16], e[17], e[18]
            ok = sl * we >= 0.0 and not (
                sl * (k0 * I + k1 * w + k2 * dl + k3) < 0.0 < sl * (k0 * Ie + k1 * we + k2 * de + k3))
    return (Ie, we, de), ok


@njit(cache=True)
def event_step(pl: Plant, x, k, tk, t_next, u_m, arrive, volts, head, tail, armed, guard):
    """From tk to t_next through the commands landing inside (``pipeline.model.loop``'s stepper).

    Each piece first tries the cached whole step of the regime (``quick_entry``)
    and hands over to ``advance`` when that may hold an event; returns early,
    with ``hit``, where the armed continuous guard is reached.
    """
    while True:
        while head < tail and arrive[head] <= tk + TIME_EPS:
            u_m = volts[head]
            head += 1
        if head < tail and arrive[head] < t_next - TIME_EPS:
            stop = arrive[head]               # a delayed command lands inside this step
        else:
            stop = t_next
        # lengths rounded like the step caches' keys, so repeated spacings hit the same entry
        L = step_key(stop - tk)
        e = quick_entry(pl, u_m, L, armed, guard)
        if len(e):
            xq, ok = quick_step(pl, e, x)
            if ok:
                x, tk = xq, stop
                if stop == t_next:
                    return x, tk, u_m, head, False
                continue
        x, tk, hit = advance(pl, x, tk, stop, u_m, armed, guard)
        if hit or stop == t_next:
            return x, tk, u_m, head, hit


STEPPERS[Plant] = event_step


@njit(cache=True)
def run_events(p, md, steps, c, t, x0, out, dirs) -> None:
    """The automaton on the event-driven plant (``loop.run``): stick/slip, backlash edges, the continuous guard."""
    pl = new_plant(p, md, steps)
    reset(pl, (x0[0], x0[1], x0[2]))
    run(pl, c, t, x0, out, dirs)
