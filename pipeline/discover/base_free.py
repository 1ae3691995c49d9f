"""Effects that hold once the base model may move: discovery on a rig whose ``[model]`` is not declared.

A rig that is not the paper's has its own motor, gearbox, springs and friction.  Fitted against
Table I, its recording shows structure that catalogued effects can absorb -- softer springs, more
viscous friction, a backlash, a delay -- although the rig has none of them: they stand in for the
base model's error, and the search may even call the recording explained by them.  So where the
rig's TOML declares no ``[model]``, every effect the search found is tested again with the base
parameters free within their prior (Table I with ``TABLE_I_TOLERANCE``, under calibration's
convention), by the estimation core: one likelihood, each effect charged for all its parameters
(BIC), each dropped whose removal costs less than its charge.  Effects that are base parameters
under another name (viscous friction, spring stiffness, rack inertia) rarely survive this: without a
calibration they cannot be told from the rig's own values.  Where the check drops an effect, the
verdict is ``unexplained`` (``stage.Discovery.verdict``); where the base model itself is off
(freeing it gains more than its parameters' charge), the answer says so and asks for a calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.calibrate.structure import base_unknowns
from pipeline.discover.measurement import Measurement
from pipeline.discover.residuals import target_of
from pipeline.estimate import FitResult, Model, Problem, effect_unknowns
from pipeline.model.effects import Effect

HINT = ("the rig's [model] is not declared and the recording does not fit Table I's base model: run "
        "`pdr calibrate` on two clean recordings of this rig (with --adopt), then discover again")
MAX_NFEV = 60        # per fit: the base free from Table I converges in a few dozen evaluations


@dataclass(frozen=True)
class BaseFreeCheck:
    kept: tuple[Effect, ...]              # the effects whose evidence holds with the base free, refitted
    dropped: tuple[str, ...]
    base_off: bool                        # freeing the base gains more than its parameters' charge
    chi2: dict[str, float]                # criterion values (inflation-weighted chi-square) of the models compared
    intervals: dict[str, tuple[float, float]]   # each kept effect's first parameter, ~95 % (covariance of its fit)

    @property
    def hint(self) -> str | None:
        return HINT if self.base_off or self.dropped else None

    def to_json(self) -> dict:
        return {"kept": [e.name for e in self.kept], "dropped": list(self.dropped), "base_off": self.base_off,
                "criterion": "BIC on the inflation-weighted chi-square, every free parameter charged",
                "chi2": self.chi2}


def _fit(meas: Measurement, effects: tuple[Effect, ...], base_free: bool, factors=None) -> FitResult:
    unknowns = [u for e in effects for u in effect_unknowns(e)]
    if base_free:
        unknowns = base_unknowns(meas.config.model, declared=False) + unknowns
    problem = Problem((target_of(meas),), Model(base=meas.config.model, effects=effects), tuple(unknowns))
    return problem.fit(max_nfev=MAX_NFEV, factors=factors)


def _effects_at(res: FitResult, effects: tuple[Effect, ...]) -> tuple[Effect, ...]:
    values = res.values
    return tuple(type(e)(**{p: values.get(f"{e.name}.{p}", v) for p, v in e.parameters.items()}) for e in effects)


def check_with_base_free(meas: Measurement, effects: tuple[Effect, ...]) -> BaseFreeCheck:
    """Backward elimination from ``effects`` with the base free; then whether the base itself is off.

    The inflation of each signal is measured once, on the fullest model (base free and every effect),
    and every model compared is scored with it, so their chi-squares are one likelihood."""
    full = _fit(meas, effects, base_free=True)
    factors = full.factors
    penalty = np.log(max(full.n_data, 2))
    chi2 = {"base free + " + ("+".join(e.name for e in effects) or "nothing"): full.data_chi2}
    kept, current = tuple(effects), full
    dropped: list[str] = []
    while kept:
        trials = []
        for i, e in enumerate(kept):
            rest = kept[:i] + kept[i + 1:]
            res = _fit(meas, rest, base_free=True, factors=factors)
            chi2["base free + " + ("+".join(x.name for x in rest) or "nothing")] = res.data_chi2
            # what keeping e buys, less its charge (all its parameters)
            trials.append((res.data_chi2 - current.data_chi2 - len(e.PARAMS) * penalty, i, res))
        gain, i, res = min(trials, key=lambda x: x[0])
        if gain >= 0.0:
            break
        dropped.append(kept[i].name)
        kept, current = kept[:i] + kept[i + 1:], res
    fixed = _fit(meas, _effects_at(current, kept), base_free=False, factors=factors)
    n_base = len(base_unknowns(meas.config.model, declared=False))
    chi2["Table I + " + ("+".join(e.name for e in kept) or "nothing")] = fixed.data_chi2
    base_off = fixed.data_chi2 - current.data_chi2 > n_base * penalty
    final = current if base_off else fixed
    intervals = {e.name: final.wald_interval(f"{e.name}.{e.PARAMS[0].name}") for e in kept}
    return BaseFreeCheck(kept=_effects_at(final, kept), dropped=tuple(dropped), base_off=bool(base_off), chi2=chi2,
                         intervals=intervals)
