"""The commands in flight at a recording's first sample: when they were decided, which sequences are
worth trying, and the weighted least squares that scores each (``initial_state``'s linear step).

Under a loop delay Td the commands decided before the first sample still reach the motor after it;
they are -1, 0 or +1, so every plausible sequence is tried and the most probable kept, each change
of command charged its prior odds.
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np

# A command change among the pre-log commands is a priori unlikely: the rig reverses about once
# in 35 samples.  A change costs 2 ln 35 ~ 7 in the weighted squared residual (-2 log of its prior
# odds), so it is chosen only when the data ask for it (a pulse of the other command and a
# different initial current can explain the first samples almost equally well).
SWITCH_PENALTY = 2.0 * np.log(35.0)


def lead_offsets(delay_s: float, period_s: float) -> np.ndarray:
    """Instants (relative to t0, < 0) of the pre-log commands that reach the motor after t0."""
    if delay_s <= 0.0:
        return np.zeros(0)
    js = [j for j in range(1, int(np.ceil(delay_s / period_s)) + 1) if j * period_s < delay_s - 1e-9]
    return np.array([-delay_s] + [-j * period_s for j in sorted(js, reverse=True)])


@lru_cache(maxsize=None)
def command_sequences(m: int) -> tuple[tuple[int, ...], ...]:
    """Pre-log command sequences worth trying: one value, then perhaps another (at most one
    change of command within a loop delay: the rig reverses every ~1.7 s)."""
    if m == 0:
        return ((),)
    out = {(a,) * k + (b,) * (m - k) for a, b in itertools.product((-1, 0, 1), repeat=2) for k in range(m + 1)}
    return tuple(sorted(out))


def changes(commands: tuple[int, ...], first: int) -> int:
    """How often the command changes along the pre-log ``commands`` and into the first logged one."""
    seq = (*commands, first)
    return sum(a != b for a, b in zip(seq[:-1], seq[1:]))


class InFlight:
    """Every pre-log command sequence worth trying (``command_sequences``) for one start estimate, with the
    response to each (the pulse responses ``P`` summed, once: the estimate asks after every reweighting)."""

    def __init__(self, P: np.ndarray) -> None:
        self.m = m = P.shape[1]
        self.sequences = command_sequences(m)
        # one matrix-vector product per sequence: a product of the stacked sequences would be large enough,
        # under a long loop delay, for the BLAS to wake its threads, which then spin on the other core
        self.responses = np.stack([P @ np.asarray(c, dtype=float) for c in self.sequences]) if m else \
            np.zeros((1, P.shape[0]))

    def fit(self, r0: np.ndarray, F: np.ndarray, w: np.ndarray,
            first: int) -> list[tuple[float, tuple[int, ...], np.ndarray]]:
        """(cost, pre-log commands, coefficients) of every sequence under weights ``w``, most probable first;
        the cost is the weighted squared residual plus the prior's ``SWITCH_PENALTY`` per change.  One
        normal matrix, every sequence's right-hand side at once."""
        Fw = F * w[:, None]
        inverse = pinv(Fw.T @ Fw)
        targets = (r0 - self.responses) * w
        rhs = targets @ Fw
        a = rhs @ inverse.T
        cost = np.einsum("ij,ij->i", targets, targets) - np.einsum("ij,ij->i", rhs, a) + _penalties(self.m, first)
        order = np.argsort(cost, kind="stable").tolist() if self.m else range(len(self.sequences))
        return [(float(cost[i]), self.sequences[i], a[i]) for i in order]


@lru_cache(maxsize=None)
def _penalties(m: int, first: int) -> np.ndarray:
    """Each of ``command_sequences(m)``'s prior charge before the first logged command ``first``."""
    return np.array([SWITCH_PENALTY * changes(c, first) for c in command_sequences(m)])


def pinv(a: np.ndarray) -> np.ndarray:
    """``np.linalg.pinv(a)`` of a real matrix, to the bit (its own steps at its default rcond), without
    its ~30 us of argument handling: a start estimate takes one per reweighting of a 3x3 normal matrix."""
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    large = s > 1e-15 * np.max(s)
    s = np.divide(1.0, s, where=large, out=s)
    s[~large] = 0.0
    return np.matmul(vt.T, np.multiply(s[:, np.newaxis], u.T))


def command_spread(fits: list, Phi: np.ndarray, scale: float) -> np.ndarray:
    """Covariance of x0 across the command sequences, weighted by their posterior probability:
    a switch in flight and a different initial current can explain the first samples almost
    equally well, and the interval must say so."""
    costs = np.array([f[0] for f in fits])
    p = np.exp(-(costs - costs[0]) / (2.0 * scale))
    p /= p.sum()
    x = np.array([Phi @ f[2] for f in fits])
    d = x - x[0]
    return (d * p[:, None]).T @ d
