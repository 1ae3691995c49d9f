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
calibration they cannot be told from the rig's own values.  Where the base itself is off, the search's
choice was made against the wrong base, and the effect that is there may be missing from it (a backlash
read as a Coulomb friction): the catalogue is offered again with the base free, in forward steps by the
same criterion, each at a nameable size (``policy``) and followed by elimination; an effect that is a base
parameter under another name is not offered (it could only gain by leaving the base's prior).
The forward steps are offered only while the search's work and the check's together are within the
policy's ``decision_work_budget`` (counted in the search's unit); the elimination always runs, since it
can only drop names.

Where the check drops an effect, the verdict is ``unexplained`` (``stage.Discovery.verdict``); where
the base model itself is off (freeing it gains more than its parameters' charge), the answer says so
and asks for a calibration.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.calibrate.structure import base_unknowns
from pipeline.discover.measurement import Measurement
from pipeline.discover.policy import DEFAULT_POLICY, DiscoveryPolicy
from pipeline.discover.residuals import noise_floor, target_of
from pipeline.discover.criterion import beyond_zero_error, nameable
from pipeline.discover.search import what_it_changes
from pipeline.discover.candidates import Evaluator
from pipeline.estimate import FitResult, Model, Problem, Target, effect_unknowns
from pipeline.estimate.fit import Steps
from pipeline.model.effects import CATALOGUE, Effect

HINT = ("the rig's [model] is not declared and the recording does not fit Table I's base model: run "
        "`pdr calibrate` on two clean recordings of this rig (with --adopt), then discover again")
MAX_NFEV = 60        # per fit: the base free from Table I converges in a few dozen evaluations
# The check compares models by chi-square differences against a charge of ln n (~7) per parameter, on
# chi-squares the inflation brings to a few hundred to a few thousand: a fit stops when a step gains
# under 1e-4 of its cost, well inside one charge.  At scipy's 1e-8 a fit zig-zagged along the base's
# ridge for another 40 steps to gain 0.04 (used calibration seeds 11-16, 144 recordings: the same
# answers on all, the check's CPU x0.56)
CHECK_STEPS = Steps(ftol=1e-4)


@dataclass(frozen=True)
class BaseFreeCheck:
    kept: tuple[Effect, ...]              # the effects whose evidence holds with the base free, refitted
    dropped: tuple[str, ...]
    added: tuple[str, ...]                # not found by the search: named with the base free (where it is off)
    base_off: bool                        # freeing the base gains more than its parameters' charge
    chi2: dict[str, float]                # criterion values (inflation-weighted chi-square) of the models compared
    intervals: dict[str, tuple[float, float]]   # each kept effect's first parameter, ~95 % (covariance of its fit)
    work: int = 0                         # the search's work and the check's (``candidates.replay_cost``)
    stopped_for_time: bool = False        # the budget ended the forward steps while the base was still off

    @property
    def hint(self) -> str | None:
        return HINT if self.base_off or self.dropped else None

    def to_json(self) -> dict:
        return {"kept": [e.name for e in self.kept], "dropped": list(self.dropped), "added": list(self.added),
                "base_off": self.base_off,
                "criterion": "BIC on the inflation-weighted chi-square, every free parameter charged",
                "chi2": self.chi2, "work": self.work, "stopped_for_time": self.stopped_for_time}


class _Tally:
    """The check's work in the search's unit: its replays and start estimates counted by an ``Evaluator``
    (``work``) that starts from the search's, so one budget bounds the search and the check together."""

    def __init__(self, meas: Measurement, spent: int) -> None:
        self.counter = Evaluator(meas, floor={}, spent=spent)
        self.target = target_of(meas, on_replay=self.counter.count_replay)

    @property
    def work(self) -> int:
        return self.counter.work


def _fit(meas: Measurement, target: Target, effects: tuple[Effect, ...], base_free: bool, factors=None,
         base_start: dict[str, float] | None = None) -> FitResult:
    """``base_start``: where the free base parameters start (their prior stays Table I's)."""
    unknowns = [u for e in effects for u in effect_unknowns(e)]
    if base_free:
        base = base_unknowns(meas.config.model, declared=False)
        start = base_start or {}
        unknowns = [replace(u, start=start.get(u.name, u.start)) for u in base] + unknowns
    problem = Problem((target,), Model(base=meas.config.model, effects=effects), tuple(unknowns))
    return problem.fit(max_nfev=MAX_NFEV, factors=factors, steps=CHECK_STEPS)


def _effects_at(res: FitResult, effects: tuple[Effect, ...]) -> tuple[Effect, ...]:
    values = res.values
    return tuple(type(e)(**{p: values.get(f"{e.name}.{p}", v) for p, v in e.parameters.items()}) for e in effects)


def check_with_base_free(meas: Measurement, effects: tuple[Effect, ...], names: tuple[str, ...] | None = None,
                         policy: DiscoveryPolicy = DEFAULT_POLICY, spent: int = 0) -> BaseFreeCheck:
    """Stepwise selection with the base free, from the search's ``effects``: backward elimination, then,
    where the base itself is off, forward over the catalogue (``names``) too, each step followed by
    elimination.  The search chose on Table I's base; where that base is off, what it chose stands in
    for it as often as not, and the effect that is there may not have been found at all (a backlash
    beside a stiffer spring read as a Coulomb friction), so the catalogue is offered again.

    The inflation of each signal is measured once, on the search's fullest model with the base free,
    and every model compared is scored with it, so their chi-squares are one likelihood."""
    names = tuple(CATALOGUE) if names is None else names
    tally = _Tally(meas, spent)
    full = _fit(meas, tally.target, effects, base_free=True)
    factors = full.factors
    penalty = np.log(max(full.n_data, 2))
    chi2 = {_label("base free", effects): full.data_chi2}

    def fit(trial: tuple[Effect, ...], near: FitResult, base_free: bool = True) -> FitResult:
        # from the base of the model ``near`` (a few evaluations, not a climb from Table I each time)
        res = _fit(meas, tally.target, trial, base_free=base_free, factors=factors, base_start=near.values)
        chi2[_label("base free" if base_free else "Table I", trial)] = res.data_chi2
        return res

    def named_here(effect: Effect) -> bool:
        # the search's bar for a name, at the value the effect takes with the base free
        return nameable(effect, policy) and beyond_zero_error(effect, meas, floor, policy)

    def eliminate(kept: tuple[Effect, ...], current: FitResult) -> tuple[tuple[Effect, ...], FitResult]:
        while kept:
            # what keeping each buys, less its charge (all its parameters): the cheapest goes first, and
            # before any, one that shrank below a nameable size once the base was free
            trials = [(fit(kept[:i] + kept[i + 1:], current), i) for i in range(len(kept))]
            small = [t for t in trials if not named_here(kept[t[1]])]
            res, i = min(small or trials,
                         key=lambda t: t[0].data_chi2 - current.data_chi2 - len(kept[t[1]].PARAMS) * penalty)
            if not small and res.data_chi2 - current.data_chi2 - len(kept[i].PARAMS) * penalty >= 0.0:
                break
            dropped.append(kept[i].name)
            kept, current = _effects_at(res, kept[:i] + kept[i + 1:]), res
        return kept, current

    def base_is_off(kept: tuple[Effect, ...], current: FitResult) -> tuple[bool, FitResult]:
        fixed = fit(kept, current, base_free=False)
        return fixed.data_chi2 - current.data_chi2 > n_base * penalty, fixed

    n_base = len(base_unknowns(meas.config.model, declared=False))
    floor = noise_floor(meas)
    dropped: list[str] = []
    kept, current = eliminate(_effects_at(full, effects), full)
    base_off, fixed = base_is_off(kept, current)
    added: list[str] = []
    stopped = False
    while base_off and len(kept) < policy.max_effects:
        if tally.work > policy.decision_work_budget:
            stopped = True
            break
        others = [n for n in names if n not in {e.name for e in kept} and not a_base_parameter(meas, n)]
        trials = [(fit(trial, current), trial) for trial in ((*kept, CATALOGUE[n].typical()) for n in others)]
        # as in the search: the one that gains most of those that clear their charge at a nameable size
        clearing = [(res, _effects_at(res, trial)) for res, trial in trials
                    if current.data_chi2 - res.data_chi2 > len(trial[-1].PARAMS) * penalty]
        clearing = [(res, trial) for res, trial in clearing if named_here(trial[-1])]
        if not clearing:
            break
        res, trial = min(clearing, key=lambda t: t[0].data_chi2 + len(t[1][-1].PARAMS) * penalty)
        name = trial[-1].name
        added.append(name)
        kept, current = eliminate(trial, res)
        if name not in {e.name for e in kept}:
            break                                     # added, then dropped: the steps go round
        base_off, fixed = base_is_off(kept, current)
    final = current if base_off else fixed
    intervals = {e.name: final.wald_interval(f"{e.name}.{e.PARAMS[0].name}") for e in kept}
    names_kept = {e.name for e in kept}
    return BaseFreeCheck(kept=_effects_at(final, kept), dropped=tuple(n for n in dict.fromkeys(dropped)
                                                                       if n not in names_kept),
                         added=tuple(n for n in added if n in names_kept), base_off=bool(base_off), chi2=chi2,
                         intervals=intervals, work=tally.work, stopped_for_time=stopped)


def a_base_parameter(meas: Measurement, name: str) -> bool:
    """Whether the effect changes nothing in the plant but its base parameters (viscous friction is b,
    a rack's inertia J, the springs' scale K): with the base free it is the base under another name,
    and all it could gain is an escape from the base's prior."""
    return what_it_changes(meas, name) == ["params"]


def _label(base: str, effects: tuple[Effect, ...]) -> str:
    return f"{base} + " + ("+".join(e.name for e in effects) or "nothing")


def base_free_text(check: dict) -> str:
    """One line on what the base-free check kept, dropped and added (``base_free.BaseFreeCheck.to_json``)."""
    parts = [f"{', '.join(check[key])} {what}" for key, what in
             (("kept", "held"), ("dropped", "stood in for the base, not named"),
              ("added", "found only with the base free")) if check.get(key)]
    return ("the rig's [model] is not declared, so each effect was tested with the base free: "
            + ("; ".join(parts) if parts else "none held") + ("; the base itself is off" if check.get("base_off") else "")
            + ("; the work budget ended the search with the base free" if check.get("stopped_for_time") else ""))
