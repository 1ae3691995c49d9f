"""The linear automaton's per-sample loop, compiled (numba): one implementation for one set or many.

``run_linear_batch`` is the automaton of shared/MODEL.md on a linear plant: at
each sample the sketch's controller decides (the log before it starts, then
the sampled guard), the command reaches the motor ``Td`` later, and the state
moves by the exact step matrices of ``pipeline.model.linear``.  ``simulate``
calls it with one parameter set, ``simulate_batch`` with m, so the batch is
the single call's arithmetic, not a second copy of the physics that could drift.

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


@njit(cache=True)
def guard_threshold(R: float, guard: float) -> float:
    """The least delta with delta / R >= guard in floating point (R, guard > 0).

    Division rounds monotonically, so for a command d = +-1 the sampled guard
    d * (delta / R) >= guard holds exactly when d * delta >= this threshold:
    the lanes decide without dividing, and theta = delta / R is formed only
    when asked for, with the same bits.
    """
    x = guard * R
    while x / R >= guard:
        x = np.nextafter(x, -np.inf)
    while x / R < guard:
        x = np.nextafter(x, np.inf)
    return x


@njit(cache=True)
def run_linear_lanes(t, A, B, R, guard, V, x0, log, start, first, dir0, Y, dirs) -> None:
    """Closed loop without loop delay for m sets side by side: fills Y = (current, omega, delta) (3, n, m)
    and dirs (n, m); theta = delta / R is left to the caller (``guard_threshold``).

    The same automaton as ``run_linear_batch`` (``_undelayed``), laid out for
    many sets: sample k outside, the sets inside, so each set's chain of
    multiply-adds waits on its own previous sample while the other sets fill
    the pipeline, and LLVM turns the set loop into AVX arithmetic.  Past
    ``start`` the command is +-1 and ``next_dir`` is a sign flip when
    d * theta >= guard, i.e. d * delta >= ``guard_threshold`` (negation is
    exact): a select, not a branch, and no division.  Per set
    the operations and their order are the single call's, so the results are
    the same to the last bit (tests/model/test_batch.py).
    """
    lengths, idx = step_lengths(t)
    m = len(R)
    # Per length the step matrices, then the guard threshold, guard, V: one array keeps the alias checks few.
    PR = np.empty((len(lengths), 15, m))
    Pq = np.empty(12)
    for q in range(m):
        for j in range(len(lengths)):                  # one exponential per distinct length
            phi_gamma_into(A[q], B[q], lengths[j], Pq)
            PR[j, :12, q] = Pq
            PR[j, 12, q], PR[j, 13, q], PR[j, 14, q] = guard_threshold(R[q], guard[q]), guard[q], V[q]
    for q in range(m):
        th = x0[2] / R[q]
        dq = decide(0, 0, th, guard[q], log, True, start, first, dir0)
        Y[0, 0, q], Y[1, 0, q], Y[2, 0, q], dirs[0, q] = x0[0], x0[1], x0[2], dq
    for k in range(1, len(t)):
        j = idx[k - 1]
        _lanes_step(PR, j, k, Y, dirs, m)
        if k <= start:                                 # the log still rules, or the controller's first decision
            for q in range(m):
                dirs[k, q] = decide(k, int(dirs[k - 1, q]), Y[2, k, q] / R[q], guard[q], log, True, start, first, dir0)


@njit(cache=True, error_model="numpy")
def _lanes_step(PR, j, k, Y, dirs, m) -> None:
    """Every set from sample k - 1 to k, then its command by the sampled guard (unsigned indices: no
    negative-index fix-up, so the loop vectorises)."""
    for q in range(np.uint64(0), np.uint64(m)):
        I, w, dl, dq = Y[0, k - 1, q], Y[1, k - 1, q], Y[2, k - 1, q], float(dirs[k - 1, q])
        u = dq * PR[j, 14, q]
        In = PR[j, 0, q] * I + PR[j, 1, q] * w + PR[j, 2, q] * dl + PR[j, 9, q] * u
        wn = PR[j, 3, q] * I + PR[j, 4, q] * w + PR[j, 5, q] * dl + PR[j, 10, q] * u
        dn = PR[j, 6, q] * I + PR[j, 7, q] * w + PR[j, 8, q] * dl + PR[j, 11, q] * u
        dirs[k, q] = -dq if dq * dn >= PR[j, 12, q] else dq
        Y[0, k, q], Y[1, k, q], Y[2, k, q] = In, wn, dn


def linear_outputs(m: int, n: int) -> tuple[np.ndarray, ...]:
    """Output arrays for ``run_linear_batch``: current, omega, delta (m, n) float, dirs (m, n) int8.

    The three float arrays are views of one block: numpy backs a block this size
    with huge pages, where separate 4 MB arrays (1000 x 500) take a page
    fault per 4 KiB on first write -- more time than the simulation on this VM.
    """
    block = np.empty((3, m, n))
    return block[0], block[1], block[2], np.empty((m, n), dtype=np.int8)


def lane_outputs(m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Outputs for ``run_linear_lanes``: current, omega, delta as one (3, n, m) block (huge pages), dirs (n, m) int8."""
    return np.empty((3, n, m)), np.empty((n, m), dtype=np.int8)
