"""What discovery works on: one recording's measured signals, its rig, and the two ways to simulate it.

A ``Measurement`` is built from the derive stage's kinematics table (t_s,
theta_rad, omega_rad_s, current_a, dir, dir_inferred) and the rig configuration
resolved at ingest.  Fitting uses *replay* (the logged command drives the
motor), which is smooth in the parameters; the verdict is confirmed in *closed
loop* (the model's own sampled guard decides), the paper's free-run measure,
whose error jumps whenever a simulated switch slips by one control period.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import pandas as pd

from pipeline.config import RigConfig
from pipeline.errors import PdrError
from pipeline.model.effects import Effect, PlantSpec
from pipeline.model.simulate import SimResult
from pipeline.validate.compare import observed_signals
from pipeline.estimate.noise import sample_instants
from pipeline.estimate.initial_state import STATE_SCALES, Observed, StartEstimator, without_offset
from pipeline.estimate.start import Start


@dataclass
class StartCache:
    """The start estimates a measurement has made: the estimators per plant without sensor offset, their
    starts per (plant, the command's first seconds, offset), and after a reset the counter's held offset.

    The one mutable part of a ``Measurement``, and shared on purpose by the copies ``replace`` makes (another
    command, another rig value): every start is keyed on what it depends on, so a copy reuses what applies
    and the work counted (``Measurement.start_runs``) is the discovery's whole."""

    estimators: dict = field(default_factory=dict)
    starts: dict = field(default_factory=dict)
    offsets: dict = field(default_factory=dict)


@dataclass(eq=False)
class Measurement:
    """One recording, as arrays; ``current`` is None when the sketch does not log it.  The arrays are
    never changed; the start estimates accumulate in ``cache`` (see ``StartCache``), so this is not frozen."""

    name: str
    config: RigConfig
    kinematics: pd.DataFrame        # derive stage table, one row per sample (for validate.metrics)
    t: np.ndarray                   # s
    t_fit: np.ndarray               # s, t on a 0.1 ms grid (SIM_GRID_S): what the fits replay on
    theta: np.ndarray               # rad
    omega: np.ndarray               # rad/s (derive's default estimator; NaN where undefined)
    current: np.ndarray | None      # A, as the sensor reads it
    dir: np.ndarray                 # int8 command after each sample (logged, else inferred)
    dir_source: str                 # "logged" or "inferred"
    samples_in_recording: int = 0   # > n when only the first MAX_SAMPLES are used
    # False for a segment after a board reset: the counter restarted wherever the pinion was, so
    # where the springs rest in its angle is a nuisance (a constant in the angle), not a datum
    angle_reference_known: bool = True
    # per signal whose zero ingest read off the data itself (a current zero = "auto"), the number of
    # rest readings it is the mean of: an offset within that mean's error may be the zero's own
    zero_samples: dict[str, int] = field(default_factory=dict, compare=False)
    # logged samples after which the reversal in a gap of lost rows is a sample from where the sketch's rule on
    # the interpolated angle puts it (``simulate.lost_samples_filled``): a nuisance discovery settles
    lost_shifts: tuple[int, ...] = ()
    cache: StartCache = field(default_factory=StartCache, repr=False)

    @property
    def onset(self) -> int | None:
        """Index of the first motor-on sample when it is only inferred (no logged command and a
        motor-off lead-in): the derive stage dates it from the first motion, which a loop delay
        or a sticking pinion postpone, so fitting treats it as unknown (``ONSET_SHIFTS``)."""
        if self.dir_source != "inferred":
            return None
        nz = np.flatnonzero(self.dir != 0)
        return int(nz[0]) if len(nz) and nz[0] > 0 else None

    def with_onset(self, k: int) -> np.ndarray:
        """The command sequence with the motor switched on at sample ``k`` instead."""
        k0 = self.onset
        d = self.dir.copy()
        if k0 is None or k == k0:
            return d
        k = int(np.clip(k, 1, self.n - 1))
        if k < k0:
            d[k:k0] = d[k0]
        else:
            d[k0:k] = 0
        return d

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def signals(self) -> dict[str, np.ndarray]:
        """The signals the fit scores: the angle and, when logged, the current.

        omega is left out of the likelihood: it is differentiated from theta,
        so counting it again would count the encoder twice.
        """
        out = {"theta": self.theta}
        if self.current is not None:
            out["current"] = self.current
        return out

    def spec(self, effects: tuple[Effect, ...] = ()) -> PlantSpec:
        """The rig's model ([model] + [effects] of its TOML) plus ``effects``."""
        return self.config.plant_spec(tuple(effects))

    @cached_property
    def observed(self) -> Observed:
        """The fitted signals with their noise variances, from the recording (validation's numbers)."""
        return observed_signals(self.kinematics)

    @property
    def start_runs(self) -> int:
        """Simulations run for start estimates so far, by this measurement and the copies sharing its estimators."""
        return sum(e.runs for e in self.cache.estimators.values())

    def x0(self, spec: PlantSpec, dir_log: np.ndarray | None = None) -> Start:
        """The start (x0 with its uncertainty, the pre-log commands) under ``spec``, estimated
        from the data on the recording's own instants as validation does (so the MSEs agree)."""
        d = self.dir if dir_log is None else dir_log
        plant = without_offset(spec)
        if plant not in self.cache.estimators:
            self.cache.estimators[plant] = StartEstimator(plant, self.t, self.observed,
                                                     angle_offset=not self.angle_reference_known)
        estimator = self.cache.estimators[plant]
        shifted = self.lost_shifts
        key = (plant, estimator.window(d, shifted), spec.I0)
        if key not in self.cache.starts:
            if self.angle_reference_known:
                self.cache.starts[key] = estimator.start(d, spec.I0, shifted=shifted)
            elif self.cache.offsets:
                # the offset is the counter's, one per segment: estimated under the first model asked
                # (the base), then held, as the angle residual is taken about its own mean anyway
                # (re-estimating it for every candidate's plant tripled each start's cost), and fitted
                # again under the final model (``discover.start_refit``)
                self.cache.starts[key] = estimator.start(d, spec.I0, offset=self.cache.offsets["segment"],
                                                         shifted=shifted)
            else:
                # the first seconds alone barely tell the counter's offset from where the springs hold
                # the pinion (a segment opening at rest, creeping): the whole segment pins it
                start = estimator.start(d, spec.I0, shifted=shifted)
                offset = self._segment_offset(plant, spec.I0, start, d)
                if offset is not None:
                    start = estimator.start(d, spec.I0, offset=offset, shifted=shifted)
                    self.cache.offsets["segment"] = offset
                self.cache.starts[key] = start
        return self.cache.starts[key]

    def _segment_offset(self, plant: PlantSpec, I0: float, start: Start, d: np.ndarray) -> float | None:
        """The counter's offset that, with the start moved along with it, replays the whole segment
        best: one weighted linear least squares in (start, offset), the replay's response to the
        start by finite differences (exact for a linear plant, a Gauss-Newton step otherwise)."""
        z0 = np.array(start.x0 if start.z is None else start.z, dtype=float)

        def outputs(z: np.ndarray) -> np.ndarray:
            sim = self.run(start.with_z(z), plant, d)
            parts = [sim.theta / np.sqrt(self.observed["theta"][1])]
            if self.current is not None:
                parts.append((sim.current + I0) / np.sqrt(self.observed["current"][1]))
            return np.concatenate(parts)

        try:
            base = outputs(z0)
            steps = OFFSET_STEP * STATE_SCALES
            J = np.column_stack([(outputs(z0 + np.eye(3)[i] * steps[i]) - base) / steps[i] for i in range(3)])
        except (RuntimeError, FloatingPointError, ValueError):
            return None
        y = [self.theta / np.sqrt(self.observed["theta"][1])]
        ones = [np.full(self.n, 1.0 / np.sqrt(self.observed["theta"][1]))]
        if self.current is not None:
            y.append(self.current / np.sqrt(self.observed["current"][1]))
            ones.append(np.zeros(self.n))
        A = np.column_stack([J, np.concatenate(ones)])
        r = np.concatenate(y) - base
        ok = np.isfinite(r) & np.all(np.isfinite(A), axis=1)
        if not ok.any():
            return None
        solution = np.linalg.lstsq(A[ok], r[ok], rcond=None)[0]
        return float(solution[3]) if np.isfinite(solution[3]) else None

    @property
    def held_offset(self) -> float | None:
        """After a reset: the counter's offset the starts are estimated with (None before one is)."""
        return self.cache.offsets.get("segment")

    def segment_offset(self, spec: PlantSpec, dir_log: np.ndarray) -> float | None:
        """After a reset, the counter's offset that replays the whole segment best under ``spec`` and
        ``dir_log`` (a model that lacks an effect, as the base does, bends it); None otherwise."""
        if self.angle_reference_known:
            return None
        return self._segment_offset(without_offset(spec), spec.I0, self.x0(spec, dir_log), dir_log)

    def start_with_offset(self, spec: PlantSpec, dir_log: np.ndarray, offset: float) -> Start:
        """The start under ``spec`` and ``dir_log`` with the counter's ``offset`` (not remembered)."""
        self.x0(spec, dir_log)
        return self.cache.estimators[without_offset(spec)].start(dir_log, spec.I0, offset=offset,
                                                                 shifted=self.lost_shifts)

    def hold_offset(self, spec: PlantSpec | None, offset: float) -> None:
        """Hold the counter's ``offset``; the starts under ``spec``'s plant (None: every plant's) are
        estimated again with it."""
        self.cache.offsets["segment"] = offset
        plant = None if spec is None else without_offset(spec)
        for key in [k for k in self.cache.starts if plant is None or k[0] == plant]:
            del self.cache.starts[key]

    def pin_start(self, spec: PlantSpec, dir_log: np.ndarray, start: Start) -> None:
        """Use ``start`` for ``spec`` under ``dir_log`` from now on (a start refined on more than the
        first seconds: ``discover.start_refit``)."""
        self.x0(spec, dir_log)
        plant = without_offset(spec)
        self.cache.starts[(plant, self.cache.estimators[plant].window(dir_log, self.lost_shifts), spec.I0)] = start

    def simulate_ways(self, spec: PlantSpec, dir_log: np.ndarray) -> dict[str, SimResult]:
        """Closed loop and replay at the recording's own instants, from its start (validation's two ways)."""
        start = self.x0(spec, dir_log)
        return {way: self.run(start, spec, dir_log, t=self.t, closed_loop=way == "closed_loop")
                for way in ("closed_loop", "replay")}

    def replay(self, spec: PlantSpec, x0: Start | tuple[float, float, float] | None = None,
               dir_log: np.ndarray | None = None, n: int | None = None) -> SimResult:
        """The logged command (or ``dir_log``) drives the model (smooth in the parameters), from
        the start estimated for that command (or ``x0``: a fixed state, or a start estimated for
        this measurement's own command); ``n``: only the first n samples."""
        d = self.dir if dir_log is None else dir_log
        m = self.n if n is None else n
        if x0 is None:
            start = self.x0(spec, d)
        elif isinstance(x0, Start) and dir_log is not None and not np.array_equal(d, self.dir):
            # the start depends on the command replayed (an inferred onset), under the sensor offset ``x0`` had
            start = self.x0(replace(spec, I0=x0.current_offset), d)
        else:
            start = x0 if isinstance(x0, Start) else Start.given(x0)
        return self.run(start, spec, d, n=m)

    def run(self, start: Start, spec: PlantSpec, dir_log: np.ndarray, *, n: int | None = None,
            t: np.ndarray | None = None, closed_loop: bool = False) -> SimResult:
        """``start.simulate`` on the first ``n`` of the recording's instants (``t``: default the fitting
        grid); a reversal at a lost row is decided on the measured angle (``with_lost_samples``), in the
        counter's frame the sketch decided in, not on the model's: fixed by the data, so the replay is
        smooth in the model's parameters, and right after a reset, where the two frames differ."""
        m = self.n if n is None else n
        t = self.t_fit if t is None else t
        return start.simulate(spec, t[:m], dir_log[:m], closed_loop=closed_loop, angle=self.theta[:m],
                              shifted=self.lost_shifts)


# Discovery fits the first MAX_SAMPLES samples of a longer recording: each candidate costs a few
# dozen replays, and the 10 s budget holds for about this many (100 s of a 50 ms sketch).
MAX_SAMPLES = 2000

# The start's step for the whole segment's response to it (a fraction of each state's typical size).
OFFSET_STEP = 1e-3

# Sample instants are replayed on this grid while fitting: micros() stamps make every step
# different, and each distinct step costs the simulator a matrix exponential; moving an instant
# by <= 50 us moves the angle by < w * 5e-5 ~ 1e-4 rad, a third of one encoder count's noise.
SIM_GRID_S = 1e-4


def _column(kin: pd.DataFrame, name: str) -> np.ndarray | None:
    if name not in kin.columns:
        return None
    return kin[name].to_numpy(dtype=float, na_value=np.nan)


def measurement_from_kinematics(kin: pd.DataFrame, config: RigConfig, name: str,
                                angle_reference_known: bool = True,
                                zero_samples: dict[str, int] | None = None,
                                max_samples: int = MAX_SAMPLES) -> Measurement:
    """Arrays for fitting from the first ``max_samples`` rows of a kinematics table; refuses tables
    discovery cannot use."""
    if "t_s" in kin.columns and "theta_rad" not in kin.columns:
        raise PdrError("discovery needs the angle: this recording has no encoder column (columns.counts = \"\"), "
                       "and the catalogued effects are told apart by their fingerprints in the angle and velocity"
                       + ("; validation compares its current with the model instead" if "dir" in kin.columns else ""),
                       path=name)
    for col in ("t_s", "theta_rad"):
        if col not in kin.columns:
            raise PdrError(f"kinematics table lacks column '{col}', which discovery needs", path=name)
    total = len(kin)
    kin = kin.iloc[:max_samples].reset_index(drop=True)
    if len(kin) < 20:
        raise PdrError(f"only {len(kin)} samples; discovery needs at least 20 to fit and hold out", path=name)
    t = _column(kin, "t_s")
    theta = _column(kin, "theta_rad")
    if t is not None and np.all(np.isfinite(t)):
        t = sample_instants(t)
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)):
        raise PdrError("sample times must be finite and strictly increasing", path=name)
    if not np.all(np.isfinite(theta)):
        raise PdrError("theta_rad has missing values", path=name)
    omega = _column(kin, "omega_rad_s")
    if omega is None:
        omega = np.full_like(theta, np.nan)
    current = _column(kin, "current_a")
    if current is not None and not np.all(np.isfinite(current)):
        current = None
    d, source = _command(kin)
    if d is None:
        raise PdrError("kinematics table lacks a usable 'dir' column (-1/0/1, logged or inferred); "
                       "replay needs the command sequence", path=name)
    t_fit = np.round(t / SIM_GRID_S) * SIM_GRID_S
    if np.any(np.diff(t_fit) <= 0):
        t_fit = t
    return Measurement(name=name, config=config, kinematics=kin, t=t, t_fit=t_fit, theta=theta, omega=omega,
                       current=current, dir=d, dir_source=source, samples_in_recording=total,
                       angle_reference_known=angle_reference_known, zero_samples=dict(zero_samples or {}))


def _command(kin: pd.DataFrame) -> tuple[np.ndarray | None, str]:
    """The derive stage's ``dir`` (logged, or inferred from the guards when ``dir_inferred``)."""
    if "dir" not in kin.columns:
        return None, ""
    values = kin["dir"].to_numpy(dtype=float, na_value=np.nan)
    if not (np.all(np.isfinite(values)) and np.all(np.isin(values, (-1, 0, 1)))):
        return None, ""
    inferred = "dir_inferred" in kin.columns and bool(kin["dir_inferred"].to_numpy(dtype=bool).any())
    return values.astype(np.int8), "inferred" if inferred else "logged"
