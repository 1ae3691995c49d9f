"""The discovery matrices' protocol (docs/BENCHMARKS.md): a fresh seed unless one is asked for, said
so the run can be repeated, and a rate always with its 95 % interval."""

from __future__ import annotations

import secrets


def fresh_seed() -> int:
    """A seed nobody has tuned on: drawn from the operating system's randomness at each run."""
    return secrets.randbelow(2**31)


def seed_for_run(asked: int | None, what: str) -> int:
    """``asked`` (a repeated run), or a fresh seed; printed either way, with the option that repeats it."""
    seed = fresh_seed() if asked is None else asked
    how = "given" if asked is not None else "fresh"
    print(f"{what}: seed {seed} ({how}; repeat this run with --seed {seed})", flush=True)
    return seed


def rate_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) interval of a success rate: it covers the true rate at least
    ``confidence`` of the time whatever the rate, where the normal approximation undercovers near 100 %."""
    from scipy.stats import binomtest

    if trials == 0:
        return (0.0, 1.0)
    ci = binomtest(successes, trials).proportion_ci(confidence_level=confidence, method="exact")
    return (float(ci.low), float(ci.high))


def rate_text(successes: int, trials: int) -> str:
    """``"k of n (r %, 95 % interval lo-hi %)"``."""
    if trials == 0:
        return "0 of 0"
    low, high = rate_interval(successes, trials)
    share = 100.0 * successes / trials
    return f"{successes} of {trials} ({share:.1f} %, 95 % interval {100 * low:.1f}-{100 * high:.1f} %)"
