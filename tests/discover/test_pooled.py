"""The statistics across runs on numbers drawn from known distributions: the pooled interval covers the
truth at its nominal rate and shrinks as 1/sqrt(runs), disagreement widens it, a drift is flagged and a
stable rig is not (at the stated false-alarm rate)."""

import numpy as np
import pytest

from pipeline.discover.pooled import AGREE_P, TREND_P, pool, standard_errors, trend

TRUTH = 7.7e-4


def _runs(rng, n, se=2e-6, spread=0.0, drift=0.0):
    se_i = se * rng.uniform(0.7, 1.3, n)
    truth = TRUTH * (1 + drift * np.arange(n) / max(n - 1, 1)) + (rng.normal(0, spread, n) if spread else 0.0)
    return np.arange(n, dtype=float), truth + rng.normal(0, 1, n) * se_i, se_i


def test_interval_standard_error_is_half_width_over_1_96():
    assert standard_errors(np.array([1.0]), np.array([1.0 + 2 * 1.959963984540054]))[0] == pytest.approx(1.0)


def test_pooled_interval_covers_the_truth_at_about_95_percent():
    rng = np.random.default_rng(1)
    hits = 0
    for _ in range(1000):
        _d, x, se = _runs(rng, 20)
        p = pool(x, se)
        hits += p.lo <= TRUTH <= p.hi
    assert 0.93 <= hits / 1000 <= 0.97


def test_pooled_interval_shrinks_as_one_over_sqrt_runs():
    rng = np.random.default_rng(2)
    _d, x, se = _runs(rng, 20)
    se = np.full(20, 2e-6)
    w5, w20 = (pool(x[:k], se[:k]) for k in (5, 20))
    assert (w5.hi - w5.lo) / (w20.hi - w20.lo) == pytest.approx(2.0, rel=1e-9)
    assert w20.method == "fixed" and w20.agree


def test_runs_that_disagree_get_the_random_effects_interval():
    rng = np.random.default_rng(3)
    _d, x, se = _runs(rng, 20, spread=2e-5)
    p = pool(x, se)
    assert p.p_agree < AGREE_P and not p.agree and p.method == "random"
    assert p.tau == pytest.approx(2e-5, rel=0.5)
    fixed_half = 1.96 / np.sqrt(np.sum(1 / se**2))
    assert (p.hi - p.lo) / 2 > 3 * fixed_half


def test_a_thirty_percent_drift_is_flagged_and_a_stable_rig_is_not():
    rng = np.random.default_rng(4)
    days, x, se = _runs(rng, 20, se=3e-5, drift=0.3)
    tr = trend(days, x, se, pool(x, se))
    assert tr.flagged and tr.p < TREND_P
    assert tr.change_pct == pytest.approx(100 * 0.3 / 1.15, rel=0.25)    # +30 % of the first, on the mean
    alarms = 0
    for _ in range(500):
        days, x, se = _runs(rng, 20, se=3e-5, spread=5e-5)     # scatter beyond the intervals, no drift
        alarms += trend(days, x, se, pool(x, se)).flagged
    assert alarms / 500 < 0.03


def test_a_trend_needs_four_runs_on_two_instants_at_least():
    x, se = np.full(3, TRUTH), np.full(3, 1e-6)
    assert trend(np.arange(3.0), x, se, pool(x, se)) is None
    x, se = np.full(5, TRUTH), np.full(5, 1e-6)
    assert trend(np.zeros(5), x, se, pool(x, se)) is None
    with pytest.raises(ValueError):
        pool(np.array([]), np.array([]))
