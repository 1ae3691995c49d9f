"""Forward selection over the catalogue by one criterion: held-out likelihood.

The criterion, the checks and what every model compared is judged by are ``criterion``'s.

The search.  Round by round every remaining candidate is tried on top of the model found so far (all
parameters of all effects refitted jointly); of those that clear every check, the one that removes the
most held-out likelihood is adopted.  A round is not run where even an effect that left only noise could
not clear a charge (``room``).  Where the rounds leave more than the clock's tick leaves
(``policy.starts_above`` noise variances), round one's other candidates are further starts: the rounds
run from each, and the model with the best criterion (held-out likelihood less charges, one set of
autocorrelation times for all) is kept, because the first pick among near-twins (a softer spring and a
heavier rack both slow the oscillation; viscous friction for a delay and a driver drop together) is made
before the partners are known; a run that comes to a model another run passed through ends there.  Then
each effect the others made redundant (refitted with them, it falls below a nameable size, or its gain no
longer clears its charge) is dropped, and where one was, the rounds run again from what is left; where
none was and the model still leaves more than the clock's tick, each member in turn is exchanged for the
best of a round run in its place (stepwise selection with exchange, each step kept only where the
criterion improves): the room a stand-in held goes to what it stood in for.  After a board reset the
counter's zero, a nuisance held from the base model's fit through the rounds, is first estimated again under
the model found (``start_refit.hold_offset_of``), so the elimination and the verdict judge every model at one
offset.

The verdict.  ``none`` when nothing is adopted and the recording is at its noise floor;
``explained`` when effects are adopted and what is left is within ``policy.structure_floors``
noise variances; ``unexplained`` otherwise.  A sensor's zero is not named beside structure in the
other signals: a plant the model gets wrong moves that sensor's mean too.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from pipeline.discover.candidates import Evaluator, Fit, fit_candidate, folds_by_cycle, scan
from pipeline.discover.criterion import (beyond_zero_error, charge, criterion, evidence, heldout_nll, nameable,
                                        residual_taus, room, structure_share)
from pipeline.discover.joint import effect_intervals, joint_fit, sensitivity
from pipeline.discover.inferred_switches import ambiguous, settled, timing
from pipeline.discover.measurement import Measurement
from pipeline.discover.policy import DEFAULT_POLICY, DiscoveryPolicy
from pipeline.discover.residuals import noise_floor
from pipeline.discover.start_refit import held_start_sensitivity, hold_offset_of, refine_start
from pipeline.model.effects import CATALOGUE, Effect


@dataclass
class Candidate:
    """One candidate effect tried in one round: its fit and its held-out evidence."""

    fit: Fit
    round: int
    evidence: float          # held-out nll gain, in independent samples (the criterion)
    charge: float            # what its parameters cost: ``evidence_per_parameter`` each
    share: float             # the largest share of a signal's held-out structure it removes
    accepted: bool = False   # adopted in this round
    min_share: float = DEFAULT_POLICY.min_heldout_share
    nameable: bool = True    # of a nameable size, clear of a zero's error

    @property
    def name(self) -> str:
        return self.fit.name

    @property
    def score(self) -> float:
        return self.evidence

    @property
    def checks(self) -> dict[str, bool]:
        return {"evidence": bool(self.evidence > self.charge), "share": bool(self.share >= self.min_share),
                "size": bool(self.nameable)}

    @property
    def clears(self) -> bool:
        return all(self.checks.values())

    def to_json(self) -> dict:
        f = self.fit
        return {"name": f.name, "score": round(self.evidence, 3), "round": self.round,
                "parameters": f.effect.parameters, "units": dict(CATALOGUE[f.name].UNITS),
                "interval": {f.parameter: list(f.interval)}, "fold_estimates": {f.parameter: list(f.fold_values)},
                "heldout_evidence": self.evidence, "charge": self.charge, "structure_share": self.share,
                "heldout_nll_gain": f.heldout_nll_gain,
                "heldout_mse_before": f.heldout_mse_before, "heldout_mse_after": f.heldout_mse_after,
                "checks": self.checks,
                "accepted": self.accepted}


@dataclass
class Screened:
    """A candidate not fitted this round: its scan gained nothing, or ranked below ``later_full_fits``."""

    name: str
    round: int
    value: float            # best scan point
    scan_gain: float        # nll decrease there, all samples

    accepted = False
    clears = False
    score = 0.0

    def to_json(self) -> dict:
        p = CATALOGUE[self.name].PARAMS[0].name
        return {"name": self.name, "score": 0.0, "round": self.round, "parameters": {p: self.value},
                "units": dict(CATALOGUE[self.name].UNITS), "scan_nll_gain": self.scan_gain,
                "screened_out": True, "accepted": False}


@dataclass
class Selection:
    effects: tuple[Effect, ...]
    verdict: str
    rounds: list[list[Candidate | Screened]]
    floor: dict[str, float]
    excess_before: dict[str, float]       # replay MSE above noise, in noise variances, base model
    excess_after: dict[str, float]        # same for the final model
    near_tie: dict | None
    simulations: int
    failures: list[str]                   # parameter sets the simulator refused (scored as infinitely bad)
    command_before: np.ndarray            # the command replayed for the base model ...
    command_after: np.ndarray             # ... and the final one (differ only in an inferred motor start)
    stopped_for_time: bool                # the work budget ended the search
    work: int                             # what the search cost (``Evaluator.work``)
    pruned: list[str]                     # adopted, then dropped once later effects made them redundant
    intervals: list[tuple[float, float]]  # ~95 % interval of each final effect's parameter, all refitted jointly
    meas: Measurement                     # the measurement fitted (inferred switches settled)
    policy: DiscoveryPolicy               # the thresholds the search used
    refit_samples: int = 0                # samples the effects were refitted on after the search, if more


# ------------------------------------------------------------------ the search

def what_it_changes(meas: Measurement, name: str) -> list[str]:
    """The fields of the recording's plant (``PlantSpec``) the effect moves, at its typical size."""
    base = meas.spec()
    spec = meas.spec((CATALOGUE[name].at(CATALOGUE[name].PARAMS[0].typical),))
    return [f.name for f in fields(base) if getattr(base, f.name) != getattr(spec, f.name)]


def candidate_names(meas: Measurement, names: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """The catalogue (or ``names``) less what the recording cannot tell: after a board reset, an effect that
    changes nothing in the plant but its constant torque only moves where the springs rest in the
    counter's unknown zero."""
    names = tuple(CATALOGUE) if names is None else names
    return names if meas.angle_reference_known else tuple(n for n in names if what_it_changes(meas, n) != ["torque"])


def excess(ev: Evaluator, effects: tuple[Effect, ...]) -> dict[str, float]:
    return {s: m / ev.floor[s] - 1.0 for s, m in ev.mse(ev.sim(effects)).items()}


@dataclass
class _Run:
    effects: tuple[Effect, ...]
    rounds: list[list[Candidate]]


def _round(ev: Evaluator, effects: tuple[Effect, ...], remaining: list[str], folds, round_: int,
           policy: DiscoveryPolicy) -> tuple[list[Candidate], list[Screened]]:
    """Every remaining candidate scanned on top of ``effects``; in round one all are fitted and
    cross-validated, later the ``later_full_fits`` the scan ranks first (a round's cost bound).
    Each candidate's evidence is counted with the autocorrelation of the residual it leaves (as an
    F-test takes the dispersion from the larger model)."""
    base_sens = sensitivity(ev, effects) if effects else None
    nll_now = ev.nll(ev.sim(effects))
    scans = {n: scan(ev, effects, n, base_sens) for n in remaining}
    order = sorted(remaining, key=lambda n: float(np.min(scans[n].nll)))
    k = len(order) if round_ == 1 else policy.later_full_fits
    out: list[Candidate] = []
    screened = []
    for i, n in enumerate(order):
        gain = nll_now - float(np.min(scans[n].nll))
        if i >= k or gain <= 0 or (out and ev.work > policy.work_budget):
            screened.append(Screened(n, round_, float(scans[n].grid[np.argmin(scans[n].nll)]), gain))
            continue
        fit = fit_candidate(ev, effects, n, folds, scans[n])
        out.append(Candidate(fit=fit, round=round_, evidence=evidence(fit, residual_taus(ev, fit.effects), ev.meas.n),
                             charge=charge(n, policy), share=structure_share(fit, ev.floor, ev.meas.n, policy),
                             min_share=policy.min_heldout_share,
                             nameable=nameable(fit.effect, policy) and beyond_zero_error(fit.effect, ev.meas, ev.floor, policy)))
    # ranked by one likelihood (the held-out nll each removes, the same for every candidate of the round)
    out.sort(key=lambda c: -c.fit.heldout_nll_gain)
    return out, screened


def _forward(ev: Evaluator, names: tuple[str, ...], folds, policy: DiscoveryPolicy,
             start: Candidate | None, first_round: list[Candidate], effects: tuple[Effect, ...] = (),
             reached: set[frozenset[str]] | None = None) -> _Run | None:
    """Forward selection from ``effects``, or from ``start`` adopted out of round one's ``first_round``.
    ``reached``: the models earlier runs passed through, to which this run's are added; a run that comes
    to one of them would go on as that run did, so it ends there (None)."""
    rounds: list[list[Candidate]] = []
    if start is not None:
        effects = start.fit.effects
        rounds.append([replace(c, accepted=c is start) if isinstance(c, Candidate) else c for c in first_round])
    while reached is None or _joins(reached, effects):
        if (len(effects) >= policy.max_effects or ev.work > policy.work_budget
                or room(ev, effects) <= min(charge(n, policy) for n in names)):
            break
        remaining = [n for n in names if n not in {e.name for e in effects}]
        if not remaining:
            break
        tried, screened = _round(ev, effects, remaining, folds, len(effects) + 1, policy)
        rounds.append([*tried, *screened])
        adopt = next((c for c in tried if c.clears), None)
        if adopt is None:
            break
        adopt.accepted = True
        effects = adopt.fit.effects
    else:
        return None
    return _Run(effects=effects, rounds=rounds)


def _model_key(effects: tuple[Effect, ...]) -> frozenset[str]:
    """A model as the set of its effects' names (their values aside)."""
    return frozenset(e.name for e in effects)


def _joins(reached: set[frozenset[str]], effects: tuple[Effect, ...]) -> bool:
    """Records ``effects``' model in ``reached``; False where it was there already."""
    if _model_key(effects) in reached:
        return False
    reached.add(_model_key(effects))
    return True


def _size_share(effect: Effect) -> float:
    return max(abs(effect.parameters[p.name] - p.absent) / abs(p.typical - p.absent) for p in effect.PARAMS)


def _prune(ev: Evaluator, effects: tuple[Effect, ...], folds, policy: DiscoveryPolicy,
           taus: dict[str, float]) -> tuple[Effect, ...]:
    """Backward elimination by the same checks a candidate is adopted by: an effect the others, refitted
    with it, leave below a nameable size (or within a zero's error) is dropped, the smallest first; then
    one whose held-out gain, the others refitted without it, no longer clears its charge (the weakest first)."""
    def named(e: Effect) -> bool:
        return nameable(e, policy) and beyond_zero_error(e, ev.meas, ev.floor, policy)

    while small := [e for e in effects if not named(e)]:
        drop = min(small, key=_size_share)
        effects = joint_fit(ev, tuple(e for e in effects if e is not drop))
    while len(effects) > 1:
        full = heldout_nll(ev, effects, folds, taus)
        trials = []
        for i, e in enumerate(effects):
            rest = joint_fit(ev, effects[:i] + effects[i + 1:])
            trials.append((heldout_nll(ev, rest, folds, taus) - full - charge(e.name, policy), i, rest))
        gain, i, rest = min(trials, key=lambda t: t[0])
        if gain > 0:
            break
        effects = rest
    return effects


def _stepwise(ev: Evaluator, names: tuple[str, ...], folds, policy: DiscoveryPolicy, taus: dict[str, float],
              run: _Run, exchange: bool = True) -> tuple[tuple[Effect, ...], list[list[Candidate]]]:
    """Stepwise selection: backward elimination; where it dropped an effect, forward selection again from
    what is left; where it did not, an exchange (``_exchange``) and forward selection from that; until none
    changes the model.  A stand-in adopted early and dropped once its partners are in leaves room for the
    effect it stood in for.  A step is kept only where the criterion (held-out nll + charges, under the
    residual correlation ``taus``) improves, and no model twice."""
    key = _model_key
    effects, rounds = _prune(ev, run.effects, folds, policy, taus), list(run.rounds)
    dropped, seen = len(effects) < len(run.effects), {key(run.effects), key(effects)}
    while ev.work <= policy.work_budget:
        if not dropped:
            swap = _exchange(ev, names, folds, policy, taus, effects) if exchange else None
            if swap is None or key(swap[0]) in seen:
                break
            seen.add(key(swap[0]))
            effects = swap[0]
            rounds.append([replace(c, round=len(rounds) + 1) for c in swap[1]])
        again = _forward(ev, names, folds, policy, None, [], effects)
        grown = _prune(ev, again.effects, folds, policy, taus)
        if key(grown) in seen or (criterion(ev, grown, folds, taus, policy)
                                  >= criterion(ev, effects, folds, taus, policy)):
            dropped = False              # growing changed nothing: an exchange next, or the end
            continue
        seen.add(key(grown))
        dropped = len(grown) < len(again.effects)
        # the rounds numbered on from the run's, in the order they ran
        rounds += [[replace(c, round=len(rounds) + 1 + i) for c in rnd] for i, rnd in enumerate(again.rounds)]
        effects = grown
    return effects, rounds


def _exchange(ev: Evaluator, names: tuple[str, ...], folds, policy: DiscoveryPolicy, taus: dict[str, float],
              effects: tuple[Effect, ...]) -> tuple[tuple[Effect, ...], list[Candidate | Screened]] | None:
    """Sequential replacement (Miller's stepwise exchange), where the model leaves more than the clock's
    tick (``policy.starts_above``): each member in turn is taken out, the others refitted, and a round of
    the candidates outside the model is run in its place; the first replacement that clears every check
    and improves the criterion, each sensor zero it names readable, is returned with its round (None: none
    does).  A stand-in picked while its partners were missing (viscous friction for a driver's drop beside
    a delay) is kept by elimination, which only asks whether it still earns its charge."""
    if not effects or max(excess(ev, effects).values()) <= policy.starts_above:
        return None
    now = criterion(ev, effects, folds, taus, policy)
    outside = [n for n in names if n not in {e.name for e in effects}]
    rests = [joint_fit(ev, effects[:i] + effects[i + 1:]) for i in range(len(effects))]
    # the member the others miss least first: the likeliest stand-in, and the budget may end the exchange
    for rest in sorted(rests, key=lambda r: ev.nll(ev.sim(r))):
        if ev.work > policy.work_budget or not outside:
            break
        tried, screened = _round(ev, rest, outside, folds, len(effects), policy)
        for c in (c for c in tried if c.clears and _readable(ev, c.fit.effects, policy)):
            if criterion(ev, c.fit.effects, folds, taus, policy) < now:
                c.accepted = True
                return c.fit.effects, [*tried, *screened]
    return None


def _zero_beside_structure(effect: Effect, ex_after: dict[str, float], policy: DiscoveryPolicy) -> bool:
    signal = effect.PARAMS[0].zero_of
    return bool(signal) and any(x > policy.structure_floors for s, x in ex_after.items() if s != signal)


def _readable(ev: Evaluator, effects: tuple[Effect, ...], policy: DiscoveryPolicy) -> bool:
    """Whether every sensor zero the model names is readable (not beside structure in the other signals):
    a model that would be cut down at the verdict is no better than what is kept."""
    ex = excess(ev, effects)
    return not any(_zero_beside_structure(e, ex, policy) for e in effects)


def _polished(ev: Evaluator, effects: tuple[Effect, ...], policy: DiscoveryPolicy) -> tuple[Effect, ...]:
    """The values of an explanation, refitted under the likelihood with each signal counted in independent
    samples at the model chosen (``joint_fit(taus=...)``): the angle's misfit, smooth over ~20 samples where
    switches are known to a sample, no longer outweighs the current on a parameter the current measures
    (a sensor's offset).  Before the start is refined for the model (a start refined for one set of values
    and estimated for the others would be a step the fit cannot cross); only where the model explains the
    recording and still does after (what leaves structure is checked further, and its work is theirs)."""
    if not effects or max(excess(ev, effects).values()) > policy.structure_floors:
        return effects
    polished = joint_fit(ev, effects, taus=residual_taus(ev, effects))
    return polished if max(excess(ev, polished).values()) <= policy.structure_floors else effects


def _search(meas: Measurement, names: tuple[str, ...], policy: DiscoveryPolicy, spent: int = 0,
            resume: tuple[Effect, ...] = (), exchange: bool = True) -> Selection:
    """The rounds, further starts, elimination, exchange and verdict on one settling of the switches;
    ``spent``: the work of an earlier search on the recording (the budgets bound them together);
    ``resume``: the model that search found, searched on from (its starts were tried there)."""
    floor = noise_floor(meas)
    ev = Evaluator(meas, floor, spent)
    folds = folds_by_cycle(meas)
    reached: set[frozenset[str]] = set()
    # resumed: the rounds over the model found first (each scanned and fitted afresh: the switches moved
    # under its values), then over the catalogue
    found = _forward(ev, tuple(e.name for e in resume), folds, policy, None, []) if resume else _Run((), [])
    plain = _forward(ev, names, folds, policy, None, [], found.effects, reached=reached)
    plain.rounds[:0] = found.rounds
    runs = [plain]
    first = plain.rounds[0] if plain.rounds else []
    # other starts where the plain run leaves more than the clock does (a wrong twin first leaves its partner's
    # pattern); after a reset every trial fits a counter zero too: one run only
    if not resume and meas.angle_reference_known and max(excess(ev, plain.effects).values()) > policy.starts_above:
        # round one's others that clear every check; where none does, those that fail only the evidence (the
        # held-out likelihood of a start is judged on the model it leads to: partners can be needed together)
        others = [c for c in first if isinstance(c, Candidate) and not c.accepted
                  and (c.clears if plain.effects else c.share >= c.min_share and c.nameable
                       and c.fit.heldout_nll_gain > 0)]
        for c in others[:policy.starts - 1]:
            if ev.work > policy.total_work_budget:
                break
            if (run := _forward(ev, names, folds, policy, c, first, reached=reached)) is not None:
                runs.append(run)
        # a further start counts where each sensor zero it names is readable (below), or the best would be cut down
        runs = [plain, *(r for r in runs[1:] if _readable(ev, r.effects, policy))]
    # one likelihood for every model compared: the residual correlation the plain run leaves
    taus = residual_taus(ev, plain.effects)
    best = plain if len(runs) == 1 else min(runs, key=lambda r: criterion(ev, r.effects, folds, taus, policy))
    hold_offset_of(ev, best.effects)
    effects, rounds = _stepwise(ev, names, folds, policy, taus, best, exchange)
    adopted = {e.name for r in runs for e in r.effects} | {c.fit.name for rnd in rounds for c in rnd
                                                           if getattr(c, "accepted", False)}
    effects = _polished(ev, effects, policy)
    refine_start(ev, effects)
    ex_after = excess(ev, effects)
    if unreadable := [e for e in effects if _zero_beside_structure(e, ex_after, policy)]:
        effects = joint_fit(ev, tuple(e for e in effects if e not in unreadable))
        refine_start(ev, effects)
        ex_after = excess(ev, effects)
    structured = max(ex_after.values()) > policy.structure_floors
    verdict = "unexplained" if structured else "explained" if effects else "none"
    spans = effect_intervals(held_start_sensitivity(ev, effects), effects) if effects else []
    return Selection(effects=effects, verdict=verdict, rounds=rounds, floor=floor,
                     excess_before=excess(ev, ()), excess_after=ex_after, near_tie=_near_tie(rounds, policy),
                     simulations=ev.simulations, failures=ev.failures, command_before=ev.command_for(()),
                     command_after=ev.command_for(effects), stopped_for_time=ev.work > policy.work_budget,
                     work=ev.work, pruned=sorted(adopted - {e.name for e in effects}), intervals=spans,
                     meas=meas, policy=policy)


def _near_tie(rounds: list[list[Candidate]], policy: DiscoveryPolicy) -> dict | None:
    """The first round whose runner-up's net evidence is within ``policy.near_tie`` of the winner's."""
    for rnd in rounds:
        chosen = next((c for c in rnd if c.accepted), None)
        runner = next((c for c in rnd if c is not chosen and isinstance(c, Candidate) and c.clears), None)
        if chosen is None or runner is None:
            continue
        if chosen.evidence - runner.evidence <= policy.near_tie * chosen.charge:
            return {"round": chosen.round, "chosen": chosen.name, "runner_up": runner.name,
                    "scores": {chosen.name: chosen.evidence, runner.name: runner.evidence},
                    "runner_up_accepted": False}
    return None


def select(meas: Measurement, names: tuple[str, ...] | None = None,
           policy: DiscoveryPolicy = DEFAULT_POLICY, exchange: bool = True) -> Selection:
    """Discovery on one recording (replay fits; the closed loop is confirmed by the caller).
    ``exchange``: members may be exchanged (``_exchange``); not on a rig whose base is itself in doubt
    (no [model] declared), where what a member stands in for may be the base's own error, which the
    check with the base free decides (``base_free``) within the same work.

    Switches the data leave a sample open (inferred ones on a guard, reversals on rows lost over serial)
    are nuisances, settled with the model: by the base model first, then, while what is found leaves
    structure, by the model found, and searched on from that model, until the switches no longer move (the
    run that leaves least structure is kept).  The exchange of members, which judges models on one
    settling, comes after, within the work budget: from the model kept, on its switches, kept where it
    leaves no more structure."""
    names = candidate_names(meas, names)
    if not ambiguous(meas):
        return _search(meas, names, policy, exchange=exchange)
    best = last = _search(settled(meas, ()), names, policy, exchange=False)
    seen = {timing(best.meas)}
    while last.verdict == "unexplained" and last.effects and last.work <= policy.total_work_budget:
        again = settled(meas, last.effects)
        if timing(again) in seen:
            break
        seen.add(timing(again))
        last = _search(again, names, policy, spent=last.work, resume=last.effects, exchange=False)
        if max(last.excess_after.values()) < max(best.excess_after.values()):
            best = last
    if (not exchange or not best.effects or max(best.excess_after.values()) <= policy.starts_above
            or last.work > policy.work_budget):
        return best
    final = _search(best.meas, names, policy, spent=last.work, resume=best.effects)
    return final if max(final.excess_after.values()) <= max(best.excess_after.values()) else best
