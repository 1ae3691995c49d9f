"""Rerun the hybrid model on a recording, two ways, and measure the difference.

Pure functions from a kinematics table (derive stage) and a ``PlantSpec`` to
numbers and tables; no file access here (``stage.py`` is the shell).

Two ways, as the issue asks:

- closed loop: the simulator's own sampled guard decides the switches, as the
  paper's Simulink model did (Sec. IV); switch-time slips of one sample show
  up as large errors after the slip;
- replay: the logged (or inferred) ``dir`` sequence drives the motor, which
  isolates the continuous dynamics (eqs. 2, 4/8, 5) from the guard.

When the closed loop happens to switch at exactly the logged samples the two
are the same computation and must give identical signals (tested).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.derive.energy import run_electrical_energy, run_energy
from pipeline.model.effects import PlantSpec
from pipeline.model.simulate import SimResult
from pipeline.estimate.initial_state import Observed, StartEstimator, without_offset
from pipeline.estimate.start import Start
from pipeline.estimate.switch_timing import Timing, pattern_misfit, settle
from pipeline.validate.metrics import signal_errors
from pipeline.estimate.noise import angle_noise, sample_instants, signal_noise

WAYS = ("closed_loop", "replay")
# Why a way is not run on a recording that lacks what it needs (a capture without an encoder column)
WAY_NEEDS = {"closed_loop": ("theta_rad", "closed loop skipped: the simulator's guard switches on the angle, and "
                                          "without an encoder there is no measured angle to hold it to"),
             "replay": ("dir", "replay skipped: no logged dir, and without the angle the commands cannot be "
                               "inferred from the guards, so nothing drives the model")}


def possible_ways(kin: pd.DataFrame) -> tuple[str, ...]:
    """The ways this recording can be compared: both with an encoder, replay alone with dir but no angle."""
    return tuple(way for way in WAYS if WAY_NEEDS[way][0] in kin.columns)


def skipped_ways(kin: pd.DataFrame) -> dict[str, str]:
    """Each way this recording cannot be compared, with the sentence saying why."""
    return {way: why for way, (needs, why) in WAY_NEEDS.items() if needs not in kin.columns}


def observed_signals(kin: pd.DataFrame) -> Observed:
    """The logged signals the start is fitted to, each with its noise variance from the recording."""
    t = column(kin, "t_s", dtype=float)
    out = {}
    if "theta_rad" in kin.columns:
        theta = column(kin, "theta_rad", dtype=float)
        omega = column(kin, "omega_rad_s", dtype=float, na_value=np.nan)
        out["theta"] = (theta, angle_noise(theta, omega, t))
    if "current_a" in kin.columns:
        current = column(kin, "current_a", dtype=float, na_value=np.nan)
        out["current"] = (current, signal_noise(current))
    return out


def initial_state(kin: pd.DataFrame, spec: PlantSpec, timing: Timing | None = None) -> Start:
    """x0 = [I, w, delta] at the first sample and the pre-log commands, estimated under ``spec`` (and the
    switches' ``timing``, default the logged or inferred commands as the rule fills lost rows).

    No at-rest rule: a recording may open mid-motion, and one noisy first reading would
    persist for La/Ra = 7 s; the first seconds pin the start down (``initial_state.py``).
    Validation and discovery share this estimate, so their MSEs are the same numbers.
    """
    timing = Timing(logged_dir(kin)) if timing is None else timing
    return _estimator(kin, spec).start(timing.dir, spec.I0, shifted=timing.shifted)


def _estimator(kin: pd.DataFrame, spec: PlantSpec) -> StartEstimator:
    return StartEstimator(without_offset(spec), sample_instants(column(kin, "t_s", dtype=float)), observed_signals(kin))


def settled_timing(kin: pd.DataFrame, spec: PlantSpec, half_count: float) -> tuple[Timing, Start]:
    """The switches the data leave open (``switch_timing``: an inferred one on a guard, a reversal or the
    motor's start in a gap of lost rows) settled by which timing ``spec`` replays better, as discovery
    settles them: a nuisance of the recording, so the MSEs measure the model, not the rule's guess.
    Returns the timing and the start estimated under it (one estimator for every timing tried)."""
    timing = Timing(logged_dir(kin))
    estimator = _estimator(kin, spec)
    if "theta_rad" not in kin.columns:
        return timing, estimator.start(timing.dir, spec.I0)
    t = sample_instants(column(kin, "t_s", dtype=float))
    theta = column(kin, "theta_rad", dtype=float)
    observed = observed_signals(kin)
    finite = np.logical_and.reduce([np.isfinite(y) for y, _ in observed.values()])

    def misfit(tm: Timing) -> float:
        start = estimator.start(tm.dir, spec.I0, shifted=tm.shifted)
        sim = start.simulate(spec, t, tm.dir, closed_loop=False, angle=theta, shifted=tm.shifted)
        model = {"theta": sim.theta, "current": sim.current_measured}
        return pattern_misfit({s: (y - model[s])[finite] for s, (y, _) in observed.items()},
                              {s: var for s, (_, var) in observed.items()})

    inferred = "dir_inferred" in kin.columns and bool(kin["dir_inferred"].to_numpy(dtype=bool).any())
    timing = settle(timing, t=t, theta=theta, guard=float(spec.guard_rad), half_count=half_count, inferred=inferred,
                    misfit=misfit)
    return timing, estimator.start(timing.dir, spec.I0, shifted=timing.shifted)


def logged_dir(kin: pd.DataFrame) -> np.ndarray:
    """The command sequence that drives replay: logged ``dir``, or the derive stage's inferred one."""
    return column(kin, "dir", dtype=np.int8)


def timing_json(kin: pd.DataFrame, timing: Timing | None) -> dict | None:
    """Where the replay's switches are a sample off the rule's (``validation.json``'s ``switch_timing``): the
    samples whose inferred command moved, and the logged samples after whose lost rows a reversal or start did."""
    if timing is None:
        return None
    t = column(kin, "t_s", dtype=float)
    return {"inferred_moved_s": [float(t[k]) for k in np.flatnonzero(timing.dir != logged_dir(kin))],
            "lost_rows_moved_after_s": [float(t[i]) for i in timing.shifted]}


def simulate_both(spec: PlantSpec, kin: pd.DataFrame, start: Start | None = None,
                  timing: Timing | None = None) -> dict[str, SimResult]:
    """Closed loop and replay at the recording's own sample instants, from its estimated start, under the
    switches' ``timing`` (default: the logged or inferred commands, lost rows filled by the sketch's rule);
    only the ``possible_ways``: none without both the angle and dir."""
    ways = possible_ways(kin)
    if not ways:
        return {}
    t = sample_instants(column(kin, "t_s", dtype=float))
    timing = Timing(logged_dir(kin)) if timing is None else timing
    start = initial_state(kin, spec, timing) if start is None else start
    angle = column(kin, "theta_rad", dtype=float) if "theta_rad" in kin.columns else None
    return {way: start.simulate(spec, t, timing.dir, closed_loop=way == "closed_loop", angle=angle,
                                shifted=timing.shifted) for way in ways}


def switch_indices(d: np.ndarray) -> np.ndarray:
    """Samples at which the command reversed (+1 <-> -1; motor-off samples are not switches)."""
    d = np.asarray(d)
    return np.flatnonzero((d[1:] != d[:-1]) & (d[1:] != 0) & (d[:-1] != 0)) + 1


def switch_differences(t: np.ndarray, d_measured: np.ndarray, d_sim: np.ndarray) -> dict[str, float]:
    """Switch-time slips: each logged switch paired with the nearest simulated one of the same sign."""
    im, isim = switch_indices(d_measured), switch_indices(d_sim)
    out = {"n_measured": int(len(im)), "n_simulated": int(len(isim)),
           "mean_abs_s": float("nan"), "max_abs_s": float("nan"), "n_slipped": 0}
    if len(im) == 0 or len(isim) == 0:
        return out
    diffs = []
    for k, tk in zip(im, t[im]):
        same = isim[np.asarray(d_sim)[isim] == np.asarray(d_measured)[k]]
        if len(same) == 0:
            continue
        diffs.append(t[same[np.argmin(np.abs(t[same] - tk))]] - tk)
    if diffs:
        a = np.abs(np.array(diffs))
        out.update(mean_abs_s=float(a.mean()), max_abs_s=float(a.max()),
                   n_slipped=int(np.sum(a > 1e-9)))
    return out


def oscillation_stats(t: np.ndarray, theta: np.ndarray, d: np.ndarray, guard: float) -> dict[str, float]:
    """Period, amplitude and overshoot of the bang-bang oscillation (Sec. IV-B).

    A switch to q2 is decided when theta has reached +theta_g, but the pinion
    keeps turning: the command reverses only at the next 50 ms sample and the
    current needs La/Ra to reverse.  So for every pair of consecutive switches
    the peak is the extreme angle between them, on the side of the guard that
    triggered the first one; the overshoot is how far that peak passed the guard.
    """
    idx = switch_indices(d)
    nan = float("nan")
    out = {"n_half_cycles": 0, "period_s": nan, "amplitude_rad": nan, "overshoot_rad": nan}
    if len(idx) < 2:
        return out
    peaks = []
    for a, b in zip(idx[:-1], idx[1:]):
        seg = theta[a:b + 1]
        peaks.append(seg.max() if d[a] < 0 else -seg.min())
    peaks = np.array(peaks)
    out.update(n_half_cycles=int(len(peaks)), period_s=float(2.0 * np.mean(np.diff(t[idx]))),
               amplitude_rad=float(peaks.mean()), overshoot_rad=float(np.mean(peaks - guard)))
    return out


def _difference(sim: dict[str, float], meas: dict[str, float], keys: tuple[str, ...]) -> dict[str, float]:
    return {k: float(sim[k] - meas[k]) for k in keys}


def compare(kin: pd.DataFrame, spec: PlantSpec, sims: dict[str, SimResult] | None = None) -> dict:
    """Everything ``validation.json`` holds about one run, for both ways."""
    sims = simulate_both(spec, kin) if sims is None else sims
    t = column(kin, "t_s", dtype=float)
    theta = column(kin, "theta_rad", dtype=float) if "theta_rad" in kin.columns else None
    d = logged_dir(kin) if "dir" in kin.columns else None
    guard = spec.guard_rad
    meas_osc = oscillation_stats(t, theta, d, guard) if theta is not None else None
    meas_energy = None
    if "current_a" in kin.columns:
        # the derive stage's current (smoothed within phases when it made one): the same
        # inputs and code as summary.json's energy, so validation's "measured" is derive's figure
        current = column(kin, "current_smooth_a" if "current_smooth_a" in kin.columns else "current_a", dtype=float)
        if theta is None:
            meas_energy = run_electrical_energy(t, current, d, spec)
        else:
            omega = np.nan_to_num(column(kin, "omega_rad_s", dtype=float, na_value=np.nan))
            meas_energy = run_energy(t, current, omega, theta, d, spec)
    out: dict = {"measured": {"oscillation": meas_osc, "energy": meas_energy}, "skipped": skipped_ways(kin)}
    osc_keys = ("period_s", "amplitude_rad", "overshoot_rad")
    for way, sim in sims.items():
        osc = oscillation_stats(sim.t, sim.theta, sim.dir, guard)
        energy = run_energy(sim.t, sim.current, sim.omega, sim.theta, sim.dir, spec)
        block = {
            "signals": signal_errors(kin, sim),
            "switches": switch_differences(t, d, sim.dir),
            "oscillation": osc,
            "oscillation_error": _difference(osc, meas_osc, osc_keys) if meas_osc is not None else None,
            "energy": energy,
            "energy_error": None,
        }
        if meas_energy is not None:
            e_sim, e_meas = energy["energy_paper_j"], meas_energy["energy_paper_j"]
            block["energy_error"] = {
                "paper_j": e_sim - e_meas,
                "paper_pct": 100.0 * (e_sim - e_meas) / e_meas if e_meas else float("nan"),
                "input_j": energy["input_energy_j"] - meas_energy.get("input_energy_j", np.nan),
            }
        out[way] = block
    out["agreement"] = None
    if len(sims) == 2:
        cl, rp = sims["closed_loop"], sims["replay"]
        out["agreement"] = {"same_switches": bool(np.array_equal(cl.dir, rp.dir)),
                            "max_abs_theta_diff_rad": float(np.max(np.abs(cl.theta - rp.theta)))}
    return out


def comparison_table(kin: pd.DataFrame, sims: dict[str, SimResult]) -> pd.DataFrame:
    """Measured beside both simulations and the residuals (measured - model), one row per sample
    (``schemas/comparison.json``); without an encoder the angle's columns and the closed loop's are
    left out, and without dir either, only the measured current remains."""
    cols = {"t_s": column(kin, "t_s", dtype=float)}
    for name in ("theta_rad", "omega_rad_s", "current_a"):
        if name in kin.columns:
            cols[name] = column(kin, name, dtype=float, na_value=np.nan)
    if "dir" in kin.columns:
        cols["dir"] = logged_dir(kin)
    for way, sim in sims.items():
        cols |= {f"theta_{way}_rad": sim.theta, f"omega_{way}_rad_s": sim.omega,
                 f"current_{way}_a": sim.current_measured, f"dir_{way}": sim.dir.astype(np.int8)}
    for way in sims:
        for signal, unit in (("theta", "rad"), ("omega", "rad_s"), ("current", "a")):
            measured = "current_a" if signal == "current" else f"{signal}_{unit}"
            if measured in cols:
                cols[f"{signal}_residual_{way}_{unit}"] = cols[measured] - cols[f"{signal}_{way}_{unit}"]
    return pd.DataFrame(cols)
