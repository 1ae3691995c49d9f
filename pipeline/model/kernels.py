"""The linear automaton's per-sample loop, compiled (numba): one implementation for one set or many.

``run_linear_batch`` is the automaton of shared/MODEL.md on a linear plant: at
each sample the sketch's controller decides (the log before it starts, then
the sampled guard), the command reaches the motor ``Td`` later, and the state
moves by the exact step matrices of ``pipeline.model.linear``.  ``simulate``
calls it with one parameter set; ``simulate_batch`` runs the same steps laid out
in lanes (``pipeline.model.lanes``: the sets side by side, this module's
``decide`` and the same sums in the same order), tested equal to the last bit.

Plain float arithmetic in a compiled loop: CPython spent ~1 us per sample on
it, this spends a few ns.  The order of every sum is the one the Python loops
had, so the results are the same to the last bit (or within an ulp where numba's
``round`` and CPython's differ in the last digit of a step length).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from pipeline.model.linear import phi_gamma_into, step_key, step_lengths

# Split lengths remembered per set in the delayed loop (a Td landing inside steps of a few lengths).
MAX_SPLIT_LENGTHS = 8
# Two instants closer than this are the same instant (float noise of t_ms / 1000 sums).
TIME_EPS = 1e-12


@njit(cache=True)
def next_dir(current_dir: int, theta: float, guard: float) -> int:
    """The sketch's rule: reverse when the angle has reached the guard in the direction of motion."""
    if current_dir >= 0 and theta >= guard:
        return -1
    if current_dir <= 0 and theta <= -guard:
        return 1
    return current_dir if current_dir != 0 else 1


@njit(cache=True)
def decide(k: int, d_prev: int, theta: float, guard: float, log: np.ndarray, closed_loop: bool,
           start: int, first: int, dir0: int) -> int:
    """The command at sample k: the log (replay, or before the sketch starts), then the sampled guard.

    ``start`` is the first sample the controller decides and ``first`` its mode
    there (0: decide by ``next_dir`` from ``dir0``); see ``simulate._plan``.
    """
    if not closed_loop or k < start:
        return int(log[k])
    if k == start:
        return first if first != 0 else next_dir(dir0, theta, guard)
    return next_dir(d_prev, theta, guard)


@njit(cache=True)
def run_linear_batch(t, A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0,
                     current, omega, delta, dirs) -> None:
    """The automaton for m parameter sets at the instants ``t``: fills current, omega, delta, dirs (m, n).

    A (m, 3, 3), B (m, 3); R, guard, V, Td (m,).  ``simulate`` is the case m = 1.
    The sets share the instants, hence the distinct step lengths (``step_lengths``).
    theta = delta / R (eq. 7) is the caller's, as for every kernel.
    """
    lengths, idx = step_lengths(t)
    P = np.empty((len(lengths), 12))
    for i in range(len(R)):
        for j in range(len(lengths)):                  # one exponential per distinct length
            phi_gamma_into(A[i], B[i], lengths[j], P[j])
        if closed_loop and Td[i] == 0.0:
            _undelayed(t, P, idx, R[i], guard[i], V[i], x0, log, start, first, dir0,
                       current[i], omega[i], delta[i], dirs[i])
        else:
            _delayed(t, P, idx, A[i], B[i], R[i], guard[i], V[i], Td[i], x0, log, closed_loop, start, first, dir0,
                     current[i], omega[i], delta[i], dirs[i])


@njit(cache=True)
def _undelayed(t, P, idx, R, guard, V, x0, log, start, first, dir0, current, omega, delta, dirs) -> None:
    """The hot path (closed loop, no loop delay): the command acts at once, u = d * v_drive."""
    n = len(t)
    I, w, dl = x0[0], x0[1], x0[2]
    d = decide(0, 0, dl / R, guard, log, True, start, first, dir0)
    u = d * V
    current[0], omega[0], delta[0], dirs[0] = I, w, dl, d
    for k in range(1, n):
        j = idx[k - 1]                  # indexing P[j, .] directly: a row view would cost a refcount per step
        I, w, dl = (P[j, 0] * I + P[j, 1] * w + P[j, 2] * dl + P[j, 9] * u,
                    P[j, 3] * I + P[j, 4] * w + P[j, 5] * dl + P[j, 10] * u,
                    P[j, 6] * I + P[j, 7] * w + P[j, 8] * dl + P[j, 11] * u)
        dn = decide(k, d, dl / R, guard, log, True, start, first, dir0)
        if dn != d:
            d = dn
            u = d * V
        current[k], omega[k], delta[k], dirs[k] = I, w, dl, d


@njit(cache=True)
def _delayed(t, P, idx, A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0,
             current, omega, delta, dirs) -> None:
    """Any plan with a loop delay: x+ = Phi(h) x + Gamma(h) u0 + sum over motor changes at a of Gamma(h - a) du.

    A command decided at t_k reaches the motor at t_k + Td; the arrivals are in
    order, so the commands on their way are a queue (``arrive``/``volts``).
    """
    n = len(t)
    arrive = np.empty(n)
    volts = np.empty(n)
    head = tail = 0
    G = np.empty(12)
    # Gamma(h - a) per split length: with a fixed Td the splits repeat a few lengths (50/51 ms minus Td, ...)
    split_keys = np.empty(MAX_SPLIT_LENGTHS)
    split_gamma = np.empty((MAX_SPLIT_LENGTHS, 3))
    n_split = 0
    I, w, dl = x0[0], x0[1], x0[2]
    d = 0
    u_m = 0.0                                        # motor voltage; off until the first command
    for k in range(n):
        current[k], omega[k], delta[k] = I, w, dl
        dn = decide(k, d, dl / R, guard, log, closed_loop, start, first, dir0)
        if dn != d or k == 0:
            arrive[tail] = t[k] + Td
            volts[tail] = dn * V
            tail += 1
        d = dn
        dirs[k] = d
        if k + 1 == n:
            break
        tk, t_next = t[k], t[k + 1]
        h = t_next - tk
        j = idx[k]
        u0 = u_m
        e0 = e1 = e2 = 0.0
        changed = False
        while head < tail and arrive[head] < t_next - TIME_EPS:
            du = volts[head] - u_m
            u_m = volts[head]
            a = arrive[head] - tk
            head += 1
            if du != 0.0:                            # a change at a inside the step: Gamma(h - a) du
                changed = True
                if a <= TIME_EPS:
                    e0 += P[j, 9] * du
                    e1 += P[j, 10] * du
                    e2 += P[j, 11] * du
                else:
                    key = step_key(h - a)
                    c = 0
                    while c < n_split and split_keys[c] != key:
                        c += 1
                    if c == n_split:                 # a split length not seen yet (few: Td is fixed)
                        if n_split == len(split_keys):
                            c = n_split = 0
                        phi_gamma_into(A, B, key, G)
                        split_keys[c] = key
                        split_gamma[c, 0], split_gamma[c, 1], split_gamma[c, 2] = G[9], G[10], G[11]
                        n_split += 1
                    e0 += split_gamma[c, 0] * du
                    e1 += split_gamma[c, 1] * du
                    e2 += split_gamma[c, 2] * du
        if changed:
            I, w, dl = (P[j, 0] * I + P[j, 1] * w + P[j, 2] * dl + P[j, 9] * u0 + e0,
                        P[j, 3] * I + P[j, 4] * w + P[j, 5] * dl + P[j, 10] * u0 + e1,
                        P[j, 6] * I + P[j, 7] * w + P[j, 8] * dl + P[j, 11] * u0 + e2)
        else:                                        # most steps: adding e = 0 would only lengthen the chain
            I, w, dl = (P[j, 0] * I + P[j, 1] * w + P[j, 2] * dl + P[j, 9] * u0,
                        P[j, 3] * I + P[j, 4] * w + P[j, 5] * dl + P[j, 10] * u0,
                        P[j, 6] * I + P[j, 7] * w + P[j, 8] * dl + P[j, 11] * u0)


def linear_outputs(m: int, n: int) -> tuple[np.ndarray, ...]:
    """Output arrays for ``run_linear_batch``: current, omega, delta (m, n) float, dirs (m, n) int8.

    The three float arrays are views of one block: numpy backs a block this size
    with huge pages, where separate 4 MB arrays (1000 x 500) take a page
    fault per 4 KiB on first write -- more time than the simulation on this VM.
    """
    block = np.empty((3, m, n))
    return block[0], block[1], block[2], np.empty((m, n), dtype=np.int8)

