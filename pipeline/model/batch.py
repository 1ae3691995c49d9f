"""Many parameter sets at once (what fitting needs): one recording's instants, one controller, m plants.

For linear plants (viscous friction, driver drop, rack inertia, spring scale,
loop delay and sensor offset -- everything but Coulomb friction and backlash)
the m sets run through one compiled kernel (``lanes.run_linear_lanes``): per
set its exact step matrices for each distinct step length, then 64 sets at a
time through every sample, eight to a vector register, with the single call's
arithmetic per set, so equal to ``simulate`` to the last bit (tested), closed
loop or replay, with or without loop delay.

The batch saves the ~21 us of Python around each single call (argument checks,
kernel dispatch, result packaging); its own Python is one pass over the specs
(``spec_columns``).  Its blocks of sets are shared between threads, one per
idle core by default (the kernel releases the GIL; ``idle_cores``).  Non-smooth specs (Tc,
gap) or the continuous guard fall back to a loop of ``simulate`` calls.
"""

from __future__ import annotations

import os
import struct
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pipeline.errors import PdrError
from pipeline.model.effects import PlantSpec
from pipeline.model.params import MATRIX_PARAMS, state_matrices_of
from pipeline.model.lanes import LANES, lane_outputs, run_linear_lanes
from pipeline.model.simulate import SimResult, _plan, simulate


@dataclass(frozen=True)
class BatchResult:
    """Signals at the sample instants, one row per parameter set: arrays shaped (n_sets, n_samples)."""

    t: np.ndarray
    omega: np.ndarray
    current: np.ndarray
    delta: np.ndarray
    dir: np.ndarray
    v_drive: np.ndarray          # (n_sets,) V   |u| of each set
    I0: np.ndarray               # (n_sets,) A   current sensor offset of each set
    R: np.ndarray                # (n_sets,) m   pinion radius of each set

    @property
    def theta(self) -> np.ndarray:
        """delta / R (eq. 7), formed when asked for: the kernels' own division, so the same bits."""
        return self.delta / self.R[:, None]

    @property
    def current_measured(self) -> np.ndarray:
        return self.current + self.I0[:, None]

    @property
    def u(self) -> np.ndarray:
        return self.dir * self.v_drive[:, None]

    def __len__(self) -> int:
        return self.delta.shape[0]

    def result(self, i: int) -> SimResult:
        """Set ``i`` as a ``SimResult`` (what ``simulate`` would have returned)."""
        return SimResult(t=self.t, theta=self.delta[i] / self.R[i], omega=self.omega[i], current=self.current[i],
                         current_measured=self.current[i] + self.I0[i], delta=self.delta[i], dir=self.dir[i],
                         u=self.dir[i] * self.v_drive[i])


def simulate_batch(specs: Sequence[PlantSpec], t: np.ndarray | None = None, *, duration: float = 24.95,
                   x0: tuple[float, float, float] = (0.0, 0.0, 0.0), dir0: int = 1,
                   dir_log: np.ndarray | None = None, closed_loop: bool = True,
                   guard: str = "sampled", threads: int | None = None) -> BatchResult:
    """``simulate`` for every spec at the same instants and controller settings (see ``simulate``).

    ``threads``: how many threads share the linear sets (default: the cores
    this process may use that no other task is running on, ``idle_cores``);
    each takes whole blocks of 64 sets and writes its own columns, so the
    results do not depend on it.  A batch of 1000 sets with a loop delay runs
    ~1.5x faster on two idle cores; without one, the outputs' memory
    bandwidth is the limit and two cores gain little.
    """
    if threads is not None and (not isinstance(threads, (int, np.integer)) or isinstance(threads, bool)
                                or threads < 1):
        raise PdrError(f"expected a whole number of threads, at least 1, got {threads!r}", key="threads")
    specs = list(specs)
    if not specs:
        raise PdrError("expected at least one parameter set", key="specs")
    plan = _plan(specs[0], t, duration, dir0, dir_log, closed_loop, guard)
    columns = spec_columns(specs)
    linear = not (columns[ROW_TC].any() or columns[ROW_GAP].any())       # PlantSpec.is_linear of every set
    if not (linear and (guard == "sampled" or not closed_loop)):
        runs = [simulate(s, plan.t, x0=x0, dir0=dir0, dir_log=dir_log, closed_loop=closed_loop, guard=guard)
                for s in specs]
        return _stack(plan.t, runs, columns)
    return _run_lanes(columns, plan, np.asarray(x0, dtype=float), threads or idle_cores())


# Rows of ``spec_columns``: the matrix parameters (``MATRIX_PARAMS``, R first), then the spec's own terms.
ROW_R, ROW_GUARD, ROW_V_DRIVE, ROW_TD, ROW_I0, ROW_TC, ROW_GAP = 0, 9, 10, 11, 12, 13, 14
_ROW = struct.Struct("15d")


def spec_columns(specs: list[PlantSpec]) -> np.ndarray:
    """Every set's numbers as columns (15, m): ``MATRIX_PARAMS`` in order, guard_rad, v_drive, Td, I0, Tc, gap.

    One pass of attribute reads packed straight into bytes: building numpy
    arrays from Python floats element by element (np.array, np.fromiter) costs
    ~3x more here, and for 1000 sets more than the simulation they feed.
    """
    pack = _ROW.pack
    rows = b"".join([pack((p := s.params).R, p.J, p.Ke, p.Kt, p.La, p.Ra, p.K1, p.K2, p.b,
                          s.guard_rad, s.v_drive, s.Td, s.I0, s.Tc, s.gap) for s in specs])
    return np.frombuffer(rows).reshape(len(specs), _ROW.size // 8).T.copy()


def _stack(t: np.ndarray, runs: list[SimResult], columns: np.ndarray) -> BatchResult:
    return BatchResult(t=t, **{f: np.stack([getattr(r, f) for r in runs]) for f in ("omega", "current", "delta", "dir")},
                       v_drive=columns[ROW_V_DRIVE], I0=columns[ROW_I0], R=columns[ROW_R])


def usable_cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def idle_cores() -> int:
    """The usable cores not running another task right now, this thread's included (at least 1).

    The kernel counts the runnable tasks in /proc/loadavg (read in ~5 us).
    A batch thread on a core that another task also wants waits for its
    turn, often holding a block while the others have finished: with a busy
    loop on the other core, two threads ran a delayed batch in 1.57 ms and
    one thread alone in 1.39 ms.  Where the count cannot be read, every
    usable core.
    """
    cores = usable_cores()
    try:
        fd = os.open("/proc/loadavg", os.O_RDONLY)
        try:
            running = int(os.read(fd, 128).split()[3].split(b"/")[0])
        finally:
            os.close(fd)
    except (OSError, ValueError, IndexError):
        return cores
    return max(1, min(cores, cores - running + 1))


_pool: tuple[ThreadPoolExecutor, int, int] | None = None


def _helpers(n: int) -> ThreadPoolExecutor:
    """A pool of at least n threads for the lanes kernel (it releases the GIL), kept for later batches.

    A new one after a fork: the child inherits the pool but not its threads.
    """
    global _pool
    if _pool is None or _pool[1] < n or _pool[2] != os.getpid():
        if _pool is not None and _pool[2] == os.getpid():
            _pool[0].shutdown(wait=False)              # outgrown: its idle threads end
        _pool = (ThreadPoolExecutor(max_workers=n, thread_name_prefix="pdr-lanes"), n, os.getpid())
    return _pool[0]


def _run_lanes(columns: np.ndarray, plan, x0: np.ndarray, threads: int) -> BatchResult:
    """Every set through the compiled automaton, side by side (``lanes.run_linear_lanes``), by ``threads``
    threads that claim its blocks of sets one at a time (disjoint output columns)."""
    A, B = state_matrices_of(*columns[:len(MATRIX_PARAMS)])
    m, n = columns.shape[1], len(plan.t)
    Y, dirs = lane_outputs(m, n)
    next_block = np.zeros(3, dtype=np.int64)           # blocks claimed, from the front, from the back
    R, guard, V, Td = columns[ROW_R], columns[ROW_GUARD], columns[ROW_V_DRIVE], columns[ROW_TD]

    def run(from_front: bool) -> None:
        run_linear_lanes(plan.t, A, B, R, guard, V, Td, x0, plan.log, plan.closed_loop, plan.start, plan.first,
                         plan.dir0, Y, dirs, next_block, from_front)

    helpers = min(threads, -(-m // LANES)) - 1
    others = [_helpers(helpers).submit(run, i % 2 == 1) for i in range(helpers)]
    run(True)
    for f in others:
        f.result()
    return BatchResult(t=plan.t, omega=Y[:, 1, :m].T, current=Y[:, 0, :m].T, delta=Y[:, 2, :m].T, dir=dirs[:, :m].T,
                       v_drive=columns[ROW_V_DRIVE], I0=columns[ROW_I0], R=columns[ROW_R])
