"""The controller around any plant, written once: the sketch's sampled guard, the motor-off start, the
command queue of the loop delay (docs/MODEL.md, hybrid automaton).  Compiled with numba.

At each sample instant the controller reads theta and decides the command
(``decide``: the log before the sketch starts or in replay, then the sampled
guard); a decision that changes the command reaches the motor ``Td`` later, so
the commands on their way form a queue of (arrival, voltage).  Between two
samples a *plant stepper* moves the state with the motor voltage piecewise
constant: ``linear.zoh_step`` (exact zero-order-hold steps of the linear
modes) or ``event_step.event_step`` (event-located steps of the non-smooth
regimes).  A stepper may stop early where the continuous guard is reached;
the controller then reverses at once.

A stepper is ``step(plant, x, k, tk, t_next, u_m, arrive, volts, head, tail, armed, guard)
-> (x, t reached, u_m, head, hit)``: it applies the queued commands landing
inside (tk, t_next) and returns at t_next unless ``hit``.  Each plant module
registers its stepper for its plant's NamedTuple class (``STEPPERS``); ``run``
calls ``step``, which numba resolves by the plant's type when it compiles, so
there is one loop, compiled (and cached) once per plant.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import overload

# Two instants closer than this are the same instant (float noise of t_ms / 1000 sums).
TIME_EPS = 1e-12
# A logged command that is not known (a row lost over serial): the sketch's rule decides it, on the model's angle.
UNKNOWN = 2


@njit(cache=True)
def next_dir(current_dir: int, theta: float, guard: float) -> int:
    """The sketch's rule: reverse when the angle has reached the guard in the direction of motion."""
    if current_dir >= 0 and theta >= guard:
        return -1
    if current_dir <= 0 and theta <= -guard:
        return 1
    return current_dir if current_dir != 0 else 1


class Controller(NamedTuple):
    """The sketch and its wiring as the loop runs them (built by ``simulate``)."""

    R: float                # m    pinion radius: theta = delta / R (eq. 7)
    guard: float            # rad  the guard the sketch reverses at
    V: float                # V    |u| of a command
    v_bias: float           # V    added to every command's voltage, the motor's only one before the first
    Td: float               # s    loop delay from deciding sample to motor
    log: np.ndarray         # int8 logged commands (-1/0/1, UNKNOWN), one per sample; empty without a log
    closed_loop: bool       # False: replay, the log drives the motor
    start: int              # first sample the sampled guard decides (closed loop; earlier ones follow the log)
    first: int              # the mode there (0: decide by ``next_dir`` from ``dir0``)
    dir0: int               # the mode the sampled guard starts from when there is no logged one
    continuous: bool        # reverse the instant theta reaches the guard instead of at the next sample


@njit(cache=True)
def decide(c: Controller, k: int, d_prev: int, theta: float) -> int:
    """The command at sample k: the log (replay, or before the sketch starts), then the sampled guard;
    an ``UNKNOWN`` entry of the log is decided by the sketch's rule too (a lost row: the loop ran there)."""
    if not c.closed_loop or k < c.start:
        if c.log[k] == UNKNOWN:
            return d_prev if d_prev == 0 else next_dir(d_prev, theta, c.guard)
        return int(c.log[k])
    if k == c.start:
        return c.first if c.first != 0 else next_dir(c.dir0, theta, c.guard)
    return next_dir(d_prev, theta, c.guard)


@njit(cache=True)
def enqueue(arrive: np.ndarray, volts: np.ndarray, head: int, tail: int, at: float, v: float):
    """Append (at, v) to the commands on their way; continuous-guard reversals may outgrow the first size."""
    if tail == len(arrive):
        live = tail - head
        grown_at, grown_v = np.empty(2 * live + 16), np.empty(2 * live + 16)
        grown_at[:live], grown_v[:live] = arrive[head:tail], volts[head:tail]
        arrive, volts, head, tail = grown_at, grown_v, 0, live
    arrive[tail] = at
    volts[tail] = v
    return arrive, volts, head, tail + 1


# plant NamedTuple class -> its compiled stepper (filled by linear.py and event_step.py)
STEPPERS: dict[type, object] = {}


def step(plant, x, k, tk, t_next, u_m, arrive, volts, head, tail, armed, guard):
    """Advance ``plant`` over one sample step: the stepper registered for its type (compiled code only)."""
    raise NotImplementedError("plant steppers run inside compiled code")


@overload(step)
def _stepper_of(plant, x, k, tk, t_next, u_m, arrive, volts, head, tail, armed, guard):
    stepper = STEPPERS.get(getattr(plant, "instance_class", None))
    if stepper is None:
        return None

    def impl(plant, x, k, tk, t_next, u_m, arrive, volts, head, tail, armed, guard):
        return stepper(plant, x, k, tk, t_next, u_m, arrive, volts, head, tail, armed, guard)
    return impl


@njit(cache=True)
def run(plant, c: Controller, t, x0, out, dirs) -> None:
    """The automaton at instants ``t``: fills ``out`` (rows current, omega, delta) and ``dirs`` (the
    command decided per sample).  The motor sees ``d * V + v_bias`` once command d has arrived, ``v_bias``
    before the first one (motor off); ``v_bias`` is how a constant torque enters (``simulate``)."""
    n = len(t)
    arrive = np.empty(n + 16)
    volts = np.empty(n + 16)
    head = tail = 0
    x = (x0[0], x0[1], x0[2])
    d = 0
    u_m = c.v_bias
    for k in range(n):
        out[0, k], out[1, k], out[2, k] = x
        dn = decide(c, k, d, x[2] / c.R)
        if dn != d or k == 0:
            arrive, volts, head, tail = enqueue(arrive, volts, head, tail, t[k] + c.Td, dn * c.V + c.v_bias)
        d = dn
        dirs[k] = d
        if k + 1 == n:
            break
        tk, t_next = t[k], t[k + 1]
        armed = d if c.continuous and k >= c.start else 0
        while True:
            while head < tail and arrive[head] <= tk + TIME_EPS:     # landed by the start of the step
                u_m = volts[head]
                head += 1
            x, tk, u_m, head, hit = step(plant, x, k, tk, t_next, u_m, arrive, volts, head, tail, armed, c.guard)
            if not hit:
                break
            # the continuous controller reverses the instant theta reaches the guard
            d = armed = -d
            arrive, volts, head, tail = enqueue(arrive, volts, head, tail, tk + c.Td, d * c.V + c.v_bias)
