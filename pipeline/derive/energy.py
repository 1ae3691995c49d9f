"""Energy of a run: the paper's estimate and a physical balance (Sec. IV-C, docs/MODEL.md).

The paper's figure ``V_RMS * T_s * sum |y[k-1] + y[k]| / 2`` is kept verbatim so
its numbers (16.496 J simulated, 21.582 J measured, +30.83 %) can be reproduced,
but it is not an energy balance: it multiplies |I| by a constant voltage.  The
companions below are: the signed input energy ``int u I dt`` (u held over each
sample interval, as the Arduino holds it), where it goes (copper, friction, the
back-EMF/torque mismatch) and what is stored (spring, kinetic, magnetic).
The residual closes the books: near zero on a simulation sampled finely
enough, and on a recording it shows what the model does not account for.

Why a separate ``emf_torque_mismatch_j`` term: Table I gives Ke = 1.1459 V s/rad
but Kt = 0.01819 N m/A.  In a consistent motor they are equal in SI units; with
the paper's values the back-EMF absorbs ``Ke w I`` of electrical power while
only ``Kt w I`` appears as mechanical power, so ``(Ke - Kt) int w I dt`` leaves
the model as if it were a loss.  Naming it keeps the residual meaningful.

One function serves measured runs (derive stage) and simulated ones (the model
and validation stages), so "experiment vs simulation" compares like with like.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pipeline.model.effects import PlantSpec

ENERGY_KEYS = (
    "energy_paper_j", "input_energy_j", "copper_loss_j", "friction_loss_j",
    "emf_torque_mismatch_j", "spring_energy_change_j", "kinetic_energy_change_j",
    "magnetic_energy_change_j", "load_work_j", "balance_residual_j",
)


def paper_energy_j(current: np.ndarray, v_rms: float, period_s: float) -> float:
    """The paper's trapezoid on |I| (Sec. IV-C): V_RMS * T_s * sum_k |y[k-1] + y[k]| / 2.

    Uses the nominal T_s, as the paper does (500 samples over 24.95 s, 50 ms):
    paper figures are 16.496 J (simulation) and 21.582 J (experiment).
    """
    y = np.asarray(current, dtype=float)
    if len(y) < 2:
        return float("nan")             # no interval: nothing to integrate (null in JSON, never 0)
    return float(v_rms * period_s * np.sum(np.abs(y[:-1] + y[1:])) / 2.0)


def applied_voltage(t: np.ndarray, dirs: np.ndarray, v_drive: float, Td: float = 0.0) -> np.ndarray:
    """Mean voltage over each sample interval [t_k, t_k+1] when the command reaches the motor ``Td`` late.

    The command decided at sample j acts from t_j + Td (``loop_delay``);
    before t_0 + Td the motor is taken as off.  With Td = 0 this is just
    ``dirs * v_drive`` (the zero-order hold).  The last entry repeats the
    last interval's value (it is never integrated).
    """
    t = np.asarray(t, dtype=float)
    u = np.asarray(dirs, dtype=float) * v_drive
    if Td <= 0.0 or len(t) < 2:
        return u
    # cumulative integral of the delayed input: piecewise linear with breakpoints t_j + Td
    knots = np.concatenate([t + Td, [t[-1] + Td + 1.0]])
    cum = np.concatenate([[0.0], np.cumsum(u * np.diff(knots))])
    U = np.interp(t, knots, cum, left=0.0)
    out = np.empty(len(t))
    out[:-1] = np.diff(U) / np.diff(t)
    out[-1] = out[-2]
    return out


def motor_on_start(dirs: np.ndarray) -> int:
    """First sample at which the sketch drives the motor (``len(dirs)`` if never): the paper's
    window starts there (its N = 500 samples are the motor-on run, not the logging before it)."""
    on = np.flatnonzero(np.asarray(dirs) != 0)
    return int(on[0]) if len(on) else len(dirs)


def run_energy(t: np.ndarray, current: np.ndarray, omega: np.ndarray, theta: np.ndarray,
               dirs: np.ndarray, spec: PlantSpec) -> dict[str, float]:
    """The energy figures of one run, measured or simulated, from its commands: the one entry point.

    The derive stage (measured), the validation stage (measured and both simulations) and
    ``pdr simulate`` all call this, so "experiment vs simulation" compares like with like:
    the voltage the motor sees (``dirs`` delayed by ``spec.Td``, after the driver drop) and
    the supply's V_RMS for the paper's estimate, taken over the motor-on window
    (``motor_on_start``); the physical balance covers the whole run.
    """
    u = applied_voltage(t, dirs, spec.v_drive, spec.Td)
    out = energy_terms(t, current, omega, theta, u, spec, v_rms=spec.v_rms, period_s=spec.period_s)
    k0 = motor_on_start(dirs)
    out["energy_paper_j"] = paper_energy_j(np.asarray(current, dtype=float)[k0:], spec.v_rms, spec.period_s)
    return out


def dead_zone(theta: np.ndarray, gap: float) -> np.ndarray:
    """dz(theta): the angle the springs feel through a backlash of total width ``gap`` centred on 0."""
    theta = np.asarray(theta, dtype=float)
    if gap <= 0.0:
        return theta
    return np.sign(theta) * np.maximum(np.abs(theta) - gap / 2.0, 0.0)


def _trapezoid(y: np.ndarray, t: np.ndarray) -> float:
    if len(y) < 2:
        return float("nan")
    return float(np.sum((y[:-1] + y[1:]) * np.diff(t)) / 2.0)


def _change(y: np.ndarray) -> float:
    return float(y[-1] - y[0]) if len(y) >= 2 else float("nan")


def energy_terms(t: np.ndarray, current: np.ndarray, omega: np.ndarray, theta: np.ndarray,
                 u: np.ndarray, spec: PlantSpec, v_rms: float, period_s: float) -> dict[str, float]:
    """All energy figures of one run, in joules (keys: ``ENERGY_KEYS``).

    ``t`` [s] sample instants (uneven allowed); ``current`` [A] the armature
    current (pass ``SimResult.current`` for a simulation, the measured current
    for a recording); ``omega`` [rad/s]; ``theta`` [rad]; ``u`` [V] the voltage
    applied from each sample to the next (zero-order hold, ``dir * v_drive``).
    Integrals are trapezoids on the real time axis; stored-energy changes are
    last sample minus first.  With fewer than two samples every figure is NaN
    (nothing to integrate), never 0.
    """
    t = np.asarray(t, dtype=float)
    current = np.asarray(current, dtype=float)
    omega = np.asarray(omega, dtype=float)
    theta = np.asarray(theta, dtype=float)
    u = np.asarray(u, dtype=float)
    n = len(t)
    if not (len(current) == len(omega) == len(theta) == len(u) == n):
        raise ValueError("energy_terms: t, current, omega, theta and u must have the same length")
    p = spec.params
    electrical = electrical_terms(t, current, u, spec, v_rms, period_s)
    input_j, copper, magnetic = (electrical[k] for k in ("input_energy_j", "copper_loss_j", "magnetic_energy_change_j"))
    friction = _trapezoid(p.b * omega ** 2 + spec.Tc * np.abs(omega), t)          # b w^2 + Tc |w|
    mismatch = (p.Ke - p.Kt) * _trapezoid(omega * current, t)                     # (Ke - Kt) w I
    spring = _change(0.5 * p.spring_torque_per_rad * dead_zone(theta, spec.gap) ** 2)  # Ks = R^2 (K1 + K2)
    kinetic = _change(0.5 * p.J * omega ** 2)
    load = -spec.torque * _change(theta)                                          # work against a constant torque
    residual = input_j - copper - friction - mismatch - spring - kinetic - magnetic - load
    return {
        "energy_paper_j": electrical["energy_paper_j"],
        "input_energy_j": input_j,
        "copper_loss_j": copper,
        "friction_loss_j": friction,
        "emf_torque_mismatch_j": mismatch,
        "spring_energy_change_j": spring,
        "kinetic_energy_change_j": kinetic,
        "magnetic_energy_change_j": magnetic,
        "load_work_j": load,
        "balance_residual_j": residual,
    }


# The figures of ENERGY_KEYS that need neither the angle nor the velocity
ELECTRICAL_KEYS = ("energy_paper_j", "input_energy_j", "copper_loss_j", "magnetic_energy_change_j")


def electrical_terms(t: np.ndarray, current: np.ndarray, u: np.ndarray | None, spec: PlantSpec,
                     v_rms: float, period_s: float) -> dict[str, float]:
    """The energy figures the current alone gives (``ELECTRICAL_KEYS``; ``input_energy_j`` only with the
    applied voltage ``u``): all a recording without an encoder has, and part of ``energy_terms``."""
    t = np.asarray(t, dtype=float)
    current = np.asarray(current, dtype=float)
    p = spec.params
    out = {"energy_paper_j": paper_energy_j(current, v_rms, period_s)}
    if u is not None:
        # u[k] is held over [t_k, t_k+1]; the current is trapezoidal within the interval
        u = np.asarray(u, dtype=float)
        out["input_energy_j"] = (float(np.sum(u[:-1] * (current[:-1] + current[1:]) * np.diff(t)) / 2.0)
                                 if len(t) >= 2 else float("nan"))
    out["copper_loss_j"] = p.Ra * _trapezoid(current ** 2, t)                     # Ra I^2
    out["magnetic_energy_change_j"] = _change(0.5 * p.La * current ** 2)
    return out


def run_electrical_energy(t: np.ndarray, current: np.ndarray, dirs: np.ndarray | None,
                          spec: PlantSpec) -> dict[str, float]:
    """``run_energy`` for a recording without an encoder: ``electrical_terms`` from its commands (the
    paper's window from the motor-on start, the input energy from the applied voltage) or, without
    ``dirs``, over the whole run and with no input energy."""
    u = applied_voltage(t, dirs, spec.v_drive, spec.Td) if dirs is not None else None
    out = electrical_terms(t, current, u, spec, v_rms=spec.v_rms, period_s=spec.period_s)
    k0 = motor_on_start(dirs) if dirs is not None else 0
    out["energy_paper_j"] = paper_energy_j(np.asarray(current, dtype=float)[k0:], spec.v_rms, spec.period_s)
    return out


# Terms that depend on the current, and so carry its noise; the others (friction, spring,
# kinetic) depend on the encoder alone, whose quantisation is far smaller here.
CURRENT_TERMS = ("energy_paper_j", "input_energy_j", "copper_loss_j", "emf_torque_mismatch_j",
                 "magnetic_energy_change_j", "balance_residual_j")


def current_noise_a(current: np.ndarray, smooth: np.ndarray, window: int, order: int) -> float:
    """Standard deviation of the sensor noise: the scatter of the logged current about its local
    polynomial fit, scaled up for the fit's own degrees of freedom (``window - order - 1`` of ``window``)."""
    r = np.asarray(current, dtype=float) - np.asarray(smooth, dtype=float)
    r = r[np.isfinite(r)]
    if len(r) < 2 or window <= order + 1:
        return float("nan")
    return float(np.sqrt(np.mean(r * r) * window / (window - order - 1)))


def energy_uncertainty(t: np.ndarray, current: np.ndarray, omega: np.ndarray, dirs: np.ndarray,
                       spec: PlantSpec, noise_a: float,
                       smoother: Callable[[np.ndarray], np.ndarray] | None = None) -> dict[str, float]:
    """One standard deviation [J] of each current-dependent energy figure from white current noise.

    Linear propagation: the figures are computed from the smoothed current S(I + e), so
    a figure F changes by g . S e (g = dF/dI at the smoothed current) and
    sigma_F = noise * ||S^T g||.  ``smoother`` is S (the stage's phase-wise local fit,
    nearly symmetric, so S stands in for S^T; it is given the gradients as the columns
    of one (n, 6) array); without it the raw noise is propagated.
    Smoothing preserves sums, so the long sums (input, paper) keep nearly all the noise
    (a one-ADC-step noise puts ~1.1 % on the paper's 500-sample sum whatever the
    smoother), while the balance residual loses much of it: a slow current error moves
    the input and the stored magnetic energy together.
    """
    t = np.asarray(t, dtype=float)
    i = np.asarray(current, dtype=float)
    w = np.asarray(omega, dtype=float)
    n = len(t)
    if n < 2 or not np.isfinite(noise_a):
        return {k: float("nan") for k in CURRENT_TERMS}
    p = spec.params
    u = applied_voltage(t, dirs, spec.v_drive, spec.Td)
    h = np.diff(t)
    trap = np.zeros(n)                                   # d/dy_k of the trapezoid of y over t
    trap[:-1] += h / 2.0
    trap[1:] += h / 2.0
    d_input = np.zeros(n)
    d_input[:-1] += u[:-1] * h / 2.0
    d_input[1:] += u[:-1] * h / 2.0
    d_copper = 2.0 * p.Ra * i * trap
    d_mismatch = (p.Ke - p.Kt) * w * trap
    d_magnetic = np.zeros(n)
    d_magnetic[-1] += p.La * i[-1]
    d_magnetic[0] -= p.La * i[0]
    d_paper = np.zeros(n)
    k0 = motor_on_start(dirs)
    s = np.sign(i[k0:-1] + i[k0 + 1:]) * spec.v_rms * spec.period_s / 2.0
    d_paper[k0:-1] += s
    d_paper[k0 + 1:] += s
    d_residual = d_input - d_copper - d_mismatch - d_magnetic
    grads = {"energy_paper_j": d_paper, "input_energy_j": d_input, "copper_loss_j": d_copper,
             "emf_torque_mismatch_j": d_mismatch, "magnetic_energy_change_j": d_magnetic,
             "balance_residual_j": d_residual}
    stacked = np.column_stack(list(grads.values()))
    if smoother is not None:
        stacked = smoother(stacked)                       # one pass for every figure's gradient
    return {k: float(noise_a * np.linalg.norm(stacked[:, j])) for j, k in enumerate(grads)}
