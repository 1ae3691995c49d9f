"""The noise of each logged signal, from the recording itself (no model, no rig settings).

A signal sampled every 50 ms is smooth at the sample scale (the rig's oscillation turns at
~2-3 rad/s, so a k-th difference shrinks it by about (0.15)^k), while white noise grows under
differencing by a known factor: the k-th difference of noise of variance s^2 has variance
C(2k, k) s^2.  So the k-th difference's mean square, divided by C(2k, k), is the variance of
the white part, taken over the differences within ``TRIM`` robust sigmas (median absolute
deviation) of their median: blind to the few kinks at the controller's switches, but a mean, not
the median itself, whose scale reads quantised noise (a few distinct ADC codes) 13 % off on
average against the virtual rig's truth over 60 randomised draws (the trimmed mean: 5 %), and
the current's floor is what a sensor offset of a third of a noise sigma is measured against.
The order is the signal's: the current is noisy and kinked at every switch, where a low order
spreads each kink over fewer differences (against the virtual rig's true noise variance over 18
recordings, 1-4x noise, 185/100/66 mV/A: order 3 read 0.97 of it with a spread of 0.13, order 4
0.96 with 0.20); the angle is nearly noiseless
and swings fast, so its smooth part must cancel (at a 100 ms period order 3 read 50 times the
encoder's quantisation, order 5 twice).

Quantised data (encoder counts, 10-bit ADC codes) cannot be fitted better than the
quantisation error, q^2 / 12, whatever the difference says (with noise below one step a
difference is mostly 0).  The step q is read off the data too: the gap between
neighbouring distinct values of which every other gap is a whole multiple.
"""

from __future__ import annotations

from math import comb

import numpy as np

CURRENT_ORDER = 3
ANGLE_ORDER = 5
TRIM = 4.0                          # robust sigmas of the differences kept for the current's mean square
_MAD = 0.6744897501960817          # median |N(0,1)|


def difference_noise(y: np.ndarray, order: int = CURRENT_ORDER, trim: float | None = TRIM) -> float:
    """Variance of the white part of ``y``: mean square of its ``order``-th difference within
    ``trim`` robust sigmas (None: the robust scale itself, for the angle, whose smooth part leaks
    into a mean square at a long sample period).

    Only runs of finite samples are differenced, so a missing value costs its
    neighbours rather than poisoning the estimate.
    """
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(y)
    d = np.diff(np.where(ok, y, 0.0), n=order)
    valid = np.convolve(ok.astype(float), np.ones(order + 1), mode="valid") == order + 1
    d = d[valid]
    if len(d) < 3:
        return 0.0
    centre = np.median(d)
    sigma = np.median(np.abs(d - centre)) / _MAD
    if trim is not None:
        kept = d[np.abs(d - centre) <= trim * sigma]
        return float(np.mean(kept * kept) / comb(2 * order, order)) if len(kept) >= 3 else 0.0
    return float(sigma * sigma / comb(2 * order, order))


def quantum(y: np.ndarray) -> float:
    """The step of quantised data (0 when the values are not on a grid).

    The smallest gap between distinct values is a candidate step; the data are on
    its grid when (nearly) every gap is a whole number of it.  A fast signal skips
    values (an encoder moving several counts per sample), which leaves the gaps
    multiples of the step; unquantised values have gaps in no such ratio.
    """
    v = np.unique(np.asarray(y, dtype=float)[np.isfinite(y)])
    if len(v) < 3:
        return 0.0
    gaps = np.diff(v)
    scale = float(np.max(np.abs(v)))
    gaps = gaps[gaps > scale * 1e-12]                      # float noise of unit conversions
    if len(gaps) < 2:
        return 0.0
    ratio = gaps / gaps.min()
    whole = np.abs(ratio - np.round(ratio)) < 1e-3
    if np.mean(whole) < 0.95:
        return 0.0
    return float(np.median(gaps[whole & (np.round(ratio) == 1)]))


def signal_noise(y: np.ndarray, order: int = CURRENT_ORDER, trim: float | None = TRIM) -> float:
    """Per-sample noise variance of a logged signal: its white part, at least its quantisation."""
    q = quantum(y)
    return max(difference_noise(y, order, trim), q * q / 12.0)


def angle_noise(theta: np.ndarray, omega: np.ndarray, t: np.ndarray) -> float:
    """The angle's noise variance: its own (``ANGLE_ORDER``) plus the clock's truncation."""
    return signal_noise(theta, ANGLE_ORDER, trim=None) + timing_noise(omega, t)


def clock_step(t: np.ndarray) -> float:
    """The logged clock's step [s], read off the stamps: the smallest difference between distinct
    sample intervals (millis() stamps step by 50 or 51 ms: 1 ms; micros(): 1 us).  Intervals that
    are all equal show no truncation at all (a schedule, not a clock): 0."""
    intervals = np.unique(np.round(np.diff(np.asarray(t, dtype=float)), 9))
    return float(np.diff(intervals).min()) if len(intervals) > 1 else 0.0


def sample_instants(t: np.ndarray) -> np.ndarray:
    """The instants the samples were taken at, as well as the stamps tell: a clock that truncates
    (millis()) stamps an instant somewhere in [stamp, stamp + step), half a step later on average,
    so the model is sampled there (a velocity times that mean lag would otherwise be structure)."""
    t = np.asarray(t, dtype=float)
    return t + clock_step(t) / 2.0


def timing_noise(omega: np.ndarray, t: np.ndarray) -> float:
    """Angle error from the clock's truncation about ``sample_instants``: w * U(-step/2, step/2),
    variance w^2 step^2 / 12."""
    w = np.asarray(omega, dtype=float)
    w = w[np.isfinite(w)]
    step = clock_step(t)
    return float(np.mean(w * w)) * step * step / 12.0 if len(w) else 0.0
