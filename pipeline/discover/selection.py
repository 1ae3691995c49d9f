"""Select effects on evidence, not on the least-bad MSE.

A candidate is added only when all of these hold (issue 6, step 3):

Every threshold is a field of a ``policy.DiscoveryPolicy`` (``select(meas, policy=...)``).

1. noise:     on held-out cycles it removes at least ``min_gain`` noise variances of mean
              squared error from some signal (in the current: a many-sigma gain over the recording);
2. held out:  fitted on half the cycles, it removes at least ``min_heldout_share``
              of the structure (MSE above the noise floor) on the other half,
              without making any signal worse by more than ``max_worsening_floors``;
3. BIC:       2*delta(nll) + k*ln(n) <= ``max_delta_bic`` on all samples;
4. interval:  its ~95 % interval excludes the value at which it is absent (a sensor's zero read
              off the data: and stands three of that zero's standard errors clear of it);
5. signature: the residual pattern that points at it shrinks by half (or to the noise,
              or the candidate removes ``dominant_share`` of all the structure);
6. size:      its fitted parameter is at least ``min_size_share`` of the way from "absent" to
              the catalogue's typical (clearly visible) value: a catalogued effect that absorbs
              a small misfit of another kind takes a small value (a hot winding read as springs
              1-2 % stiffer, a start transient as a 1e-5 N m torque), so smaller is not named.

The best passing candidate (largest held-out likelihood gain) is added, all
added parameters are refitted jointly, and the round repeats (stacked effects,
at most ``max_effects``, while some signal keeps structure a candidate could remove).
Then each adopted effect is tried against the near-twins that also passed in its round,
with the later effects beside them (``swap_twins``), and an effect the others made
redundant is dropped (``prune``).  The verdict: ``none`` when nothing was added and the
residual is at the noise floor; ``explained`` when effects were added and what
is left is within ``structure_floors`` of it; ``unexplained`` when structure
remains that no candidate removes (effects that passed every rule on the way
are still listed: a hidden viscous friction next to an uncatalogued torque is
named, the torque is not; but not a sensor's zero, which only a model that gets
the other signals right can tell from a plant error).  A near tie between the two best candidates is
reported with both scores.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from pipeline.discover.candidates import Evaluator, folds_by_cycle, prune, scan
from pipeline.discover.evidence import Assessment, Screened, adoption_rank, assess, min_gain, nameable_size
from pipeline.discover.joint import effect_intervals, joint_fit, sensitivity
from pipeline.discover.measurement import Measurement, ambiguous_switches, settle_switches
from pipeline.discover.policy import DEFAULT_POLICY, DiscoveryPolicy
from pipeline.discover.residuals import noise_floor
from pipeline.discover.start_refit import held_start_sensitivity, refine_start
from pipeline.discover.thorough import pair_restart, structure_after_start, thorough_round
from pipeline.model.effects import CATALOGUE, Effect

@dataclass
class Selection:
    effects: tuple[Effect, ...]
    verdict: str
    rounds: list[list[Assessment | Screened]]
    floor: dict[str, float]
    excess_before: dict[str, float]       # replay MSE above noise, in noise variances, base model
    excess_after: dict[str, float]        # same for the final model
    near_tie: dict | None
    simulations: int
    failures: list[str]                   # parameter sets the simulator refused (scored as infinitely bad)
    command_before: np.ndarray            # the command replayed for the base model ...
    command_after: np.ndarray             # ... and the final one (differ only in an inferred motor start)
    stopped_for_time: bool                # the budget ended the search (work_budget, total_work_budget)
    work: int                             # what the rounds cost, all runs on the recording (Evaluator.work)
    pruned: list[str]                     # accepted in a round, dropped once later effects made them redundant
    intervals: list[tuple[float, float]]  # ~95 % interval of each final effect's parameter, all refitted jointly
    meas: Measurement                     # the measurement fitted (inferred switches settled)
    policy: DiscoveryPolicy               # the thresholds the search used
    refit_samples: int = 0                # samples the effects were refitted on after the search, if more (``longer``)


def only_a_constant_torque(meas: Measurement, name: str) -> bool:
    """Whether the effect changes nothing in the plant but its constant external torque.  Such an effect
    only moves where the springs rest, which after a board reset is the counter's unknown zero
    (``Measurement.angle_reference_known``): it cannot be told from that nuisance, so it is not a candidate."""
    base = meas.spec()
    spec = meas.spec((CATALOGUE[name].at(CATALOGUE[name].PARAMS[0].typical),))
    return [f.name for f in fields(base) if getattr(base, f.name) != getattr(spec, f.name)] == ["torque"]


def wide_searches(meas: Measurement) -> bool:
    """Whether the searches beyond the rounds (the thorough round, the pair restart, the rounds from
    round one's two best) may run: only where the angle's zero is known.  After a board reset the start and the
    counter's zero are fitted per model, so each of their many trial models costs several times what
    ``Evaluator.work`` counts (the budget would not bound them), and the structure left there is the
    reset's nuisances (``start_refit``, ``measurement``) more often than a missing effect."""
    return meas.angle_reference_known


def excess(ev: Evaluator, effects: tuple[Effect, ...]) -> dict[str, float]:
    return {s: m / ev.floor[s] - 1.0 for s, m in ev.mse(ev.sim(effects)).items()}


def swap_twins(ev: Evaluator, effects: tuple[Effect, ...], rounds: list[list[Assessment | Screened]],
               policy: DiscoveryPolicy, budget: float = float("inf")) -> tuple[Effect, ...]:
    """Each adopted effect against the candidates that also passed every check in its round or an
    earlier one (a later round assesses only the few its scan ranks first), with the effects adopted
    later now beside them: a round picks among near-twins (a softer spring and a
    heavier rack both slow the oscillation) before the later effects are known, and the choice is
    right only once they are.  A twin replaces the effect when, all refitted jointly, it fits every
    sample better by ``twin_swap_share`` of ``max_delta_bic`` (equal parameter counts: the likelihoods compare).  Each
    trial (a joint fit, ~0.3 M of work) starts only while ``ev.work`` is within ``budget``."""
    nll = ev.nll(ev.sim(effects))
    for r, rnd in enumerate(rounds):
        adopted = next((a.fit.name for a in rnd if a.accepted and a.fit.name in {e.name for e in effects}), None)
        if adopted is None:
            continue
        passed = {a.fit.name: a for earlier in rounds[:r + 1] for a in earlier if a.accepted}
        for twin in (a for a in passed.values() if a.fit.name not in {e.name for e in effects}):
            if ev.work > budget:
                return effects
            i = next(k for k, e in enumerate(effects) if e.name == adopted)
            trial = joint_fit(ev, (*effects[:i], twin.fit.effect, *effects[i + 1:]))
            trial_nll = ev.nll(ev.sim(trial))
            if trial_nll < nll + policy.twin_swap_share * policy.max_delta_bic:
                effects, nll, adopted = trial, trial_nll, twin.fit.name
                for _ in range(policy.twin_settles):   # the partners had settled around the old twin: let them move on
                    effects, before = joint_fit(ev, effects), nll
                    nll = ev.nll(ev.sim(effects))
                    if nll > before - policy.twin_settle_nll:
                        break
    return effects


def worth_another_round(left: dict[str, float], n: int, policy: DiscoveryPolicy) -> bool:
    """Whether any signal keeps structure (MSE above its noise, in noise variances, over ``n`` samples)
    that a candidate would have to remove to be named (``evidence.min_gain``).  A sensor offset of half a
    noise sigma next to another effect is a quarter noise variance in the current, many sigmas over
    hundreds of samples; one noise variance left in the angle is structure too.  A near-zero effect that
    would absorb a count of drift is refused by its size (``min_size_share``), not by this floor."""
    return any(v >= min_gain(s, n, policy) for s, v in left.items())


def select(meas: Measurement, names: tuple[str, ...] | None = None,
           policy: DiscoveryPolicy = DEFAULT_POLICY) -> Selection:
    """The discovery loop on one recording (replay fits; closed loop is confirmed by the caller).

    Inferred switches a sample apart (``ambiguous_switches``) are settled by the rig's model first.
    When that leaves structure no candidate removes and effects were found, they are settled again by
    the model with those effects, and, if any switch moves, the rounds go on from those effects
    refitted on the new switches: a heavier rack or a backlash shifts where the angle crosses a guard,
    so the base model can time a switch a sample off, and that one sample is structure that hides the
    next effect.  The run that leaves less structure is kept.

    Cheapest first, all within one work budget (``total_work_budget``): plain rounds; when they leave
    structure, plain rounds from round one's two best together (``_from_round_ones_two_best``); when the better of
    those still leaves some, the wide searches (a thorough round when a round adopts nothing, a pair
    restart: ``thorough``) from its effects, on the switches as finally settled."""
    names = tuple(CATALOGUE) if names is None else names
    if not meas.angle_reference_known:
        names = tuple(n for n in names if not only_a_constant_torque(meas, n))
    sel = _from_round_ones_two_best(_settled_and_selected(meas, names, policy), names)
    if (sel.verdict != "unexplained" or not wide_searches(sel.meas)
            or sel.work > policy.total_work_budget - policy.wide_search_work):
        return sel
    # the wide searches last: from the effects of the run that left less structure
    return _less_structure(_forward(sel.meas, names, policy, sel.effects, sel.rounds[:len(sel.effects)],
                                    spent=sel.work, wide=True), sel)


def _settled_and_selected(meas: Measurement, names: tuple[str, ...], policy: DiscoveryPolicy) -> Selection:
    if not ambiguous_switches(meas):
        return _forward(meas, names, policy)
    first = _forward(_settled(meas, ()), names, policy)
    if first.verdict != "unexplained" or not first.effects:
        return first
    again = _settled(meas, first.effects)
    if np.array_equal(again.dir, first.meas.dir) or first.work > policy.total_work_budget - policy.later_run_work:
        return first
    second = _forward(again, names, policy, first.effects, first.rounds, spent=first.work)
    return _less_structure(second, first)


def _less_structure(a: Selection, b: Selection) -> Selection:
    """The run that leaves less structure, with the work of both."""
    kept = a if max(a.excess_after.values()) < max(b.excess_after.values()) else b
    return replace(kept, work=max(a.work, b.work))


def _from_round_ones_two_best(sel: Selection, names: tuple[str, ...]) -> Selection:
    """When the rounds leave structure, the rounds again from round one's winner and runner-up together
    (if both passed every rule), and the run that leaves less structure is kept.  Round one picks among
    near-twins (Coulomb or viscous friction, a voltage drop or viscous friction) before the others are
    known: the wrong twin fits best alone, then no second effect opens beside it; or both are there, and
    either alone hides the other.  Refitted together, a twin that is not there shrinks to nothing and
    is pruned (``wide_searches`` only)."""
    if sel.verdict != "unexplained" or not sel.effects or not sel.rounds or not wide_searches(sel.meas):
        return sel
    passed = [a for a in sel.rounds[0] if isinstance(a, Assessment) and a.accepted]
    if len(passed) < 2 or sel.work > sel.policy.total_work_budget - sel.policy.later_run_work:
        return sel
    twins = (passed[0].fit.effect, passed[1].fit.effect)
    return _less_structure(_forward(sel.meas, names, sel.policy, twins, sel.rounds[:1], spent=sel.work), sel)


def _settled(meas: Measurement, effects: tuple[Effect, ...]) -> Measurement:
    spec = meas.spec(effects)
    probe = Evaluator(meas, noise_floor(meas, meas.replay(meas.spec())))
    return settle_switches(meas, lambda m: probe.nll(m.replay(spec)))


def _forward(meas: Measurement, names: tuple[str, ...], policy: DiscoveryPolicy, found: tuple[Effect, ...] = (),
             earlier: list[list[Assessment | Screened]] | None = None, wide: bool = False,
             spent: int = 0) -> Selection:
    """Rounds, twin swaps, pruning and the verdict on a measurement whose switches are settled;
    ``found``: effects a run on the same recording adopted in its rounds ``earlier``, refitted here
    and the rounds continued after them; ``wide``: whether the wide searches run (a thorough round when
    a round adopts nothing, a pair restart: ``thorough``);
    ``spent``: the work of the runs before this one on the recording (``total_work_budget``)."""
    budget = min(policy.work_budget, policy.total_work_budget - spent)
    floor = noise_floor(meas, meas.replay(meas.spec()))
    ev = Evaluator(meas, floor)
    folds = folds_by_cycle(meas)
    effects: tuple[Effect, ...] = joint_fit(ev, found)
    rounds: list[list[Assessment | Screened]] = list(earlier or [])[:len(found)]
    near_tie = None
    stopped_for_time = False
    restarted = refilled = False
    adopted: set[str] = set()
    while True:
        for round_ in range(len(effects) + 1, policy.max_effects + 1):
            remaining = [n for n in names if n not in {e.name for e in effects}]
            if not remaining or (effects and not worth_another_round(excess(ev, effects), meas.n, policy)):
                break
            if round_ > 1 and ev.work > budget:
                stopped_for_time = True
                break
            assessed, screened = _round(ev, meas, effects, remaining, folds, round_, budget, wide, policy)
            rounds.append([*assessed, *screened])
            passing = [a for a in assessed if a.accepted]
            if not passing:
                break
            best = passing[0]
            near_tie = near_tie or _near_tie(round_, best, assessed, policy)
            effects = best.fit.effects
        if not (restarted or not wide or not rounds or ev.work > budget or not wide_searches(meas)
                or structure_after_start(ev, effects) <= policy.structure_floors):
            # structure left that no single candidate removes (none adopted, or the rounds' last): two round-one
            # candidates at once, then rounds again
            restarted = True
            pair = pair_restart(ev, meas, effects, rounds[0], budget, policy)
            if pair is not None:
                effects = pair
                continue
        effects = swap_twins(ev, effects, rounds, policy, budget)
        adopted |= {e.name for e in effects}
        kept = prune(ev, effects)
        while small := [e for e in kept if not nameable_size(e.name, e.value, policy)]:
            kept = joint_fit(ev, tuple(e for e in kept if e is not small[0]))    # refitted jointly it shrank
        dropped = len(kept) < len(effects)
        effects = kept
        # an effect the later ones made redundant freed a round (the last one may not have been run)
        if refilled or not dropped or len(effects) >= policy.max_effects or ev.work > budget:
            break
        refilled = True
    stopped_for_time = stopped_for_time or ev.work > budget         # a round's later candidates not assessed
    ex_before = excess(ev, ())
    refine_start(ev, effects)
    ex_after = excess(ev, effects)
    if unreadable := [e for e in effects if _zero_beside_structure(e, ex_after, policy)]:
        effects = joint_fit(ev, tuple(e for e in effects if e not in unreadable)) if len(effects) > 1 else ()
        refine_start(ev, effects)
        ex_after = excess(ev, effects)
    pruned = [n for n in CATALOGUE if n in adopted - {e.name for e in effects}]
    spans = effect_intervals(held_start_sensitivity(ev, effects), effects) if effects else []
    structured = max(ex_after.values()) > policy.structure_floors
    if structured:
        verdict = "unexplained"
    else:
        verdict = "explained" if effects else "none"
    return Selection(effects=effects, verdict=verdict, rounds=rounds, floor=floor, excess_before=ex_before,
                     excess_after=ex_after, near_tie=near_tie, simulations=ev.simulations, work=spent + ev.work,
                     failures=ev.failures, command_before=ev.command_for(()),
                     command_after=ev.command_for(effects), meas=meas, stopped_for_time=stopped_for_time,
                     pruned=pruned, intervals=spans, policy=policy)



def _zero_beside_structure(effect: Effect, ex_after: dict[str, float], policy: DiscoveryPolicy) -> bool:
    """Whether ``effect`` is a sensor's zero (``Param.zero_of``) while another signal keeps structure:
    a plant the model gets wrong also moves that signal's mean (a hot winding's smaller current, over
    unequal times in each direction, reads as an offset), and only the other signals tell the two
    apart, so such a zero is not named."""
    signal = effect.PARAMS[0].zero_of
    return bool(signal) and any(x > policy.structure_floors for s, x in ex_after.items() if s != signal)


def _round(ev: Evaluator, meas: Measurement, effects: tuple[Effect, ...], remaining: list[str],
           folds: tuple[np.ndarray, np.ndarray], round_: int, budget: int,
           wide: bool, policy: DiscoveryPolicy) -> tuple[list[Assessment], list[Screened]]:
    """One round: every remaining candidate scanned, the best by the scan (all in round one) assessed;
    when none passes and structure is left, each again from its profile walk (``thorough_round``)."""
    nll_now = ev.nll(ev.sim(effects))
    base_sens = sensitivity(ev, effects) if effects else None
    scans = {n: scan(ev, effects, n, base_sens) for n in remaining}
    scan_gain = {n: nll_now - float(np.min(scans[n].nll)) for n in remaining}
    order = sorted(remaining, key=lambda n: -scan_gain[n])
    k = len(order) if round_ == 1 else policy.later_full_fits
    assessed = []
    for n in order[:k]:                       # most promising first, while the budget lasts (one at least)
        if scan_gain[n] > 0 and (not assessed or ev.work <= budget):
            assessed.append(assess(ev, meas, effects, n, folds, round_, policy, scans[n]))
    full = {a.fit.name for a in assessed}
    assessed.sort(key=adoption_rank)
    screened = [Screened(n, round_, float(scans[n].grid[np.argmin(scans[n].nll)]), scan_gain[n])
                for n in order if n not in full]
    if (wide and not any(a.accepted for a in assessed) and effects and wide_searches(meas)
            and structure_after_start(ev, effects) > policy.structure_floors):
        redone = thorough_round(ev, meas, effects, scan_gain, scans, folds, round_, [*assessed, *screened],
                                budget, policy)
        assessed = [a for a in redone if isinstance(a, Assessment)]
        screened = [a for a in redone if not isinstance(a, Assessment)]
    return assessed, screened


def _near_tie(round_: int, best: Assessment, assessed: list[Assessment], policy: DiscoveryPolicy) -> dict | None:
    """The runner-up when it leaves at most ``policy.near_tie`` times the winner's held-out structure."""
    runner = next((a for a in assessed if a is not best), None)
    if runner is None or runner.structure_left + 1.0 > policy.near_tie * (best.structure_left + 1.0):
        return None
    return {"round": round_, "chosen": best.fit.name, "runner_up": runner.fit.name,
            "scores": {best.fit.name: best.score, runner.fit.name: runner.score},
            "structure_left": {best.fit.name: best.structure_left, runner.fit.name: runner.structure_left},
            "heldout_nll_gain": {best.fit.name: best.fit.heldout_nll_gain,
                                 runner.fit.name: runner.fit.heldout_nll_gain},
            "runner_up_accepted": bool(runner.accepted)}
