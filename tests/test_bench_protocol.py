"""The discovery matrices' protocol (docs/BENCHMARKS.md): a rate's exact interval, and a fresh seed unless
one is asked for."""

import pytest

from benchmarks.protocol import rate_interval, rate_text, seed_for_run


def test_the_interval_is_clopper_pearsons():
    # closed forms at the ends: k = 0 -> [0, 1 - (a/2)^(1/n)], k = n -> [(a/2)^(1/n), 1]
    assert rate_interval(0, 10) == pytest.approx((0.0, 1 - 0.025 ** 0.1))
    assert rate_interval(120, 120) == pytest.approx((0.025 ** (1 / 120), 1.0))
    low, high = rate_interval(296, 300)
    assert low < 296 / 300 < high and high - low < 0.04
    assert rate_interval(3, 4)[0] < 0.2                       # four draws say little, and the interval says so


def test_the_rate_is_said_with_its_interval():
    assert rate_text(296, 300) == "296 of 300 (98.7 %, 95 % interval 96.6-99.6 %)"
    assert rate_text(0, 0) == "0 of 0"


def test_a_seed_is_fresh_unless_given_and_printed_either_way(capsys):
    assert seed_for_run(15, "matrix") == 15
    assert "seed 15 (given; repeat this run with --seed 15)" in capsys.readouterr().out
    fresh = {seed_for_run(None, "matrix") for _ in range(5)}
    printed = capsys.readouterr().out
    assert len(fresh) > 1 and all(f"repeat this run with --seed {s})" in printed for s in fresh)
