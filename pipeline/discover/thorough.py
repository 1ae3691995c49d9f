"""A round's candidates started from the coarse scan's best points and fitted jointly with the
effects already adopted, for when the quick round finds no candidate that passes.

The quick round (``candidates.scan``) relaxes the adopted effects by one Gauss-Newton step per scan
point.  That step is linear, and near-twins are not: a rack inertia adopted alone takes the spring's
share of a slower oscillation (and a friction the voltage drop's share of a slower run), so adding
the twin means moving the adopted effect a long way back, along a valley the one step does not
follow.  The candidate then looks useless and is screened out or fails the held-out check, and the
recording is left ``unexplained`` with a catalogued effect missing.  Here each remaining candidate is
refitted from its best scan points with every adopted parameter free (``joint.joint_fit``); the result
is assessed by the same rules as any candidate (``evidence.assess``), so nothing is named on weaker
evidence -- only the starting point of the fit changes.
"""

from __future__ import annotations

import numpy as np

from pipeline.discover.candidates import Evaluator, Scan, make
from pipeline.discover.joint import joint_fit
from pipeline.model.effects import CATALOGUE, Effect

STARTS = 2          # scan points each candidate's joint fit starts from (the best ones, "absent" excluded)


def jointly_relaxed(ev: Evaluator, base: tuple[Effect, ...], name: str, scanned: Scan) -> Scan:
    """``scanned`` with one more point: the candidate and every adopted effect fitted jointly from
    each of its ``STARTS`` best scan points, the best of those fits inserted where its value falls
    (so ``fit_candidate`` starts from it and brackets it by the scan's neighbours)."""
    absent = CATALOGUE[name].PARAMS[0].absent
    order = [int(i) for i in np.argsort(scanned.nll) if scanned.grid[i] != absent][:STARTS]
    best: tuple[float, tuple[Effect, ...]] | None = None
    for i in order:
        fitted = joint_fit(ev, (*scanned.bases[i], make(name, float(scanned.grid[i]))))
        nll = ev.nll(ev.sim(fitted))
        if best is None or nll < best[0]:
            best = (nll, fitted)
    if best is None or best[0] >= float(np.min(scanned.nll)):
        return scanned
    nll, fitted = best
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
