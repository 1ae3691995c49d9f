"""A fitting problem: recordings of one rig, a model, the unknowns; its whitened residual.

The core knows a recording only as a ``Target``: a function from a model to its residual per
signal (measured minus replayed, the recording's nuisances solved inside) and the signal's noise
variance.  Several recordings of one rig share the model's unknowns: their rows are stacked.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from pipeline.estimate.fit import FAILED, FitResult, Steps, fit
from pipeline.estimate.unknowns import Model, Unknown


@dataclass(frozen=True)
class Target:
    """One recording as the fit sees it."""

    name: str
    residuals: Callable[[Model], dict[str, np.ndarray]]    # signal -> measured minus model (raises on failure)
    noise: dict[str, float]                                 # signal -> noise variance (the floor)


@dataclass(frozen=True)
class Problem:
    targets: tuple[Target, ...]
    model: Model
    unknowns: tuple[Unknown, ...]

    def model_at(self, x: np.ndarray) -> Model:
        return self.model.with_values({u.name: u.to_value(z) for u, z in zip(self.unknowns, x)})

    def whitened(self, model: Model) -> list[np.ndarray]:
        """Each target's signals' residuals over their noise standard deviation, in a fixed order."""
        out = []
        for target in self.targets:
            res = target.residuals(model)
            for s in sorted(target.noise):
                out.append(res[s] / np.sqrt(target.noise[s]))
        return out

    def rows(self) -> list[slice]:
        """The residual's rows of each target's signal, in ``whitened``'s order (from one evaluation)."""
        edges = np.cumsum([0, *map(len, self.whitened(self.model))])
        return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]

    def residual(self, size: int) -> Callable[[np.ndarray], np.ndarray]:
        """Internal coordinates -> the stacked whitened residual of ``size`` rows; a model the simulator
        refuses, or one whose rows are not finite, gives ``FAILED`` rows (steep: the fit steps back)."""
        def f(x: np.ndarray) -> np.ndarray:
            try:
                out = np.concatenate(self.whitened(self.model_at(x)))
            except (RuntimeError, FloatingPointError, ValueError, ZeroDivisionError):
                return np.full(size, FAILED)
            return out if out.shape == (size,) and np.all(np.isfinite(out)) else np.full(size, FAILED)
        return f

    def fit(self, max_nfev: int = 200, factors: np.ndarray | None = None, steps: Steps = Steps()) -> FitResult:
        rows = self.rows()
        return fit(self.residual(rows[-1].stop if rows else 0), self.unknowns, max_nfev=max_nfev, segments=rows,
                   factors=factors, steps=steps)
