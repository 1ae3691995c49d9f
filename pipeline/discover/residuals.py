"""Localise where model and measurement disagree, and how far above the noise that is.

Two things live here:

* the noise floor of each signal, from the recording itself, with no model and no
  rig settings (``pipeline.estimate.noise``): a robust scale of the signal's third
  (current) or fifth (angle) difference (everything smooth cancels, white noise
  remains), never below the quantisation q^2/12 with q read off the data (encoder
  count, ADC step), plus the clock's truncation for the angle;
* signatures: where a residual concentrates, each one the fingerprint of a
  catalogued effect (MODEL.md): a bias in the current alone (sensor offset), a
  burst right after each switch (loop delay), energy near zero velocity
  (Coulomb friction), after each angle zero crossing (backlash), a constant per
  mode in the electrical equation (driver drop), and projections on w (viscous),
  dw/dt (inertia) and theta (spring).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from pipeline.discover.measurement import Measurement
from pipeline.estimate import Model, Target
from pipeline.model.params import PlantSpec
from pipeline.model.simulate import SimResult


def residuals(meas: Measurement, sim: SimResult) -> dict[str, np.ndarray]:
    """Measured minus simulated, per fitted signal (current as the sensor reads it).

    The angle's residual is taken about a constant of at most one encoder count: how a sketch's
    count quantises (floor or round, the decoder's edges) biases the logged angle by up to a
    count, a nuisance no effect should be named for.  A constant torque moves the replayed angle
    by hundreds of counts, so this hides none of it.  After a board reset the counter's zero is
    anywhere (``Measurement.angle_reference_known``): the whole constant is then a nuisance, and a
    constant torque, which only moves the angle's centre, cannot be told from it."""
    r = meas.theta - sim.theta
    bias = float(np.mean(r))
    if meas.angle_reference_known:
        count = 2.0 * np.pi / meas.config.encoder.counts_per_rev
        bias = min(max(bias, -count), count)
    out = {"theta": r - bias if np.isfinite(bias) else r}
    if meas.current is not None:
        out["current"] = meas.current - sim.current_measured
    return out


# A recording whose signal never moves (a stuck sensor or timer) has no measurable noise; its floor is
# this instead of 0, so the ratios against it stay finite.
MIN_FLOOR = 1e-30


def noise_floor(meas: Measurement, sim: SimResult | None = None) -> dict[str, float]:
    """Per-sample variance of each fitted signal that no model can remove, from the recording
    itself (``pipeline.estimate.noise``: white part, at least the quantisation, plus the clock's
    share for the angle), the numbers the start is weighted by.  The same for every model, so
    ``sim`` is not needed (kept for callers that pass the base model's replay)."""
    return {s: max(var, MIN_FLOOR) for s, (_, var) in meas.observed.items() if s in meas.signals}


# ---------------------------------------------------------------- signatures

@dataclass(frozen=True)
class Events:
    """Sample indices the signatures align on."""

    switches: np.ndarray        # first sample after each command reversal
    zero_crossings: np.ndarray  # first sample after each sign change of the measured angle
    mode: np.ndarray            # +1 / -1 / 0 command in force over each sample


def events(meas: Measurement) -> Events:
    d = meas.dir
    sw = np.flatnonzero((d[1:] != d[:-1]) & (d[1:] != 0) & (d[:-1] != 0)) + 1
    step = 2.0 * np.pi / meas.config.encoder.counts_per_rev
    s = np.sign(np.where(np.abs(meas.theta) <= step, 0.0, meas.theta))
    nz = np.flatnonzero(s != 0)
    zc = nz[1:][s[nz[1:]] != s[nz[:-1]]] if len(nz) > 1 else np.array([], dtype=int)
    mode = np.concatenate([[0], d[:-1]]).astype(int)   # the command decided at k-1 acts over (k-1, k]
    return Events(switches=sw, zero_crossings=zc, mode=mode)


def _window_mask(n: int, starts: np.ndarray, width: int) -> np.ndarray:
    m = np.zeros(n, dtype=bool)
    for s in starts:
        m[s:s + width] = True
    return m


def _ratio(r: np.ndarray, mask: np.ndarray) -> float:
    """RMS of r inside the mask over RMS outside (1 = no concentration)."""
    if mask.sum() < 3 or (~mask).sum() < 3:
        return 1.0
    inside = np.sqrt(np.mean(r[mask] ** 2))
    outside = np.sqrt(np.mean(r[~mask] ** 2))
    return float(inside / outside) if outside > 0 else float("inf") if inside > 0 else 1.0


def _projection(r: np.ndarray, x: np.ndarray) -> float:
    """Share of the residual's energy along x (0..1): how much a term proportional to x explains."""
    ok = np.isfinite(r) & np.isfinite(x)
    r, x = r[ok], x[ok]
    den = float(np.dot(x, x) * np.dot(r, r))
    return float(np.dot(r, x) ** 2 / den) if den > 0 else 0.0


def signatures(meas: Measurement, sim: SimResult, floor: dict[str, float]) -> dict[str, dict[str, float]]:
    """Numbers describing where each residual lives; each maps to effect fingerprints."""
    ev = events(meas)
    res = residuals(meas, sim)
    n = meas.n
    w = sim.omega
    wmax = float(np.max(np.abs(w))) or 1.0
    slow = np.abs(w) < 0.15 * wmax
    after_switch = _window_mask(n, ev.switches, 3)
    after_zero = _window_mask(n, ev.zero_crossings, 3)
    accel = np.gradient(w, meas.t)
    out: dict[str, dict[str, float]] = {}
    for s, r in res.items():
        mse = float(np.mean(r * r))
        feats = {
            "mse": mse,
            "excess": max(mse / floor[s] - 1.0, 0.0),      # structure above the noise, in noise variances
            "mean": float(np.mean(r)),
            "mean_q1": float(np.mean(r[ev.mode == 1])) if np.any(ev.mode == 1) else 0.0,
            "mean_q2": float(np.mean(r[ev.mode == -1])) if np.any(ev.mode == -1) else 0.0,
            "bias_share": float(np.mean(r) ** 2 / mse) if mse > 0 else 0.0,
            "after_switch_ratio": _ratio(r, after_switch),
            "near_zero_velocity_ratio": _ratio(r, slow),
            "after_zero_crossing_ratio": _ratio(r, after_zero),
            "share_along_omega": _projection(r, w),
            "share_along_accel": _projection(r, accel),
            "share_along_theta": _projection(r, sim.theta),
            "share_along_mode": _projection(r, ev.mode.astype(float)),
        }
        out[s] = feats
    return out


def describe(sig: dict[str, dict[str, float]], floor: dict[str, float]) -> list[str]:
    """The localisation in words and numbers, most telling first."""
    unit = {"theta": "rad", "current": "A"}
    lines = []
    for s, f in sig.items():
        u = unit.get(s, "")
        rms, noise = np.sqrt(f["mse"]), np.sqrt(floor[s])
        if f["excess"] < 1.0:
            lines.append(f"the {s} residual is at the noise floor (RMS {rms:.3g} {u} vs noise {noise:.3g} {u})")
            continue
        lines.append(f"the {s} residual has RMS {rms:.3g} {u}, {rms / noise:.1f}x its noise floor ({noise:.3g} {u})")
        if f["bias_share"] > 0.3:
            both = np.sign(f["mean_q1"]) == np.sign(f["mean_q2"])
            lines.append(f"the {s} residual has a mean of {f['mean']:+.3g} {u} "
                         f"({'in both modes' if both else 'of opposite sign in the two modes'}: "
                         f"q1 {f['mean_q1']:+.3g}, q2 {f['mean_q2']:+.3g}); {100 * f['bias_share']:.0f}% of its energy")
        for key, text in (("after_switch_ratio", "in the 3 samples after each switch"),
                          ("near_zero_velocity_ratio", "near zero velocity (|w| < 15% of its peak)"),
                          ("after_zero_crossing_ratio", "in the 3 samples after each angle zero crossing")):
            if f[key] > 1.5:
                lines.append(f"the {s} residual is {f[key]:.1f}x larger {text} than elsewhere")
        for key, text in (("share_along_omega", "proportional to the velocity"),
                          ("share_along_accel", "proportional to the acceleration"),
                          ("share_along_theta", "proportional to the angle"),
                          ("share_along_mode", "a constant of opposite sign in the two modes")):
            if f[key] > 0.3:
                lines.append(f"{100 * f[key]:.0f}% of the {s} residual energy is {text}")
    return lines


def _bins(x: np.ndarray, n: int) -> np.ndarray:
    """Quantile edges of ``x`` (n bins), unique."""
    x = x[np.isfinite(x)]
    return np.unique(np.quantile(x, np.linspace(0.0, 1.0, n + 1))) if len(x) else np.array([0.0, 1.0])


def binned(meas: Measurement, sim: SimResult, floor: dict[str, float], n_bins: int = 5,
           max_lag: int = 6) -> dict[str, list[dict]]:
    """Residual RMS per signal, binned in state (|w|, theta, measured current) and aligned on
    events (lags after each switch, each velocity reversal and each angle zero crossing),
    in noise standard deviations (1 = at the noise floor)."""
    res = residuals(meas, sim)
    noise = {s: np.sqrt(floor[s]) for s in res}
    # bins and events come from the measurement, so before and after share them
    state = {"by_abs_velocity": np.abs(meas.omega), "by_angle": meas.theta}
    if meas.current is not None:
        state["by_current"] = meas.current
    out: dict[str, list[dict]] = {}
    for key, x in state.items():
        edges = _bins(x, n_bins)
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
        rows = []
        for b in range(len(edges) - 1):
            m = (idx == b) & np.isfinite(x)
            if m.any():
                rows.append({"from": float(edges[b]), "to": float(edges[b + 1]), "n": int(m.sum()),
                             **{f"{s}_rms_noise": float(np.sqrt(np.mean(r[m] ** 2)) / noise[s])
                                for s, r in res.items()}})
        out[key] = rows
    ev = events(meas)
    w = np.nan_to_num(meas.omega)
    reversals = np.flatnonzero(np.sign(w[1:]) * np.sign(w[:-1]) < 0) + 1
    for key, starts in (("after_switch", ev.switches), ("after_velocity_reversal", reversals),
                        ("after_zero_crossing", ev.zero_crossings)):
        rows = []
        for lag in range(max_lag):
            k = starts + lag
            k = k[k < meas.n]
            if len(k):
                rows.append({"lag": lag, "n": int(len(k)),
                             **{f"{s}_rms_noise": float(np.sqrt(np.mean(r[k] ** 2)) / noise[s])
                                for s, r in res.items()}})
        out[key] = rows
    return out


def target_of(meas: Measurement, on_replay: Callable[[PlantSpec], None] | None = None) -> Target:
    """The recording as the estimation core sees it: a model's replay residuals (its start, commands
    in flight and, after a reset, its counter zero solved for that model) and the noise floor;
    ``on_replay`` is told each plant replayed (a caller counting its work)."""
    def of(model: Model) -> dict[str, np.ndarray]:
        spec = replace(meas.config, model=model.base).plant_spec(model.effects)
        if on_replay is not None:
            on_replay(spec)
        return residuals(meas, meas.replay(spec))
    return Target(name=meas.name, residuals=of, noise=noise_floor(meas))
