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

import numpy as np

from pipeline.discover.candidates import Evaluator, Scan, make
from pipeline.discover.evidence import Assessment, Screened, assess
from pipeline.discover.joint import joint_fit
from pipeline.discover.measurement import Measurement
from pipeline.model.effects import CATALOGUE, Effect

WALK_NFEV = 8       # evaluations of each step's refit of the adopted effects along the profile walk


def thorough_round(ev: Evaluator, meas: Measurement, effects: tuple[Effect, ...], gains: dict[str, float],
                   scans: dict[str, Scan], folds: tuple[np.ndarray, np.ndarray], round_: int,
                   quick: list[Assessment | Screened], budget: int) -> list[Assessment | Screened]:
    """The round again, each candidate that gained in the scan (most first, while discovery's work stays
    within ``budget``) started from its profile walk's best point; a candidate the walk does not improve
    keeps its quick result."""
    earlier = {a.fit.name if isinstance(a, Assessment) else a.name: a for a in quick}
    out: list[Assessment | Screened] = []
    for name in sorted(earlier, key=lambda n: -gains.get(n, 0.0)):
        relaxed = (jointly_relaxed(ev, effects, name, scans[name])
                   if gains.get(name, 0.0) > 0 and ev.work <= budget else None)
        out.append(earlier[name] if relaxed is None else assess(ev, meas, effects, name, folds, round_, relaxed))
    return sorted(out, key=lambda a: -a.fit.heldout_nll_gain if isinstance(a, Assessment) else float("inf"))


def jointly_relaxed(ev: Evaluator, base: tuple[Effect, ...], name: str, scanned: Scan) -> Scan | None:
    """``scanned`` with one more point: the candidate and every adopted effect fitted jointly from the
    best point of its profile walk, inserted where its value falls (so ``fit_candidate`` starts from it
    and brackets it by the scan's neighbours); None when that beats no scan point."""
    walked = profile_walk(ev, base, name, scanned.grid)
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


def profile_walk(ev: Evaluator, base: tuple[Effect, ...], name: str, grid: np.ndarray) -> tuple[Effect, ...] | None:
    """The best point of the candidate's profile likelihood, walked outward from "absent" along its scan
    points in both directions, the adopted effects refitted at each point from where the previous point
    left them (a continuation: it follows a curved valley that no single linear step reaches), each
    direction stopped once the likelihood falls.  None when no point beats the adopted model."""
    absent = CATALOGUE[name].PARAMS[0].absent
    home = int(np.argmin(np.abs(np.asarray(grid) - absent)))
    best_nll, best = ev.nll(ev.sim(base)), None
    for step in (1, -1):
        current, last = base, ev.nll(ev.sim(base))
        for i in range(home + step, len(grid) if step > 0 else -1, step):
            held = make(name, float(grid[i]))
            current = joint_fit(ev, current, max_nfev=WALK_NFEV, held=(held,))
            nll = ev.nll(ev.sim((*current, held)))
            if nll < best_nll:
                best_nll, best = nll, (*current, held)
            if nll > last:
                break
            last = nll
    return best
