"""The estimation core on problems whose answer is known in closed form (no simulator)."""

import numpy as np
import pytest

from pipeline.estimate import Prior, Unknown, fit

X = np.linspace(0.0, 1.0, 200)


def line_problem(rng, a=2.0, b=-0.5, sigma=0.1, n=200):
    x = np.linspace(0.0, 1.0, n)
    y = a * x + b + rng.normal(0.0, sigma, n)
    return lambda z: (y - z[0] * x - z[1]) / sigma


def test_a_line_is_recovered_with_its_textbook_standard_errors():
    rng = np.random.default_rng(1)
    res = fit(line_problem(rng), [Unknown("a", 1.0, (-10, 10)), Unknown("b", 0.0, (-10, 10))],
              segments=[slice(0, 200)])
    A = np.column_stack([X, np.ones_like(X)]) / 0.1
    cov = np.linalg.inv(A.T @ A)
    assert res.values["a"] == pytest.approx(2.0, abs=4 * np.sqrt(cov[0, 0]))
    assert res.stderr["a"] == pytest.approx(np.sqrt(cov[0, 0]), rel=0.05)
    assert res.k == 2 and res.bic == pytest.approx(res.data_chi2 + 2 * np.log(200))
    assert res.aic == pytest.approx(res.data_chi2 + 4)


def test_profile_interval_equals_the_wald_one_on_a_linear_problem():
    rng = np.random.default_rng(2)
    res = fit(line_problem(rng), [Unknown("a", 1.0, (-10, 10)), Unknown("b", 0.0, (-10, 10))],
              segments=[slice(0, 200)])
    lo, hi = res.profile_interval("a")
    wlo, whi = res.wald_interval("a")
    assert lo == pytest.approx(wlo, rel=0.02) and hi == pytest.approx(whi, rel=0.02)


def test_profile_intervals_cover_the_truth_about_95_percent_of_the_time():
    held = 0
    for seed in range(120):
        rng = np.random.default_rng(100 + seed)
        res = fit(line_problem(rng, n=60), [Unknown("a", 1.0, (-10, 10)), Unknown("b", 0.0, (-10, 10))],
                  segments=[slice(0, 60)])
        lo, hi = res.profile_interval("a")
        held += lo <= 2.0 <= hi
    assert 104 <= held <= 120          # 95 % of 120 is 114; a binomial 1 % tail each side


def test_a_prior_holds_what_the_data_cannot_pin():
    """y = a c x pins only the product a c; with a prior on c, c stays at its prior and a takes the rest."""
    rng = np.random.default_rng(3)
    y = 6.0 * X + rng.normal(0.0, 0.05, len(X))
    res = fit(lambda z: (y - np.exp(z[0]) * np.exp(z[1]) * X) / 0.05,
              [Unknown("a", 1.0, (1e-3, 1e3), log=True), Unknown("c", 1.5, (1e-3, 1e3), log=True,
                                                                   prior=Prior(centre=1.5, sd=0.3))],
              segments=[slice(0, len(X))])
    assert res.values["c"] == pytest.approx(1.5, rel=0.01)
    assert res.values["a"] * res.values["c"] == pytest.approx(6.0, rel=0.01)
    assert res.stderr["c"] == pytest.approx(1.5 * 0.3, rel=0.05)     # the prior's width: the data add nothing


def test_correlated_noise_widens_the_interval():
    """A smooth error (as the clock's truncation gives the angle) is worth fewer independent samples."""
    rng = np.random.default_rng(4)
    white = rng.normal(0.0, 0.1, len(X))
    smooth = np.convolve(rng.normal(0.0, 0.1, len(X) + 19), np.ones(20) / np.sqrt(20), mode="valid")
    widths = {}
    for name, noise in (("white", white), ("smooth", smooth)):
        y = 2.0 * X + noise
        res = fit(lambda z: (y - z[0] * X) / 0.1, [Unknown("a", 1.0, (-10, 10))], segments=[slice(0, len(X))])
        widths[name] = res.stderr["a"]
        assert res.factors[0] >= 1.0
    assert widths["smooth"] > 2.0 * widths["white"]


def test_a_model_the_simulator_refuses_is_stepped_back_from():
    def residual(z):
        if z[0] > 3.0:
            return np.full(len(X), 1e3)       # what Problem gives for a refused model
        return (2.0 * X - z[0] * X) / 0.1
    res = fit(residual, [Unknown("a", 2.9, (0, 10))], segments=[slice(0, len(X))])
    assert res.values["a"] == pytest.approx(2.0, abs=1e-6)


def test_a_parameter_fitted_in_its_own_size_has_the_same_answer_and_standard_error():
    """A coefficient of 1e-4 fitted as value / 1e-4 (``Unknown.scale``, as discovery fits an effect's
    parameters): the values, standard errors and intervals are reported in the parameter's own units."""
    rng = np.random.default_rng(3)
    y = 3e-4 * X + 0.2 + rng.normal(0.0, 0.01, X.size)
    residual = lambda z: (y - z[0] * X - z[1]) / 0.01           # noqa: E731 (the values, not the internal x)
    plain = fit(residual, [Unknown("a", 1e-4, (-1.0, 1.0)), Unknown("b", 0.0, (-10, 10))], segments=[slice(0, 200)])
    scaled_unknowns = [Unknown("a", 1e-4, (-1.0, 1.0), scale=1e-4), Unknown("b", 0.0, (-10, 10))]
    scaled = fit(lambda z: residual([z[0] * 1e-4, z[1]]), scaled_unknowns, segments=[slice(0, 200)])
    assert scaled.values["a"] == pytest.approx(plain.values["a"], rel=1e-6)
    assert scaled.stderr["a"] == pytest.approx(plain.stderr["a"], rel=1e-3)
    assert scaled_unknowns[0].internal_bounds == (-1e4, 1e4)
    assert scaled.wald_interval("a")[0] < 3e-4 < scaled.wald_interval("a")[1]
