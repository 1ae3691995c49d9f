"""Hybrid automaton simulator (docs/MODEL.md): sampled bang-bang guard, ZOH input, every effect.

The automaton: modes q1 (u = +v_drive) and q2 (u = -v_drive) share one flow
matrix (eqs. 2, 4/8, 5); the controller samples theta at the recording's own
instants (uneven spacing allowed), reverses at +/- guard_rad and holds the
command until the next sample; the reset is the identity.  The command decided
at sample k reaches the motor at t_k + Td (loop delay; 0 by default), and the
motor is off until the first command arrives.

One controller loop (``pipeline.model.loop``) over two exact plant steppers,
compiled with numba (this module checks the arguments and packages the result):

- linear plant (no Coulomb friction, no dead zone) with the sampled guard:
  ``linear.run_zoh`` -- one matrix exponential per distinct step length, then
  plain float arithmetic per sample;
- otherwise ``event_step.run_events``: event-driven, stick/slip, velocity zero
  crossings, backlash edges and (``guard="continuous"``) the guard crossing
  itself located on the closed-form solution.

A constant external torque ``tau`` enters as the current that would cancel it:
with I' = I + tau/Kt, eq. (4) loses the torque and eq. (2) gains the voltage
Ra tau/Kt (``_torque_shift``), so both steppers run the base plant unchanged.
``I0`` only touches the output: ``current_measured = current + I0``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from pipeline.errors import PdrError
from pipeline.model import loop
from pipeline.model.linear import run_zoh, zoh_steps
from pipeline.model.event_step import run_events
from pipeline.model.nonsmooth import plant_constants
from pipeline.model.params import PlantSpec

GUARDS = ("sampled", "continuous")
# The sketch's rule (``loop.next_dir``) as plain Python, for callers that apply it sample by sample
# outside a kernel (derive's phases, the rig's reference plant): same source, no dispatch per call.
next_dir = loop.next_dir.py_func


@dataclass(frozen=True)
class SimResult:
    """Simulated signals at the sample instants ``t`` (what the Arduino would have logged)."""

    t: np.ndarray                  # s    sample instants
    theta: np.ndarray              # rad  pinion angle  (eq. 7: delta / R)
    omega: np.ndarray              # rad/s
    current: np.ndarray            # A    true armature current
    current_measured: np.ndarray   # A    what the current sensor reads (current + I0)
    delta: np.ndarray              # m    rack displacement
    dir: np.ndarray                # int8 command decided at each sample: +1 (q1), -1 (q2), 0 (off)
    u: np.ndarray                  # V    voltage commanded after each sample (before any loop delay)

    @property
    def switch_times(self) -> np.ndarray:
        """Sample instants at which the command reversed."""
        d = self.dir
        idx = np.flatnonzero((d[1:] != d[:-1]) & (d[1:] != 0) & (d[:-1] != 0)) + 1
        return self.t[idx]

    @property
    def switches(self) -> int:
        return int(len(self.switch_times))


def sample_times(duration: float, period: float) -> np.ndarray:
    """Nominal sample instants 0, T, 2T, ... up to ``duration`` (24.95 s at 50 ms: 500 samples)."""
    n = int(np.floor(duration / period + 1e-9)) + 1
    return np.arange(n) * period


def _times(spec: PlantSpec, t, duration: float) -> np.ndarray:
    """The sample instants the kernels run on, checked: the default grid, or ``t`` as the kernels' own copy."""
    t = sample_times(duration, spec.period_s) if t is None else np.asarray(t, dtype=float)
    if t.ndim != 1 or len(t) == 0 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0.0):
        raise PdrError("expected a non-empty, finite, non-decreasing array of sample instants", key="t")
    # The kernels' own copy, contiguous and writable: numba compiles a separate version per array layout
    # and per read-only flag (pandas 3 hands out read-only arrays), each ~10 s and a cache entry.
    return np.array(t, dtype=float, order="C")


def _controller(spec: PlantSpec, t: np.ndarray, dir0: int, dir_log, closed_loop: bool, guard: str,
                v_bias: float) -> loop.Controller:
    """The controller the kernels run at the checked instants ``t``, from ``simulate``'s arguments."""
    if guard not in GUARDS:
        raise PdrError(f"unknown guard '{guard}', expected one of {', '.join(GUARDS)}", key="guard")
    if dir0 not in (-1, 1):
        raise PdrError(f"expected dir0 = 1 or -1, got {dir0!r}", key="dir0")
    if dir_log is None:
        if not closed_loop:
            raise PdrError("replay (closed_loop=False) needs the logged command", key="dir_log")
        log, start, first = np.zeros(0, dtype=np.int8), 0, 0
    else:
        log = np.asarray(dir_log)
        if log.shape != t.shape:
            raise PdrError(f"expected one command per sample ({len(t)}), got {log.shape}", key="dir_log")
        if not np.all((log == -1) | (log == 0) | (log == 1) | (log == loop.UNKNOWN)):    # np.isin: 10x slower
            raise PdrError(f"expected commands -1, 0, 1 or {loop.UNKNOWN} (unknown)", key="dir_log")
        nz = np.flatnonzero((log != 0) & (log != loop.UNKNOWN))
        start = int(nz[0]) if len(nz) else len(t)
        first = int(log[start]) if len(nz) else 0
        log = log.astype(np.int8)
    return loop.Controller(float(spec.params.R), float(spec.guard_rad), float(spec.v_drive), v_bias,
                           float(spec.Td), log, bool(closed_loop), start, first, int(dir0),
                           guard == "continuous" and bool(closed_loop))


def with_lost_samples(t: np.ndarray, dir_log: np.ndarray, angle: np.ndarray | None = None,
                      guard: float = 0.0, shifted: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``lost_samples_filled``, remembered: a fit replays the same recording under the same command
    hundreds of times, and filling its gaps (a cubic per gap) costs more than the replay's own
    set-up.  The arrays returned are read-only (shared between callers)."""
    t = np.asarray(t, dtype=float)
    d = np.asarray(dir_log)
    a = None if angle is None else np.asarray(angle, dtype=float)
    return _filled(t.tobytes(), d.tobytes(), d.dtype.str, None if a is None else a.tobytes(), float(guard),
                   tuple(sorted(shifted)))


@lru_cache(maxsize=256)
def _filled(t: bytes, d: bytes, dtype: str, angle: bytes | None, guard: float, shifted: tuple[int, ...]):
    out = lost_samples_filled(np.frombuffer(t), np.frombuffer(d, dtype=dtype),
                              None if angle is None else np.frombuffer(angle), guard, shifted)
    for x in out:
        x.flags.writeable = False
    return out


MAX_LOST_ROWS = 50      # the longest run of lost rows filled back (2.5 s at the paper's 50 ms)


def _gaps(t: np.ndarray) -> np.ndarray:
    """Per spacing of ``t``, the rows lost in it (a gap of about k sample periods holds k - 1)."""
    h = np.diff(t)
    period = float(np.median(h))
    with np.errstate(over="ignore", invalid="ignore"):
        k = np.rint(h / period) - 1 if period > 0 else np.zeros(len(h))
    # a gap longer than MAX_LOST_ROWS periods is not rows lost over serial but a gap (a paused capture, a
    # timestamp glitch): the simulation steps across it, so its length follows the samples, not the span
    return np.where((h > 1.5 * period) & (k <= MAX_LOST_ROWS), k, 0).astype(int)


def _lost_instants(t: np.ndarray, i: int, m: int) -> np.ndarray:
    """The ``m`` instants lost in the gap after sample ``i``, evenly spaced (the sketch's loop kept time)."""
    return t[i] + (t[i + 1] - t[i]) * np.arange(1, m + 1) / (m + 1)


def _reversal_gap(dir_log: np.ndarray, i: int) -> bool:
    """The logged commands either side of the gap after sample ``i`` differ: the sketch reversed in it or at
    the next logged sample (between two equal ones it held, as a reversal would need the other guard)."""
    before, after = int(dir_log[i]), int(dir_log[i + 1])
    return before in (-1, 1) and after != before and after != loop.UNKNOWN


def _start_gap(dir_log: np.ndarray, i: int) -> bool:
    """The logged command goes from off to on across the gap after sample ``i``: the motor started at a lost
    instant or at the next logged sample.  No rule of the sketch's decides that instant from the angle (its
    start is a timer's or a button's), so the data must."""
    return int(dir_log[i]) == 0 and int(dir_log[i + 1]) in (-1, 1)


def lost_starts(t: np.ndarray, dir_log: np.ndarray) -> list[int]:
    """Logged samples after which the motor started in a gap of lost rows (``_start_gap``)."""
    t, d = np.asarray(t, dtype=float), np.asarray(dir_log)
    if len(t) < 3:
        return []
    return [int(i) for i in np.flatnonzero(_gaps(t)) if _start_gap(d, int(i))]


def _around_gap(t: np.ndarray, angle: np.ndarray, i: int) -> np.ndarray:
    """The logged samples the angle in the gap after sample ``i`` is interpolated through: two each side."""
    near = np.arange(max(i - 1, 0), min(i + 3, len(t)))
    return near[np.isfinite(angle[near])]


def _angle_at(t: np.ndarray, angle: np.ndarray, i: int, instants: np.ndarray) -> np.ndarray | None:
    """The measured angle at ``instants`` inside the gap after sample ``i``: the angle bends towards a guard
    (the motor is braking it), so a cubic through two logged samples each side, not a chord."""
    near = _around_gap(t, angle, i)
    if i not in near or i + 1 not in near:
        return None
    fit = np.polyfit(t[near] - t[i], angle[near], len(near) - 1)
    return np.polyval(fit, instants - t[i])


def lost_samples_filled(t: np.ndarray, dir_log: np.ndarray, angle: np.ndarray | None = None,
                        guard: float = 0.0, shifted: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sketch's own loop instants: every gap of about k sample periods (k >= 2, a row lost over
    serial) gets its k - 1 missing instants back, evenly spaced.  Returns (instants, commands, index of
    each logged sample among them); without gaps, the inputs.

    The sketch decided something at a lost instant.  Between two equal logged commands it held that
    one.  Between two different ones it reversed at a lost instant or at the next logged one: with the
    measured ``angle`` (one per logged sample, in the guard's frame), the sketch's rule on it
    interpolated there (``_angle_at``) decides, so a replay is fixed by the data and smooth in the
    model's parameters; without it, an ``UNKNOWN`` command, which the simulation's controller decides
    on the model's angle.  A gap after a logged sample in ``shifted`` has its reversal one instant from
    where the rule put it (later, or at the last lost instant where the rule put it at the next logged
    sample): where the interpolated angle is within the logged angles' rounding error of the guard, the
    rule may be a sample off (``lost_reversals_on_guard``), and discovery settles which.  A motor started
    in a gap (off before it, on after) is started at the next logged sample, or, after a sample in
    ``shifted``, at the last lost instant (``lost_starts``)."""
    t = np.asarray(t, dtype=float)
    if len(t) < 3:
        return t, np.asarray(dir_log), np.arange(len(t))
    missing = _gaps(t)
    if not missing.any():
        return t, np.asarray(dir_log), np.arange(len(t))
    kept = np.concatenate([[0], np.cumsum(missing + 1)])
    t_full = np.empty(kept[-1] + 1)
    d_full = np.full(kept[-1] + 1, loop.UNKNOWN, dtype=np.int8)
    t_full[kept], d_full[kept] = t, dir_log
    for i in np.flatnonzero(missing):
        m = missing[i]
        t_full[kept[i] + 1:kept[i + 1]] = _lost_instants(t, i, m)
        before, after = int(dir_log[i]), int(dir_log[i + 1])
        if (before == after and before != loop.UNKNOWN) or before == 0:
            d_full[kept[i] + 1:kept[i + 1]] = before          # held (the motor off: as the loop holds it)
            if i in shifted and _start_gap(dir_log, i):
                d_full[kept[i + 1] - 1] = after               # the motor started at the last lost instant
        elif angle is not None and before in (-1, 1):
            lost = t_full[kept[i] + 1:kept[i + 1]]
            at = _angle_at(t, angle, i, lost)
            if at is None:
                continue
            d = before
            for j in range(m):
                d = next_dir(d, float(at[j]), guard)
                d_full[kept[i] + 1 + j] = d
            if i in shifted and _reversal_gap(dir_log, i):
                gap = d_full[kept[i] + 1:kept[i + 1]]
                r = int(np.argmax(gap != before)) if np.any(gap != before) else m   # lost instants before it
                r = r + 1 if r < m else r - 1
                gap[:r], gap[r:] = before, after
    return t_full, d_full, kept


def _rounding_gain(t: np.ndarray, angle: np.ndarray, i: int, instants: np.ndarray) -> np.ndarray:
    """How far ``_angle_at``'s interpolation can move when each logged angle it passes through moves by one:
    the sum of the magnitudes of its Lagrange weights at each instant (5/3 for one lost row, 2 for two)."""
    x = t[_around_gap(t, angle, i)]
    weights = [np.prod([(instants - x[k]) / (x[j] - x[k]) for k in range(len(x)) if k != j], axis=0)
               for j in range(len(x))]
    return np.sum(np.abs(weights), axis=0)


def lost_reversals_on_guard(t: np.ndarray, dir_log: np.ndarray, angle: np.ndarray, guard: float,
                            band: float) -> list[int]:
    """Logged samples after which a reversal falls in a gap of lost rows with the interpolated angle at one
    of its lost instants within the error ``band`` (each logged angle's) carries into it of a guard: the
    sketch's rule on it may be a sample off."""
    t = np.asarray(t, dtype=float)
    angle = np.asarray(angle, dtype=float)
    if len(t) < 3:
        return []
    missing = _gaps(t)
    out = []
    for i in np.flatnonzero(missing):
        if not _reversal_gap(dir_log, i):
            continue
        instants = _lost_instants(t, i, missing[i])
        at = _angle_at(t, angle, i, instants)
        if at is not None and np.any(np.abs(np.abs(at) - guard) <= band * _rounding_gain(t, angle, i, instants)):
            out.append(int(i))
    return out


def simulate(spec: PlantSpec, t: np.ndarray | None = None, *, duration: float = 24.95,
             x0: tuple[float, float, float] = (0.0, 0.0, 0.0), dir0: int = 1,
             dir_log: np.ndarray | None = None, closed_loop: bool = True,
             guard: str = "sampled") -> SimResult:
    """Run the automaton at sample instants ``t`` (default: every ``period_s`` for ``duration``).

    closed_loop=True: the controller decides from theta at each sample, starting
    in mode ``dir0``; if ``dir_log`` is given, its leading zeros (motor off
    before the sketch starts) are honoured and the controller starts in the
    mode of its first non-zero entry.  closed_loop=False (replay): ``dir_log``
    (-1/0/1) drives the motor.  ``guard="continuous"`` switches the instant
    theta crosses the guard instead of at the next sample (for comparison).
    Either way the motor sees a command ``Td`` after it is decided.
    """
    return Prepared.of(spec, t, duration=duration, dir0=dir0, dir_log=dir_log, closed_loop=closed_loop,
                       guard=guard).run(x0)


@dataclass(frozen=True)
class Prepared:
    """A simulation with its arguments checked and its controller built, run from any start: a start
    estimate replays one plant under one command from a dozen starts, and the checks cost as much as a
    short window's simulation."""

    spec: PlantSpec
    t: np.ndarray
    controller: loop.Controller
    shift: float          # A: the constant torque carried as a current (``_torque_shift``)
    stepper: tuple        # the kernel and the plant's arguments it runs on (``zoh_steps`` or ``plant_constants``)

    @classmethod
    def of(cls, spec: PlantSpec, t: np.ndarray | None = None, *, duration: float = 24.95, dir0: int = 1,
           dir_log: np.ndarray | None = None, closed_loop: bool = True, guard: str = "sampled") -> "Prepared":
        shift, v_bias = _torque_shift(spec)
        t = _times(spec, t, duration)
        controller = _controller(spec, t, dir0, dir_log, closed_loop, guard, v_bias)
        if spec.is_linear and not controller.continuous:
            A, B = spec.params.state_matrices()
            stepper = (run_zoh, A, B, *zoh_steps(A, B, t))              # exact ZOH steps, once per instants
        else:
            stepper = (run_events, *plant_constants(spec))             # located events
        return cls(spec, t, controller, shift, stepper)

    def under(self, dir_log: np.ndarray, dir0: int = 1) -> "Prepared":
        """The same plant at the same instants replaying ``dir_log`` (a start estimate tries a dozen
        pre-log command sequences on one window; the instants and the plant are checked once)."""
        if self.controller.closed_loop:
            raise ValueError("Prepared.under replays a prepared replay under another command")
        return replace(self, controller=_controller(self.spec, self.t, dir0, dir_log, False, "sampled",
                                                    self.controller.v_bias))

    def run(self, x0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> SimResult:
        spec, t, controller = self.spec, self.t, self.controller
        x = np.array(x0, dtype=float)
        x[0] += self.shift
        out, dirs = np.empty((3, len(t))), np.empty(len(t), dtype=np.int8)
        kernel, *plant = self.stepper
        kernel(*plant, controller, t, x, out, dirs)
        current, omega, delta = out[0] - self.shift, out[1], out[2]
        # theta = delta / R (eq. 7): the division the kernels decide with, so the same bits
        return SimResult(t=t.copy(), theta=delta / spec.params.R, omega=omega, current=current,
                         current_measured=current + spec.I0, delta=delta, dir=dirs, u=dirs * float(spec.v_drive))


def _torque_shift(spec: PlantSpec) -> tuple[float, float]:
    """(current shift tau/Kt [A], voltage Ra tau/Kt [V]) that carry a constant torque tau (module doc)."""
    if spec.torque == 0.0:
        return 0.0, 0.0
    shift = spec.torque / spec.params.Kt
    return shift, spec.params.Ra * shift
