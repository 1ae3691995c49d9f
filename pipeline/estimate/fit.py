"""One joint fit and its result: ``scipy.optimize.least_squares`` on the whitened residual with the
priors as extra rows; covariance, AIC/BIC counting every free parameter, profile-likelihood intervals.

The likelihood.  Each signal's residual (measured minus the model's replay, the logged command
driving the model) is divided by the signal's noise standard deviation from the recording itself,
so the cost is chi-square: ``-2 log L`` up to a constant.  The nuisances of each recording (its
start state, the commands in force and in flight, a counter's zero after a board reset) are
concentrated out inside the residual: solved for the model at hand by the recording's own start
estimator (linear least squares, exact for a linear plant).  A prior is a normal row in the fitted
coordinate (log space for positive scales): with a prior, a parameter the data cannot pin stays near
its prior instead of wandering along a ridge.

Honesty of the intervals.  Where the model misses by more than the noise, or the residual is
correlated from sample to sample (the clock's truncation error is smooth in time), chi-square
over-counts the evidence; each recording's signal is weighted down by its ``inflation`` (reduced
chi-square, at least 1, times the residual's autocorrelation time), as a quasi-likelihood does, so
the priors and the covariance weigh what the data really hold.  Intervals are profile-likelihood ones (as lmfit's
``conf_interval``): the parameter is moved, the others refitted, until ``-2 log L`` rises by the
chi-square quantile.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.special import ndtri

from pipeline.estimate.unknowns import Unknown

# residual function: internal parameter vector -> whitened data residuals (fixed length, finite)
Residual = Callable[[np.ndarray], np.ndarray]

PROFILE_STEPS = 3      # secant steps per side of a profile interval (the rise is near quadratic: 1-2 suffice)
FAILED = 1e3          # a whitened residual for a model the simulator refuses (steep, finite: the fit steps back)


def autocorrelation_time(r: np.ndarray, max_lag: int = 50) -> float:
    """1 + 2 sum rho_k (to the first negative rho): how many samples one independent one is worth."""
    r = r - r.mean()
    den = float(np.dot(r, r))
    if den == 0:
        return 1.0
    tau = 1.0
    for k in range(1, min(max_lag, len(r) // 4)):
        rho = float(np.dot(r[:-k], r[k:])) / den
        if rho <= 0:
            break
        tau += 2.0 * rho
    return tau


@dataclass
class FitResult:
    """What one fit found (as lmfit's ``MinimizerResult``): values, covariance, criteria, intervals."""

    unknowns: list[Unknown]
    x: np.ndarray                        # internal coordinates at the optimum
    data_chi2: float                     # sum of squared whitened data residuals
    prior_chi2: float
    n_data: int
    cov_internal: np.ndarray             # covariance of x
    success: bool
    nfev: int
    residual: Residual = field(repr=False)
    segments: list[slice] = field(default_factory=list, repr=False)   # data rows per recording and signal
    factors: np.ndarray = field(default_factory=lambda: np.zeros(0))   # each segment's inflation (``inflation``)
    _profiles: dict = field(default_factory=dict, repr=False)

    @property
    def names(self) -> list[str]:
        return [u.name for u in self.unknowns]

    @property
    def values(self) -> dict[str, float]:
        return {u.name: u.to_value(z) for u, z in zip(self.unknowns, self.x)}

    @property
    def k(self) -> int:
        return len(self.unknowns)

    @property
    def aic(self) -> float:
        return self.data_chi2 + 2.0 * self.k

    @property
    def bic(self) -> float:
        return self.data_chi2 + self.k * np.log(max(self.n_data, 1))

    @property
    def stderr(self) -> dict[str, float]:
        """1-sigma of each value (delta method from the internal covariance)."""
        out = {}
        for i, u in enumerate(self.unknowns):
            sd = float(np.sqrt(max(self.cov_internal[i, i], 0.0)))
            out[u.name] = sd * u.to_value(self.x[i]) if u.log else sd * u.scale
        return out

    def wald_interval(self, name: str, level: float = 0.95) -> tuple[float, float]:
        i = self.names.index(name)
        u = self.unknowns[i]
        half = float(_quantile(level) * np.sqrt(max(self.cov_internal[i, i], 0.0)))
        return u.to_value(self.x[i] - half), u.to_value(self.x[i] + half)

    def objective(self, x: np.ndarray) -> float:
        """-2 log of the posterior (data chi-square plus priors) at internal ``x``."""
        return _objective(self.residual, self.unknowns, x)

    def profile_interval(self, name: str, level: float = 0.95, max_nfev: int = 8) -> tuple[float, float]:
        """Where the profiled ``-2 log`` posterior rises by the chi-square quantile."""
        key = (name, level)
        if key not in self._profiles:
            self._profiles[key] = _profile(self, self.names.index(name), level, max_nfev)
        return self._profiles[key]


def _quantile(level: float) -> float:
    """The square root of the chi-square(1) quantile at ``level``: the normal's two-sided one (1.96 at 95 %);
    scipy.special's ``ndtri``, not scipy.stats, whose import costs the command ~0.3 s."""
    return float(ndtri(0.5 + level / 2.0))


def _prior_rows(unknowns: Sequence[Unknown], x: np.ndarray) -> np.ndarray:
    rows = [u.prior_row(z) for u, z in zip(unknowns, x)]
    return np.array([r for r in rows if r is not None], dtype=float)


def _objective(residual: Residual, unknowns: Sequence[Unknown], x: np.ndarray) -> float:
    r = residual(x)
    p = _prior_rows(unknowns, x)
    return float(r @ r + p @ p)


def _stacked(residual: Residual, unknowns: Sequence[Unknown]) -> Residual:
    def f(x: np.ndarray) -> np.ndarray:
        return np.concatenate([residual(x), _prior_rows(unknowns, x)])
    return f


def _start(unknowns: Sequence[Unknown], bounds: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    lo, hi = bounds
    x0 = np.array([u.to_internal(u.start) for u in unknowns], dtype=float)
    margin = 1e-9 * np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    return np.clip(x0, lo + margin, hi - margin)


def _scales(unknowns: Sequence[Unknown], x0: np.ndarray) -> np.ndarray:
    """Typical step of each internal coordinate: the prior's width, else the value's size."""
    out = []
    for u, z in zip(unknowns, x0):
        if u.prior is not None:
            out.append(u.prior.sd)
        elif u.log:
            out.append(1.0)
        else:
            lo, hi = u.bounds
            out.append(max(abs(z), 1e-3 * (hi - lo) if np.isfinite(hi - lo) else 1.0))
    return np.array(out)


def inflation(r: np.ndarray, segments: Sequence[slice]) -> np.ndarray:
    """Per segment (one recording's signal): how many squared whitened rows one independent unit of
    evidence is worth there -- reduced chi-square (at least 1: the model misses, or the floor is low)
    times the residual's autocorrelation time (the clock's truncation error is smooth in time)."""
    out = []
    for s in segments:
        part = r[s]
        if len(part) <= 8:
            out.append(1.0)
            continue
        out.append(max(1.0, float(part @ part) / len(part)) * autocorrelation_time(part))
    return np.array(out)


def _weighted(residual: Residual, segments: Sequence[slice], factors: np.ndarray) -> Residual:
    def f(x: np.ndarray) -> np.ndarray:
        r = residual(x).copy()
        for s, c in zip(segments, factors):
            r[s] /= np.sqrt(c)
        return r
    return f


@dataclass(frozen=True)
class Steps:
    """How the optimizer steps: ``diff_step`` relative for its finite differences, ``x_scale`` each internal
    coordinate's typical step (None: the priors' widths, else the values' sizes), ``ftol`` where it
    stops (a step gaining less than this share of the cost)."""

    diff_step: float = 1e-6
    x_scale: float | None = None
    ftol: float = 1e-8


def _solve(residual: Residual, unknowns: list[Unknown], x0: np.ndarray, bounds, max_nfev: int, steps: Steps):
    stacked = _stacked(residual, unknowns)
    if not unknowns:
        return x0, np.zeros((len(stacked(x0)), 0)), True, 1
    sol = least_squares(stacked, x0, bounds=bounds, diff_step=steps.diff_step, max_nfev=max_nfev, method="trf", ftol=steps.ftol,
                        x_scale=_scales(unknowns, x0) if steps.x_scale is None else steps.x_scale)
    return sol.x, sol.jac, bool(sol.success), int(sol.nfev)


def fit(residual: Residual, unknowns: Sequence[Unknown], *, max_nfev: int = 200,
        segments: Sequence[slice] = (), factors: np.ndarray | None = None, steps: Steps = Steps()) -> FitResult:
    """Minimise data chi-square plus priors over ``unknowns``; ``residual`` maps their internal
    coordinates to the whitened data residuals, ``segments`` its rows per recording and signal.

    Each segment's rows are divided by the square root of its ``inflation`` (measured at a first
    optimum unless ``factors`` are given: models compared by their likelihood must share them), so
    the priors weigh against the evidence the data really hold and the covariance is honest."""
    unknowns = list(unknowns)
    lo = np.array([u.internal_bounds[0] for u in unknowns])
    hi = np.array([u.internal_bounds[1] for u in unknowns])
    x, nfev = _start(unknowns, (lo, hi)), 0
    if factors is None:
        x, _, _, nfev = _solve(residual, unknowns, x, (lo, hi), max_nfev, steps)
        factors = inflation(residual(x), segments)
    weighted = _weighted(residual, segments, factors)
    x, jac, ok, more = _solve(weighted, unknowns, x, (lo, hi), max_nfev, steps)
    nfev += more
    r = weighted(x)
    p = _prior_rows(unknowns, x)
    cov = np.linalg.pinv(jac.T @ jac) if unknowns else np.zeros((0, 0))
    return FitResult(unknowns=unknowns, x=x, data_chi2=float(r @ r), prior_chi2=float(p @ p), n_data=len(r),
                     cov_internal=cov, success=ok, nfev=nfev, residual=weighted,
                     segments=list(segments), factors=np.asarray(factors))


def _profile(res: FitResult, i: int, level: float, max_nfev: int) -> tuple[float, float]:
    """Profile-likelihood interval of unknown ``i``: each side, the signed root of the profiled rise,
    interpolated to the quantile (a secant on the signed root, which is linear for a quadratic)."""
    u = res.unknowns[i]
    target = _quantile(level)
    best = res.objective(res.x)
    others = [j for j in range(res.k) if j != i]
    lo_b, hi_b = u.internal_bounds
    se = float(np.sqrt(max(res.cov_internal[i, i], 1e-30)))
    def rise(zi: float) -> float:
        # the others start where the covariance says they go along with it (the conditional mean)
        shift = res.cov_internal[others, i] / max(res.cov_internal[i, i], 1e-300) * (zi - res.x[i])
        x_free = res.x[others] + shift

        def partial(xo: np.ndarray) -> np.ndarray:
            x = res.x.copy()
            x[others], x[i] = xo, zi
            return _stacked(res.residual, res.unknowns)(x)

        if others:
            lo = np.array([res.unknowns[j].internal_bounds[0] for j in others])
            hi = np.array([res.unknowns[j].internal_bounds[1] for j in others])
            start = np.clip(x_free, lo + 1e-12, hi - 1e-12)
            sol = least_squares(partial, start, bounds=(lo, hi), diff_step=1e-6, max_nfev=max_nfev,
                                x_scale=_scales([res.unknowns[j] for j in others], start))
            value = float(sol.fun @ sol.fun)
        else:
            f = partial(np.zeros(0))
            value = float(f @ f)
        return max(value - best, 0.0)

    ends = []
    for side in (-1.0, 1.0):
        bound = lo_b if side < 0 else hi_b
        step = target * se
        end = float(np.clip(res.x[i] + side * step, lo_b, hi_b))
        for _ in range(PROFILE_STEPS):
            trial = float(np.clip(res.x[i] + side * step, lo_b, hi_b))
            root = float(np.sqrt(rise(trial)))
            if trial == bound and root < target:
                end = bound                   # the data allow the whole way to the bound
                break
            if root <= 0.0:
                step *= 4.0
                continue
            new = step * target / root        # the secant through the optimum (root 0 there)
            end = float(np.clip(res.x[i] + side * new, lo_b, hi_b))
            if abs(new - step) < 0.05 * step:
                break
            step = new
        ends.append(end)
    return u.to_value(ends[0]), u.to_value(ends[1])
