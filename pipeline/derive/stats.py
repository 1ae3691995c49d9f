"""The one summary-statistics shape of summary.json: n, mean, std (sample), min, max; None when empty."""

from __future__ import annotations

import numpy as np


def describe(values) -> dict[str, float | int | None]:
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return {"n": 0, "mean": None, "std": None, "min": None, "max": None}
    return {"n": int(len(x)), "mean": float(x.mean()), "std": float(x.std(ddof=1)) if len(x) > 1 else 0.0,
            "min": float(x.min()), "max": float(x.max())}
