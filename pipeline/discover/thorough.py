"""A round's candidates refitted jointly with the effects already adopted from the best point of a
profile walk, for when the quick round finds no candidate that passes and structure is left.

The quick round (``candidates.scan``) relaxes the adopted effects by one Gauss-Newton step per scan
point.  That step is linear, and near-twins are not: a rack inertia adopted alone takes the spring's
share of a slower oscillation, so adding the spring means moving the inertia a long way back along a
narrow curved valley (the oscillation's frequency) that the one step does not follow.  The candidate
then looks useless, is screened out or fails the held-out check, and the recording is left
``unexplained`` with a catalogued effect missing.  Here the candidate is walked along its scan points
with the adopted effects refitted at each (``profile_walk``), then everything is fitted jointly from
the walk's best point (``joint.joint_fit``); the result is assessed by the same rules as any candidate
(``evidence.assess``), so nothing is named on weaker evidence -- only where the fit starts changes."""

from __future__ import annotations

from itertools import combinations

import numpy as np

from pipeline.discover.candidates import Evaluator, Scan, make, prune
from pipeline.discover.evidence import Assessment, Screened, adoption_rank, assess, nameable_size
from pipeline.discover.joint import coordinates, joint_fit
from pipeline.discover.measurement import Measurement
from pipeline.discover.policy import DiscoveryPolicy
from pipeline.discover.start_refit import refine_start
from pipeline.model.effects import CATALOGUE, Effect

def thorough_round(ev: Evaluator, meas: Measurement, effects: tuple[Effect, ...], gains: dict[str, float],
                   scans: dict[str, Scan], folds: tuple[np.ndarray, np.ndarray], round_: int,
                   quick: list[Assessment | Screened], budget: int,
                   policy: DiscoveryPolicy) -> list[Assessment | Screened]:
    """The round again, each candidate that gained in the scan (most first, while discovery's work stays
    within ``budget``) started from its profile walk's best point; a candidate the walk does not improve
    keeps its quick result."""
    earlier = {a.fit.name if isinstance(a, Assessment) else a.name: a for a in quick}
    out: list[Assessment | Screened] = []
    for name in sorted(earlier, key=lambda n: -gains.get(n, 0.0)):
        relaxed = (jointly_relaxed(ev, effects, name, scans[name], policy)
                   if gains.get(name, 0.0) > 0 and ev.work <= budget else None)
        out.append(earlier[name] if relaxed is None
                   else assess(ev, meas, effects, name, folds, round_, policy, relaxed))
    return sorted(out, key=lambda a: adoption_rank(a) if isinstance(a, Assessment) else float("inf"))


def jointly_relaxed(ev: Evaluator, base: tuple[Effect, ...], name: str, scanned: Scan,
                    policy: DiscoveryPolicy) -> Scan | None:
    """``scanned`` with one more point: the candidate and every adopted effect fitted jointly from the
    best point of its profile walk, inserted where its value falls (so ``fit_candidate`` starts from it
    and brackets it by the scan's neighbours); None when that beats no scan point."""
    walked = profile_walk(ev, base, name, scanned.grid, policy.walk_nfev)
    if walked is None:
        return None
    fitted = joint_fit(ev, walked)
    nll = ev.nll(ev.sim(fitted))
    if nll >= float(np.min(scanned.nll)):
        return None
    value = fitted[-1].value
    at = int(np.searchsorted(scanned.grid, value))
    if at < len(scanned.grid) and scanned.grid[at] == value:
        grid, losses, bases = scanned.grid.copy(), scanned.nll.copy(), list(scanned.bases)
        losses[at], bases[at] = nll, fitted[:-1]
    else:
        grid = np.insert(scanned.grid, at, value)
        losses = np.insert(scanned.nll, at, nll)
        bases = [*scanned.bases[:at], fitted[:-1], *scanned.bases[at:]]
    return Scan(grid=grid, nll=losses, bases=bases)


def profile_walk(ev: Evaluator, base: tuple[Effect, ...], name: str, grid: np.ndarray,
                 nfev: int) -> tuple[Effect, ...] | None:
    """The best point of the candidate's profile likelihood, walked outward from "absent" along its scan
    points in both directions, the adopted effects refitted at each point from where the previous point
    left them (a continuation: it follows a curved valley that no single linear step reaches), each
    direction stopped once the likelihood falls; each refit within ``nfev`` evaluations.  None when no
    point beats the adopted model."""
    absent = CATALOGUE[name].PARAMS[0].absent
    home = int(np.argmin(np.abs(np.asarray(grid) - absent)))
    best_nll, best = ev.nll(ev.sim(base)), None
    for step in (1, -1):
        current, last = base, ev.nll(ev.sim(base))
        for i in range(home + step, len(grid) if step > 0 else -1, step):
            held = make(name, float(grid[i]))
            current = joint_fit(ev, current, max_nfev=nfev, held=(held,))
            nll = ev.nll(ev.sim((*current, held)))
            if nll < best_nll:
                best_nll, best = nll, (*current, held)
            if nll > last:
                break
            last = nll
    return best


def pair_restart(ev: Evaluator, meas: Measurement, effects: tuple[Effect, ...],
                 first_round: list[Assessment | Screened], budget: int,
                 policy: DiscoveryPolicy) -> tuple[Effect, ...] | None:
    """Two effects that together do what no single one does, for a fresh start of the rounds: round
    one adopts the candidate that alone removes most (a long loop delay stands in for a softer spring
    beside a viscous friction), and the rounds after it cannot take that back.  Each pair of round
    one's best candidates is fitted jointly from their round-one values; the best pair is kept when
    it beats the effects found by BIC (each parameter charged), leaves at most ``pair_shrink`` of their
    structure (a pair of wrong effects can buy a little likelihood without removing the pattern) and,
    refitted, still needs both members (``prune``) at a nameable size.  None when no pair does."""
    pool = [a for a in first_round if isinstance(a, Assessment) and a.fit.heldout_nll_gain > 0
            and nameable_size(a.fit.name, a.fit.value, policy)][:policy.pair_pool]
    n_obs = meas.n * len(meas.signals)
    nll_now, k_now = ev.nll(ev.sim(effects)), len(coordinates(effects))
    left_now = _structure(ev, effects)
    now = {e.name for e in effects}
    best: tuple[float, tuple[Effect, ...]] | None = None
    for a, b in combinations(pool, 2):
        if {a.fit.name, b.fit.name} == now or ev.work > budget:
            continue
        fitted = joint_fit(ev, (a.fit.effect, b.fit.effect))
        nll = ev.nll(ev.sim(fitted))
        delta_bic = 2.0 * (nll - nll_now) + (len(coordinates(fitted)) - k_now) * np.log(n_obs)
        if (delta_bic <= policy.max_delta_bic and _structure(ev, fitted) <= policy.pair_shrink * left_now
                and (best is None or nll < best[0])):
            best = (nll, fitted)
    if best is None:
        return None
    kept = prune(ev, best[1])
    return kept if len(kept) == 2 and all(nameable_size(e.name, e.value, policy) for e in kept) else None


def _structure(ev: Evaluator, effects: tuple[Effect, ...]) -> float:
    """The largest replay MSE above the noise over the signals, in noise variances."""
    return max(m / ev.floor[s] - 1.0 for s, m in ev.mse(ev.sim(effects)).items())


def structure_after_start(ev: Evaluator, effects: tuple[Effect, ...]) -> float:
    """``_structure`` once the start is refined on the whole recording, as the verdict will have it
    (``start_refit``): a transient the first seconds' start estimate leaves (after a board reset, a
    slow mode) is not structure worth a thorough round.  The refined start is not kept."""
    spec = ev.meas.spec(effects)
    start = ev.meas.x0(spec)
    if refine_start(ev, effects) is None:
        return _structure(ev, effects)
    left = _structure(ev, effects)
    ev.meas.pin_start(spec, ev.meas.dir, start)
    return left
