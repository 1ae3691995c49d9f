"""Many parameter sets at once (what fitting needs): one recording's instants, one controller, m plants.

For linear plants (viscous friction, driver drop, rack inertia, spring scale,
loop delay and sensor offset -- everything but Coulomb friction and backlash)
the m closed loops advance together: per distinct step length one batched
matrix exponential (``linear.phi_gamma_columns`` on the stacked parameter sets),
then per sample one stacked matrix-vector product and a vectorised ``next_dir``.
A delayed command that reaches the motor inside a step adds
``Gamma(h - a) * du`` for the sets concerned (same superposition as
``simulate``), so the batch equals m single calls to rounding.
Non-smooth specs (Tc, gap) or the continuous guard fall back to a loop of
``simulate`` calls.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pipeline.errors import PdrError
from pipeline.model.effects import PlantSpec
from pipeline.model.linear import augmented_batch, phi_gamma_columns, step_key
from pipeline.model.simulate import TIME_EPS, SimResult, _plan, simulate


@dataclass(frozen=True)
class BatchResult:
    """Signals at the sample instants, one row per parameter set: arrays shaped (n_sets, n_samples)."""

    t: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    current: np.ndarray
    delta: np.ndarray
    dir: np.ndarray
    v_drive: np.ndarray          # (n_sets,) V   |u| of each set
    I0: np.ndarray               # (n_sets,) A   current sensor offset of each set

    @property
    def current_measured(self) -> np.ndarray:
        return self.current + self.I0[:, None]

    @property
    def u(self) -> np.ndarray:
        return self.dir * self.v_drive[:, None]

    def __len__(self) -> int:
        return self.theta.shape[0]

    def result(self, i: int) -> SimResult:
        """Set ``i`` as a ``SimResult`` (what ``simulate`` would have returned)."""
        return SimResult(t=self.t, theta=self.theta[i], omega=self.omega[i], current=self.current[i],
                         current_measured=self.current[i] + self.I0[i], delta=self.delta[i], dir=self.dir[i],
                         u=self.dir[i] * self.v_drive[i])


def simulate_batch(specs: Sequence[PlantSpec], t: np.ndarray | None = None, *, duration: float = 24.95,
                   x0: tuple[float, float, float] = (0.0, 0.0, 0.0), dir0: int = 1,
                   dir_log: np.ndarray | None = None, closed_loop: bool = True,
                   guard: str = "sampled") -> BatchResult:
    """``simulate`` for every spec at the same instants and controller settings (see ``simulate``)."""
    specs = list(specs)
    if not specs:
        raise PdrError("expected at least one parameter set", key="specs")
    plan = _plan(specs[0], t, duration, dir0, dir_log, closed_loop, guard)
    vectorised = all(s.is_linear for s in specs) and (guard == "sampled" or not closed_loop)
    if not vectorised:
        runs = [simulate(s, plan.t, x0=x0, dir0=dir0, dir_log=dir_log, closed_loop=closed_loop, guard=guard)
                for s in specs]
        return _stack(plan.t, runs, specs)
    return _run_linear_batch(specs, plan, np.asarray(x0, dtype=float))


def _stack(t: np.ndarray, runs: list[SimResult], specs: list[PlantSpec]) -> BatchResult:
    return BatchResult(t=t, **{f: np.stack([getattr(r, f) for r in runs])
                               for f in ("theta", "omega", "current", "delta", "dir")},
                       v_drive=np.array([s.v_drive for s in specs]), I0=np.array([s.I0 for s in specs]))


def _next_dir(d: np.ndarray, theta: np.ndarray, guard: np.ndarray) -> np.ndarray:
    """``simulate.next_dir`` for arrays."""
    down = (d >= 0) & (theta >= guard)
    up = (d <= 0) & (theta <= -guard)
    if not (down.any() or up.any() or (d == 0).any()):
        return d
    return np.where(down, -1, np.where(up, 1, np.where(d == 0, 1, d))).astype(np.int64)


def _run_linear_batch(specs: list[PlantSpec], plan, x0: np.ndarray) -> BatchResult:
    m = len(specs)
    t = plan.t
    n = len(t)
    A, B = stacked_state_matrices([s.params for s in specs])
    R = np.array([s.params.R for s in specs])
    guard = np.array([s.guard_rad for s in specs])
    V = np.array([s.v_drive for s in specs])
    Td = np.array([s.Td for s in specs])
    I0 = np.array([s.I0 for s in specs])
    delayed = bool(np.any(Td > 0.0))
    X = np.tile(x0[:, None], (1, m))              # (3, m): I, w, delta of every set
    dirs = np.zeros((n, m), dtype=np.int8)
    steps = _step_matrices(A, B, np.diff(t).tolist())
    if plan.closed_loop and not delayed:
        out = _closed_loop_undelayed(plan, steps, X, dirs, R, guard, V)
    else:
        out = _general(plan, steps, X, dirs, A, B, R, guard, V, Td)
    return BatchResult(t=t, theta=(out[:, 2, :] / R).T, omega=out[:, 1, :].T, current=out[:, 0, :].T,
                       delta=out[:, 2, :].T, dir=dirs.T, v_drive=V, I0=I0)


def stacked_state_matrices(params: list) -> tuple[np.ndarray, np.ndarray]:
    """``ModelParams.state_matrices`` for many sets at once: A (m, 3, 3), B (m, 3) (eqs. 2, 4/8, 5).

    Built from parameter columns in a handful of array operations; a thousand
    separate 3x3 constructions cost more than the simulation they feed.
    """
    col = {name: np.array([getattr(p, name) for p in params], dtype=float)
           for name in ("R", "J", "Ke", "Kt", "La", "Ra", "K1", "K2", "b")}
    m = len(params)
    A = np.zeros((m, 3, 3))
    A[:, 0, 0] = -col["Ra"] / col["La"]                                   # (2)
    A[:, 0, 1] = -col["Ke"] / col["La"]
    A[:, 1, 0] = col["Kt"] / col["J"]                                     # (4), (8)
    A[:, 1, 1] = -col["b"] / col["J"]
    A[:, 1, 2] = -col["R"] * (col["K1"] + col["K2"]) / col["J"]
    A[:, 2, 1] = col["R"]                                                 # (5)
    B = np.zeros((m, 3))
    B[:, 0] = 1.0 / col["La"]
    return A, B


def _step_matrices(A: np.ndarray, B: np.ndarray, hs: list[float]) -> list[np.ndarray]:
    """[Phi | Gamma] as (3, 4, m) for every step: one batched exponential over all distinct lengths."""
    keys = {h: step_key(h) for h in set(hs)}
    lengths = sorted(set(keys.values()))
    m = A.shape[0]
    cols = phi_gamma_columns(np.tile(A, (len(lengths), 1, 1)), np.tile(B, (len(lengths), 1)),
                             np.repeat(lengths, m))
    by_length = {h: np.ascontiguousarray(cols[:, :, i * m:(i + 1) * m]) for i, h in enumerate(lengths)}
    return [by_length[keys[h]] for h in hs]


def _decide(plan, k: int, d: np.ndarray, theta: np.ndarray, guard: np.ndarray) -> np.ndarray:
    """The controller of ``simulate._Plan.decide`` for all sets at sample k."""
    m = len(theta)
    if not plan.closed_loop or k < plan.start:
        return np.full(m, int(plan.dir_log[k]), dtype=np.int64)
    if k == plan.start:
        if plan.first:
            return np.full(m, plan.first, dtype=np.int64)
        return _next_dir(np.full(m, plan.dir0, dtype=np.int64), theta, guard)
    flip = d * theta >= guard                     # next_dir once started: d is +-1
    return np.where(flip, -d, d) if flip.any() else d


def _closed_loop_undelayed(plan, steps, X, dirs, R, guard, V) -> np.ndarray:
    """The hot path: commands act at once, so u = d * V changes only where a set reverses.

    States and input live in one (4, m) slab per sample, [I, w, delta, u], so a
    step is a single einsum with [Phi | Gamma] written straight into the next slab.
    Once the controller runs, the guard test d * (delta / R) >= guard is one
    division by d * R (IEEE division is symmetric in sign, so it rounds exactly
    alike), and a reversal negates d * R and u of the sets concerned.
    """
    n, m = len(dirs), len(R)
    slab = np.empty((n, 4, m))
    slab[0, :3] = X
    d = np.zeros(m, dtype=np.int64)
    k = 0
    for k in range(min(plan.start + 1, n)):       # the log, then the controller's first decision
        x = slab[k]
        d = _decide(plan, k, d, x[2] / R, guard)
        x[3] = d * V
        dirs[k] = d
        if k + 1 < n:
            np.einsum("ijm,jm->im", steps[k], x, out=slab[k + 1, :3])
    signed_R = d * R
    u = slab[k, 3].copy()
    theta = np.empty(m)
    first = k + 1
    flips = np.zeros((n, m), dtype=bool)          # where a set reverses at sample k
    for k in range(first, n):
        x = slab[k]
        np.divide(x[2], signed_R, out=theta)
        flip = flips[k]
        np.greater_equal(theta, guard, out=flip)
        np.negative(signed_R, out=signed_R, where=flip)
        np.negative(u, out=u, where=flip)
        x[3] = u
        if k + 1 < n:
            np.einsum("ijm,jm->im", steps[k], x, out=slab[k + 1, :3])
    if first < n:                                  # the command flips with every reversal since the start
        odd = np.logical_xor.accumulate(flips[first:], axis=0)
        dirs[first:] = np.where(odd, -d, d)
    return slab


def _general(plan, steps, X, dirs, A, B, R, guard, V, Td) -> np.ndarray:
    """Any controller plan with per-set loop delays.

    A command change decided at t_k reaches set i's motor at s = t_k + Td_i,
    inside some later step q: it adds ``Gamma(h_q - a) du`` to that step (a =
    s - t_q) and ``du`` to the motor voltage held from step q + 1 on.  Both are
    booked when the change is decided, so each step stays one einsum plus one
    add, and the batched exponentials are only taken for the sets that changed.
    Once the controller runs (closed loop), a change is exactly a reversal, so
    the sets concerned come straight from the guard test.
    """
    t = plan.t
    n, m = len(dirs), len(R)
    slab = np.empty((n, 4, m))                     # [I, w, delta, motor voltage at the step's start]
    slab[0, :3] = X
    book = _Booking(t, Td, _GammaOfLength(A, B), n, m)
    d = np.zeros(m, dtype=np.int64)
    u_cmd = np.zeros(m)
    own_from = plan.start + 1 if plan.closed_loop else n
    V2 = 2.0 * V
    log = plan.dir_log.tolist() if plan.dir_log is not None else None
    for k in range(n):
        x = slab[k]
        if k >= own_from:                          # next_dir once started: d is +-1, a flip is a change
            flip = np.flatnonzero(d * (x[2] / R) >= guard)
            if len(flip):
                now = -d[flip]
                d[flip] = now
                book(k, flip, now * V2[flip])      # u: -now V -> now V
        elif not (k and log is not None and log[k] == log[k - 1]):    # a logged command that repeats changes nothing
            d = _decide(plan, k, d, x[2] / R, guard)
            new = d * V
            changed = np.flatnonzero(new != u_cmd) if k else np.arange(m)
            if len(changed):
                book(k, changed, new[changed] - u_cmd[changed])
                u_cmd = new
        dirs[k] = d
        book.hold_voltage(k, slab[k - 1, 3] if k else 0.0, x[3])
        if k + 1 == n:
            break
        nxt = slab[k + 1, :3]
        np.einsum("ijm,jm->im", steps[k], x, out=nxt)
        book.add_extra(k, nxt)
    return slab


class _Booking:
    """Motor-voltage changes ``du`` of ``sets`` decided at sample k, booked into the steps they land in.

    A change landing within TIME_EPS of a sample belongs to the step that sample
    starts (as in ``simulate``); one landing in step q contributes
    Gamma(t_{q+1} - arrive) du there (``extra``, laid out like the state rows)
    and du to the voltage held from q + 1 on (``du_from``).  A change lands at
    most ``depth - 2`` steps after the sample that decided it, so both live in
    ring buffers of that depth (small enough to stay in cache instead of two
    (n, m) arrays): ``hold_voltage`` and ``add_extra`` read step k's row and
    clear it for reuse.
    """

    def __init__(self, t: np.ndarray, Td: np.ndarray, gamma: "_GammaOfLength", n: int, m: int) -> None:
        self.t, self.Td, self.gamma, self.last = t, Td, gamma, n - 1
        self.h = np.diff(t)
        reach = np.searchsorted(t, t + float(np.max(Td)) + TIME_EPS, side="right") - 1
        self.depth = int(np.max(reach - np.arange(n))) + 2
        self.extra = np.zeros((self.depth, 3, m))
        self.du_from = np.zeros((self.depth, m))

    def __call__(self, k: int, sets: np.ndarray, du: np.ndarray) -> None:
        t = self.t
        arrive = t[k] + self.Td[sets]
        q = np.searchsorted(t, arrive + TIME_EPS, side="right") - 1     # the step the change lands in
        if q.max() >= self.last:
            keep = q < self.last
            sets, arrive, du, q = sets[keep], arrive[keep], du[keep], q[keep]
        # each set appears once per call, so plain fancy-index += is safe (no repeated (step, set) pairs)
        G = self.gamma(sets, np.minimum(t[q + 1] - arrive, self.h[q]))      # t_{q+1} - max(arrive, t_q)
        self.extra[q % self.depth, :, sets] += G * du[:, None]
        self.du_from[(q + 1) % self.depth, sets] += du

    def hold_voltage(self, k: int, before: np.ndarray | float, out: np.ndarray) -> None:
        """out = motor voltage held over step k: ``before`` plus the du taking effect from k on (then cleared)."""
        row = self.du_from[k % self.depth]
        np.add(before, row, out=out)
        row.fill(0.0)

    def add_extra(self, k: int, x: np.ndarray) -> None:
        """x += the booked Gamma(h - a) du of step k (then cleared)."""
        row = self.extra[k % self.depth]
        x += row
        row.fill(0.0)


class _GammaOfLength:
    """Gamma(tau) = int_0^tau e^{A s} ds B for chosen sets and arbitrary tau (a delayed command's split).

    Modal closed form, V (expm1(lam tau) / lam) V^-1 B, from one stacked
    eigendecomposition: a handful of array operations per call instead of a
    batched Taylor series.  Sets whose eigenvectors are ill-conditioned (near
    a repeated eigenvalue) or with a zero eigenvalue use ``augmented_batch``.
    """

    def __init__(self, A: np.ndarray, B: np.ndarray) -> None:
        self.A, self.B = A, B
        lam, V = np.linalg.eig(A)
        self.lam = lam
        Vinv = np.linalg.inv(V)
        bt = np.einsum("mij,mj->mi", Vinv, B.astype(complex))
        self.W = V * bt[:, None, :]                # Gamma(tau) = Re W expm1(lam tau) / lam
        scale = np.maximum(1.0, np.max(np.abs(lam), axis=1))
        # 1-norm condition number from the inverse at hand (an SVD per set costs more than the whole step)
        cond = np.max(np.abs(V).sum(axis=1), axis=1) * np.max(np.abs(Vinv).sum(axis=1), axis=1)
        self.exact = (cond > 1e6) | np.any(np.abs(lam) < 1e-9 * scale[:, None], axis=1)
        self.any_exact = bool(self.exact.any())

    def __call__(self, sets: np.ndarray, tau: np.ndarray) -> np.ndarray:
        lam = self.lam[sets]
        G = np.einsum("kij,kj->ki", self.W[sets], np.expm1(lam * tau[:, None]) / lam).real
        if self.any_exact:
            fix = self.exact[sets]
            if fix.any():
                G[fix] = augmented_batch(self.A[sets[fix]], self.B[sets[fix]], tau[fix])[1]
        return G
