"""Questions across runs of one rig: a pooled estimate per effect parameter, whether the runs agree,
and whether the parameter drifts over recording time (wear).

Each run's discovery gives an estimate and a ~95 % interval; its standard
error is taken as the interval's half-width / 1.96.  Pooling is the
inverse-variance (fixed-effect) mean, whose interval shrinks as 1/sqrt(runs)
when the runs agree.  Agreement is Cochran's Q test (chi-square, runs - 1
degrees of freedom, p >= 0.05: they agree).  When they do not, the runs differ
by more than their intervals allow, and the pooled estimate becomes the
DerSimonian-Laird random-effects mean, whose interval includes the spread
between runs.

The trend is a weighted least-squares line through the estimates against
recording time (weights 1/se^2), its slope's standard error scaled up by the
scatter about the line when that exceeds what the intervals imply (the Birge
ratio: runs are not trusted beyond the scatter they show), and a t test on
n - 2 degrees of freedom.  The scatter is measured about the line, not about
the mean, so a drift does not hide itself by inflating the spread.  A trend is flagged at p < ``TREND_P``,
stricter than 0.05 because every parameter of every rig is tested.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

Z95 = 1.959963984540054
AGREE_P = 0.05
TREND_P = 0.01
MIN_TREND_RUNS = 4


@dataclass(frozen=True)
class Pooled:
    runs: int
    estimate: float
    lo: float
    hi: float
    method: str                 # "fixed" (the runs agree) or "random" (DerSimonian-Laird)
    q: float                    # Cochran's Q
    p_agree: float              # its p-value (chi-square, runs - 1 dof)
    i2: float                   # share of the spread beyond the intervals (0..1)
    tau: float                  # the between-run standard deviation (random effects; 0 when fixed)

    @property
    def agree(self) -> bool:
        return self.p_agree >= AGREE_P

    def to_dict(self) -> dict:
        return {**asdict(self), "agree": self.agree}


@dataclass(frozen=True)
class Trend:
    slope_per_day: float
    lo: float                   # ~95 % interval of the slope
    hi: float
    p: float
    change_pct: float           # the fitted change over the recorded span, % of the pooled estimate
    span_days: float

    @property
    def flagged(self) -> bool:
        return self.p < TREND_P

    def to_dict(self) -> dict:
        return {**asdict(self), "flagged": self.flagged}


def standard_errors(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The standard error each ~95 % interval implies (half-width / 1.96)."""
    return (np.asarray(hi, float) - np.asarray(lo, float)) / (2 * Z95)


def pool(x: np.ndarray, se: np.ndarray) -> Pooled:
    """Inverse-variance pooled estimate, Cochran's Q, and the random-effects fallback when the runs disagree."""
    x, se = np.asarray(x, float), np.asarray(se, float)
    if len(x) == 0 or np.any(~np.isfinite(x)) or np.any(~(se > 0)):
        raise ValueError("pool needs finite estimates with positive standard errors")
    w = 1.0 / se**2
    mean = float(np.sum(w * x) / np.sum(w))
    k = len(x)
    q = float(np.sum(w * (x - mean) ** 2))
    p = float(stats.chi2.sf(q, k - 1)) if k > 1 else 1.0
    i2 = max(0.0, (q - (k - 1)) / q) if q > 0 else 0.0
    if p >= AGREE_P:
        half = Z95 / math.sqrt(float(np.sum(w)))
        return Pooled(k, mean, mean - half, mean + half, "fixed", q, p, i2, 0.0)
    tau2 = max(0.0, (q - (k - 1)) / (np.sum(w) - np.sum(w**2) / np.sum(w)))
    ws = 1.0 / (se**2 + tau2)
    mean_r = float(np.sum(ws * x) / np.sum(ws))
    half = Z95 / math.sqrt(float(np.sum(ws)))
    return Pooled(k, mean_r, mean_r - half, mean_r + half, "random", q, p, i2, math.sqrt(tau2))


def trend(days: np.ndarray, x: np.ndarray, se: np.ndarray, pooled: Pooled) -> Trend | None:
    """Weighted straight line through the estimates over recording time; None with too few runs or one instant."""
    days, x, se = (np.asarray(a, float) for a in (days, x, se))
    k = len(x)
    span = float(days.max() - days.min()) if k else 0.0
    if k < MIN_TREND_RUNS or span <= 0:
        return None
    w = 1.0 / se**2
    tc = days - np.sum(w * days) / np.sum(w)
    sxx = float(np.sum(w * tc**2))
    slope = float(np.sum(w * tc * x) / sxx)
    intercept = float(np.sum(w * x) / np.sum(w))
    resid = x - intercept - slope * tc
    birge = float(np.sum(w * resid**2) / (k - 2))
    se_slope = math.sqrt(max(1.0, birge) / sxx)
    t = slope / se_slope if se_slope > 0 else math.inf
    p = float(2 * stats.t.sf(abs(t), k - 2))
    half = float(stats.t.ppf(0.975, k - 2)) * se_slope
    change = 100.0 * slope * span / abs(pooled.estimate) if pooled.estimate else math.inf
    return Trend(slope, slope - half, slope + half, p, change, span)
