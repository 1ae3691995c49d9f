"""All the parameters of a model at once: the joint parameter vector, sensitivities, Gauss-Newton steps,
the joint least-squares refit and the intervals from its information matrix.

``candidates`` scans and fits one candidate at a time; whatever touches every
parameter of every effect together lives here (an effect may have several).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.discover.residuals import residuals
from pipeline.estimate import autocorrelation_time
from pipeline.estimate.fit import Steps, fit
from pipeline.estimate.unknowns import effect_unknowns
from pipeline.model.effects import Effect, Param

# ------------------------------------------------------------------ the joint parameter vector
# Every parameter of every effect in a model, in order: what sensitivities, Gauss-Newton steps and
# intervals run over (an effect may have several parameters).

def coordinates(effects: tuple[Effect, ...]) -> list[tuple[int, Param]]:
    return [(i, p) for i, e in enumerate(effects) for p in e.PARAMS]


def values_of(effects: tuple[Effect, ...]) -> np.ndarray:
    return np.array([e.parameters[p.name] for i, p in coordinates(effects) for e in (effects[i],)])


def with_values(effects: tuple[Effect, ...], values: np.ndarray) -> tuple[Effect, ...]:
    params: list[dict[str, float]] = [dict(e.parameters) for e in effects]
    for (i, p), v in zip(coordinates(effects), values):
        params[i][p.name] = float(v)
    return tuple(type(e)(**ps) for e, ps in zip(effects, params))


def first_coordinate(effects: tuple[Effect, ...], i: int) -> int:
    """Index in the joint vector of effect i's first parameter."""
    return sum(len(e.PARAMS) for e in effects[:i])


def _clip(p: Param, v: float) -> float:
    return float(np.clip(v, *p.bounds))


# ------------------------------------------------------------------ sensitivities

@dataclass
class Sensitivity:
    """Residuals at a set of effects and their derivatives with respect to each effect's parameter."""

    r0: dict[str, np.ndarray]
    jac: list[dict[str, np.ndarray]]      # one per effect, per signal


def _step(p: Param, v: float) -> float:
    lo_b, hi_b = p.bounds
    return max(abs(v) * 1e-3, (hi_b - lo_b) * 1e-6)


def sensitivity(ev, effects: tuple[Effect, ...], replayed=None) -> Sensitivity:
    """Forward differences, one simulation per parameter (stepping inward at a bound or a failure);
    ``replayed``: effects -> residuals (default: the Evaluator's replay, each model from its own start)."""
    replayed = replayed or (lambda effs: residuals(ev.meas, ev.sim(effs)))
    r0 = replayed(effects)
    jac = []
    base = values_of(effects)
    for c, (_, p) in enumerate(coordinates(effects)):
        v = float(base[c])
        lo_b, hi_b = p.bounds
        h = _step(p, v)
        v2 = v + h if v + h <= hi_b else v - h
        moved = lambda x: with_values(effects, np.concatenate([base[:c], [x], base[c + 1:]]))  # noqa: E731
        r1 = replayed(moved(v2))
        if not all(np.all(np.isfinite(r)) for r in r1.values()) and v - h >= lo_b:
            v2 = v - h
            r1 = replayed(moved(v2))
        jac.append({s: (r1[s] - r0[s]) / (v2 - v) for s in r0})
    return Sensitivity(r0=r0, jac=jac)


def gauss_newton(r0: dict[str, np.ndarray], jac: list[dict[str, np.ndarray]],
                 mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(step, information matrix) of the concentrated likelihood: each signal weighted by its
    residual variance, so rad and A need no exchange rate."""
    k = len(jac)
    A = np.zeros((k, k))
    g = np.zeros(k)
    for s, r in r0.items():
        rm = r if mask is None else r[mask]
        J = np.column_stack([j[s] if mask is None else j[s][mask] for j in jac])
        w = 1.0 / (float(np.mean(rm ** 2)) + 1e-30)
        A += w * J.T @ J
        g += w * J.T @ rm
    try:
        step = -np.linalg.lstsq(A, g, rcond=None)[0]
    except np.linalg.LinAlgError:
        step = np.zeros(k)
    return step, A


def moved_effects(effects: tuple[Effect, ...], step: np.ndarray, trust: float = 0.5) -> tuple[Effect, ...]:
    """Effects with their parameters moved by ``step``, each move limited to a trust region."""
    out = []
    for (_, p), v, d in zip(coordinates(effects), values_of(effects), step):
        limit = trust * max(abs(v), _step(p, v) * 100)
        out.append(_clip(p, v + float(np.clip(d, -limit, limit))))
    return with_values(effects, np.array(out))


def joint_fit(ev, effects: tuple[Effect, ...], max_nfev: int = 40, held: tuple[Effect, ...] = (),
              taus: dict[str, float] | None = None) -> tuple[Effect, ...]:
    """Every parameter of every effect at once (``estimate.fit``: trust region within the bounds), so the
    result does not depend on the order the effects were found in.

    Each signal's residual is divided by its RMS at the start (the concentrated likelihood's weights
    there), each parameter by its own size (``effect_unknowns(scaled=True)``); the fit is kept only if
    the likelihood improves.  ``held``: effects in the model at their given values, not fitted (a
    profile over one of them).  ``taus``: each signal's residual autocorrelation time at a first optimum,
    its rows counted as that many times fewer (the criterion's likelihood, ``estimate.fit``'s inflation):
    a signal whose misfit is smooth in time does not outweigh the independent samples of another.
    """
    if not effects:
        return effects
    unknowns = [u for e in effects for u in effect_unknowns(e, scaled=True)]
    start = residuals(ev.meas, ev.sim((*effects, *held)))
    tau = taus or {s: 1.0 for s in start}
    weight = {s: 1.0 / np.sqrt((float(np.mean(r * r)) + 1e-3 * ev.floor[s]) * tau[s]) for s, r in start.items()}
    size = sum(len(r) for r in start.values())

    def at(x: np.ndarray) -> tuple[Effect, ...]:
        return with_values(effects, np.array([u.to_value(z) for u, z in zip(unknowns, x)]))

    def weighted(x: np.ndarray) -> np.ndarray:
        res = residuals(ev.meas, ev.sim((*at(x), *held)))
        out = np.concatenate([weight[s] * r for s, r in res.items()])
        return out if out.shape == (size,) and np.all(np.isfinite(out)) else np.full(size, 1e6)

    try:
        result = fit(weighted, unknowns, max_nfev=max_nfev, factors=np.zeros(0), steps=JOINT_STEPS)
    except ValueError:
        return effects
    trial = at(result.x)
    return trial if ev.nll(ev.sim((*trial, *held)), taus=taus) < ev.nll(ev.sim((*effects, *held)), taus=taus) else effects


# relative finite-difference steps of 1e-4 of each parameter's size (an event-driven plant's likelihood is only
# piecewise smooth: smaller steps read its kinks), every coordinate of unit typical step
JOINT_STEPS = Steps(diff_step=1e-4, x_scale=1.0)


def intervals(sens: Sensitivity, values: list[float]) -> list[tuple[float, float]]:
    """~95 % interval of each parameter from the joint information matrix (Gauss-Newton, the
    others free), with each signal's sample count divided by its residual's autocorrelation time."""
    k = len(sens.jac)
    A = np.zeros((k, k))
    for s, r in sens.r0.items():
        J = np.column_stack([j[s] for j in sens.jac])
        var = float(np.mean(r ** 2)) + 1e-30
        A += J.T @ J / (var * autocorrelation_time(r))
    cov = np.linalg.pinv(A)
    out = []
    for i, v in enumerate(values):
        half = 1.96 * float(np.sqrt(max(cov[i, i], 0.0)))
        if not np.isfinite(half) or A[i, i] == 0.0:
            half = float("inf")
        out.append((v - half, v + half))
    return out


def effect_intervals(sens: Sensitivity, effects: tuple[Effect, ...]) -> list[tuple[float, float]]:
    """Each effect's first-parameter interval, all parameters of all effects free."""
    spans = intervals(sens, list(values_of(effects)))
    return [spans[first_coordinate(effects, i)] for i in range(len(effects))]
