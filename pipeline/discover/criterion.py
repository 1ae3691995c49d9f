"""What counts as evidence in discovery: one likelihood, the checks beside it, and the charge.

The criterion.  A model (the rig's base plus a set of effects) is scored by its cross-validated
likelihood: its parameters are fitted on half the cycles and it predicts the other half, both
ways (``candidates.folds_by_cycle``).  The gain of adding an effect is the held-out negative
log-likelihood it removes, per signal divided by the autocorrelation time of that signal's
residual (the clock's truncation makes the angle's error smooth: tau ~ 20 samples are worth one),
so the gain is counted in independent samples.  An effect is worth its parameters when its gain
exceeds ``policy.evidence_per_parameter`` for each of them: an effect with two parameters is
charged twice.  Held-out data already charge an effect that fits noise (it predicts worse), so
the charge only asks the evidence to be clear of chance.

Beside its charge, a candidate must remove at least ``min_heldout_share`` of some signal's held-out
structure (an effect that is there removes the pattern it makes; one that buys likelihood while the
pattern stays is absorbing the misfit of something outside the catalogue), be of a nameable size
(``min_size_share`` of its catalogue's typical size), and, a sensor's offset, stand clear of the
error of a zero read off rest readings (a nuisance with a known variance).
"""

from __future__ import annotations

import numpy as np

from pipeline.discover.candidates import Evaluator, Fit, fold_fit
from pipeline.discover.joint import sensitivity
from pipeline.discover.measurement import Measurement
from pipeline.discover.policy import DiscoveryPolicy
from pipeline.discover.residuals import residuals
from pipeline.estimate.fit import autocorrelation_time
from pipeline.model.effects import CATALOGUE, Effect


def evidence(fit: Fit, taus: dict[str, float], n: int) -> float:
    """Held-out nll removed, in independent samples: per signal n/2 log(MSE before / after) over its
    autocorrelation time (``fit``'s held-out MSEs are the two folds' together)."""
    total = 0.0
    for s, before in fit.heldout_mse_before.items():
        after = fit.heldout_mse_after.get(s, np.inf)
        if not (np.isfinite(after) and after > 0 and before > 0):
            return -np.inf
        total += 0.5 * n * np.log(before / after) / taus[s]
    return float(total)


# the noise floor's estimate has relative variance ~3/n (``estimate.noise``: robust differences): a measured fact
FLOOR_RELATIVE_VARIANCE = 3.0


def structure_share(fit: Fit, floor: dict[str, float], n: int, policy: DiscoveryPolicy) -> float:
    """The largest share of one signal's held-out structure (MSE above its noise) the candidate removes:
    an effect that is there removes the pattern it makes; one that buys likelihood while most of the
    pattern stays is absorbing the misfit of something else.  A sensor's zero moves its signal alone, so
    it is not asked for the structure the floor's own error may hold (``floor_sigmas`` of it)."""
    own = CATALOGUE[fit.name].PARAMS[0].zero_of
    shares = []
    for s, b in fit.heldout_mse_before.items():
        structure, gain = b / floor[s] - 1.0, (b - fit.heldout_mse_after.get(s, np.inf)) / floor[s]
        if s == own:
            structure = max(structure - policy.floor_sigmas * np.sqrt(FLOOR_RELATIVE_VARIANCE / n), gain)
        if structure > 0:
            shares.append(gain / structure)
    return float(max(shares, default=0.0))


def beyond_zero_error(effect: Effect, meas: Measurement, floor: dict[str, float], policy: DiscoveryPolicy) -> bool:
    """Whether a sensor's offset stands ``zero_sigmas`` clear of the error of the zero ingest read off rest
    readings (a nuisance: their mean, with the noise floor over their number as its variance)."""
    p = effect.PARAMS[0]
    rest = meas.zero_samples.get(p.zero_of, 0)
    if not rest or p.zero_of not in floor:
        return True
    return abs(effect.parameters[p.name] - p.absent) > policy.zero_sigmas * float(np.sqrt(floor[p.zero_of] / rest))


def residual_taus(ev: Evaluator, effects: tuple[Effect, ...]) -> dict[str, float]:
    return {s: autocorrelation_time(r) for s, r in residuals(ev.meas, ev.sim(effects)).items()}


def room(ev: Evaluator, effects: tuple[Effect, ...]) -> float:
    """The most evidence any further effect could show: the held-out nll of bringing every signal's
    residual down to its noise floor, counted as the residual's own correlation counts it.  Where even
    that cannot clear a charge, no round is run."""
    res = residuals(ev.meas, ev.sim(effects))
    return float(sum(0.5 * len(r) * np.log(max(float(np.mean(r * r)) / ev.floor[s], 1.0)) / autocorrelation_time(r)
                     for s, r in res.items()))


def charge(name: str, policy: DiscoveryPolicy) -> float:
    return policy.evidence_per_parameter * len(CATALOGUE[name].PARAMS)


def heldout_nll(ev: Evaluator, effects: tuple[Effect, ...], folds, taus: dict[str, float]) -> float:
    """The model's held-out nll (in independent samples): refitted on each fold's training half by one
    joint Gauss-Newton step from its fit on all samples, scored on the other half."""
    total = 0.0
    sens = sensitivity(ev, effects) if effects else None
    for train in folds:
        trial = effects if sens is None else fold_fit(ev, effects, sens, train)
        res = residuals(ev.meas, ev.sim(trial))
        for s, r in res.items():
            x = r[~train]
            total += 0.5 * len(x) * np.log(float(np.mean(x * x)) + 1e-3 * ev.floor[s]) / taus[s]
    return float(total) if np.isfinite(total) else np.inf


def nameable(effect: Effect, policy: DiscoveryPolicy) -> bool:
    """Whether some parameter of the effect is at least ``min_size_share`` of its typical size away from
    absent: a catalogued effect that absorbs a small misfit of another kind (a hot winding read as
    springs 1-2 % stiffer) takes a small value, so smaller is not named."""
    return any(abs(effect.parameters[p.name] - p.absent) >= policy.min_size_share * abs(p.typical - p.absent)
               for p in effect.PARAMS)


def criterion(ev: Evaluator, effects: tuple[Effect, ...], folds, taus: dict[str, float],
               policy: DiscoveryPolicy) -> float:
    """What every model compared is judged by: its held-out nll (in independent samples under ``taus``)
    plus the charges of its effects' parameters.  Lower is better."""
    return heldout_nll(ev, effects, folds, taus) + sum(charge(e.name, policy) for e in effects)
