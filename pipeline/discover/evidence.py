"""A candidate effect's evidence in one round: fitted, then checked against every rule of
``selection.py``'s docstring (noise, held out, BIC, interval, signature, size).  One candidate at a
time; which candidates are tried, in which rounds, and what is adopted is ``selection.py``'s."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.discover.candidates import Evaluator, Fit, Scan, fit_candidate, parameter_of
from pipeline.discover.measurement import Measurement
from pipeline.discover.policy import DiscoveryPolicy
from pipeline.discover.residuals import events, residuals
from pipeline.model.effects import CATALOGUE, Effect

# The current's floor is itself an estimate (``noise.signal_noise``): over n samples its relative
# variance is ~3/n (measured on quantised noise, 150-2000 samples), so that many noise variances of
# the current's "structure" may be the floor's own error, which no effect removes; a held-out share is
# taken of the structure beyond ``DiscoveryPolicy.floor_sigmas`` of it.  A measured fact, not a threshold.
FLOOR_RELATIVE_VARIANCE = 3.0


@dataclass
class Assessment:
    """One candidate's fit and evidence in one round."""

    fit: Fit
    round: int
    delta_bic: float
    heldout_share: float                  # best share of held-out structure removed over the signals
    heldout_gain_floors: float            # best held-out MSE removed, in noise variances
    worst_worsening_floors: float         # the most any signal's held-out MSE grew, in noise variances
    structure_left: float                 # held-out MSE above the noise left after it, in noise variances
    signature_before: float
    signature_after: float
    checks: dict[str, bool] = field(default_factory=dict)

    @property
    def accepted(self) -> bool:
        return all(self.checks.values())

    @property
    def score(self) -> float:
        """The share of held-out structure the candidate removes (1 = all of it)."""
        return self.heldout_share

    def to_json(self) -> dict:
        f = self.fit
        return {
            "name": f.name, "score": round(self.score, 4), "round": self.round,
            "parameters": f.effect.parameters, "units": dict(CATALOGUE[f.name].UNITS),
            "interval": {f.parameter: list(f.interval)}, "fold_estimates": {f.parameter: list(f.fold_values)},
            "delta_bic": self.delta_bic, "heldout_nll_gain": f.heldout_nll_gain,
            "heldout_gain_noise_floors": self.heldout_gain_floors,
            "heldout_structure_left_noise_floors": self.structure_left,
            "heldout_mse_before": f.heldout_mse_before, "heldout_mse_after": f.heldout_mse_after,
            "signature_before": self.signature_before, "signature_after": self.signature_after,
            "checks": {k: bool(v) for k, v in self.checks.items()}, "accepted": bool(self.accepted),
        }


@dataclass
class Screened:
    """A candidate whose coarse scan gained too little to be worth a full fit this round."""

    name: str
    round: int
    value: float            # best scan point
    scan_gain: float        # nll decrease at that point, all samples

    accepted = False
    score = 0.0

    def to_json(self) -> dict:
        p = parameter_of(self.name)
        return {"name": self.name, "score": 0.0, "round": self.round, "parameters": {p: self.value},
                "units": dict(CATALOGUE[self.name].UNITS), "scan_nll_gain": self.scan_gain,
                "screened_out": True, "accepted": False}


# ------------------------------------------------------------ signatures per effect

def signature_energy(name: str, meas: Measurement, ev: Evaluator, effects: tuple[Effect, ...],
                     policy: DiscoveryPolicy) -> float:
    """Mean energy of the residual pattern that points at ``name``, in noise variances (~1 for
    pure noise): where the effect declares a local fingerprint (``Effect.SIGNATURE``), the
    residual there (averaged over the signals, so pure noise is ~1 with the current beside the angle
    too, as ``signature_noise`` assumes) -- right after each switch, near zero velocity, right after each angle zero
    crossing, the bias of the current alone; an effect acting everywhere has no local window,
    so the whole residual.

    Local windows, not projections on w or dw/dt: when the base model drifts out of phase
    with the recording, its residual is no small perturbation along any such direction."""
    sim = ev.sim(effects)
    res = residuals(meas, sim)
    where = CATALOGUE[name].SIGNATURE
    if where == "current_bias":
        r = res.get("current")
        return float(np.mean(r)) ** 2 / ev.floor["current"] * len(r) if r is not None else 0.0
    if where == "after_switch":
        m = _after(meas.n, events(meas).switches, policy.signature_window)
    elif where == "after_zero_crossing":
        m = _after(meas.n, events(meas).zero_crossings, policy.signature_window)
    elif where == "low_speed":
        w = sim.omega
        wmax = float(np.nanmax(np.abs(w))) if np.any(np.isfinite(w)) else 1.0
        m = np.abs(w) < policy.low_speed_share * wmax
    else:
        m = np.ones(meas.n, dtype=bool)
    if not m.any():
        return 0.0
    return float(np.mean([np.mean(r[m] ** 2) / ev.floor[s] for s, r in res.items()]))


def _after(n: int, starts: np.ndarray, width: int) -> np.ndarray:
    m = np.zeros(n, dtype=bool)
    for s in starts:
        m[s:s + width] = True
    return m


# ------------------------------------------------------------ evidence

def assess(ev: Evaluator, meas: Measurement, effects: tuple[Effect, ...], name: str,
           folds: tuple[np.ndarray, np.ndarray], round_: int,
           policy: DiscoveryPolicy, scanned: Scan | None = None) -> Assessment:
    fit = fit_candidate(ev, effects, name, folds, scanned=scanned)
    trial = fit.effects
    n_obs = meas.n * len(meas.signals)
    nll_before = ev.nll(ev.sim(effects))
    delta_bic = 2.0 * (fit.nll - nll_before) + 1.0 * np.log(n_obs)
    share, gains, worse = heldout_share(fit, ev.floor, meas.n, policy)
    left = sum(max(x, 0.0) for x in heldout_excess(fit, ev.floor)[1].values())
    sig_b = signature_energy(name, meas, ev, effects, policy)
    sig_a = signature_energy(name, meas, ev, trial, policy)
    a = Assessment(fit=fit, round=round_, delta_bic=float(delta_bic), heldout_share=share,
                   heldout_gain_floors=max(gains.values()), worst_worsening_floors=worse,
                   structure_left=float(left),
                   signature_before=sig_b, signature_after=sig_a)
    a.checks = {
        "improvement_vs_noise": any(g >= min_gain(s, meas.n, policy) for s, g in gains.items()),
        "heldout": (a.heldout_share >= policy.min_heldout_share
                    and a.worst_worsening_floors <= policy.max_worsening_floors and fit.heldout_nll_gain > 0),
        "bic": a.delta_bic <= policy.max_delta_bic,
        "interval_excludes_null": fit.excludes_null and beyond_zero_error(fit, meas, ev.floor, policy),
        # a candidate that removes most of the held-out structure has shown its pattern; its
        # local window may then hold what another, stacked effect leaves behind
        "signature_removed": (sig_a <= policy.signature_shrink * sig_b or sig_a <= policy.signature_noise
                              or share >= policy.dominant_share),
        "size": nameable_size(fit.name, fit.value, policy),
    }
    return a


def beyond_zero_error(fit: Fit, meas: Measurement, floor: dict[str, float], policy: DiscoveryPolicy) -> bool:
    """Whether the candidate stands ``policy.zero_sigmas`` clear of the error of a zero read off the data
    that its value is confounded with (True when there is no such zero).  That zero is a mean of
    rest readings, whose error is the signal's noise floor over their number: the floor is read off
    the whole recording, the rest readings' own spread off a few (11 of them read it 28 % low on a
    randomised draw)."""
    p = CATALOGUE[fit.name].PARAMS[0]
    rest = meas.zero_samples.get(p.zero_of, 0)
    if not rest or p.zero_of not in floor:
        return True
    return abs(fit.value - p.absent) > policy.zero_sigmas * float(np.sqrt(floor[p.zero_of] / rest))


def adoption_rank(a: Assessment) -> float:
    """The order a round (plain or thorough) adopts from among the candidates that pass: by held-out
    likelihood gain, largest first."""
    return -a.fit.heldout_nll_gain


def nameable_size(name: str, value: float, policy: DiscoveryPolicy) -> bool:
    """Whether ``value`` of the effect's first parameter is at least ``policy.min_size_share`` of its typical size."""
    p = CATALOGUE[name].PARAMS[0]
    return abs(value - p.absent) >= policy.min_size_share * abs(p.typical - p.absent)


def min_gain(signal: str, n: int, policy: DiscoveryPolicy) -> float:
    """MSE, in noise variances, that ``signal`` must gain (or keep, to be structure) over ``n`` samples:
    the current's by chi-square over the samples (its floor is white noise), the angle's a fixed share."""
    if signal == "current":
        return min(policy.current_min_gain, policy.current_min_gain_chi2 / max(n, 1))
    return policy.theta_min_gain


def floor_error(signal: str, n: int, policy: DiscoveryPolicy) -> float:
    """Excess MSE, in noise variances, that the current's floor estimate may account for (``floor_sigmas``)."""
    if signal != "current":
        return 0.0
    return policy.floor_sigmas * float(np.sqrt(FLOOR_RELATIVE_VARIANCE / max(n, 1)))


def heldout_excess(fit: Fit, floor: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    """Held-out MSE above the noise floor per signal, in noise variances: before the candidate, after it."""
    return ({s: fit.heldout_mse_before[s] / fl - 1.0 for s, fl in floor.items()},
            {s: fit.heldout_mse_after[s] / fl - 1.0 for s, fl in floor.items()})


def heldout_share(fit: Fit, floor: dict[str, float], n: int,
                  policy: DiscoveryPolicy) -> tuple[float, dict[str, float], float]:
    """(share of held-out structure removed, MSE gain per signal in noise variances, worst worsening).

    Structure is MSE above the noise floor, in noise variances, in each signal
    that has enough of it to be worth removing (``min_gain`` over the ``n`` samples); the share
    is the best over those signals (an effect may live in one signal only, e.g.
    a sensor offset in the current), 0 when there is nothing to explain.  Of a candidate that moves
    the current alone, the structure the floor's own error may hold (``floor_error``) is not asked.
    """
    ex_b, ex_a = heldout_excess(fit, floor)
    gains = {s: ex_b[s] - ex_a[s] for s in floor}
    structured = [s for s in floor if ex_b[s] >= min_gain(s, n, policy)]

    def structure(s: str) -> float:
        # a candidate that moves this signal alone (a sensor's offset) is not asked for the floor's error
        alone = all(gains[o] < min_gain(o, n, policy) for o in floor if o != s)
        return max(ex_b[s] - floor_error(s, n, policy), gains[s], 1e-12) if alone else ex_b[s]

    share = max((gains[s] / structure(s) for s in structured), default=0.0)
    return float(min(share, 1.0)), {s: float(g) for s, g in gains.items()}, float(max(-g for g in gains.values()))
