"""The rig's sensor chain (docs/MODEL.md, Sec. III-C): what the Arduino turns the true states into.

Pure functions from true signals (and a numpy Generator) to what the sketch
prints: ``millis()`` stamps, integer encoder counts, the ACS712 voltage and its
10-bit ADC reading.  Choices, and why:

* Loop timing: the sketch waits for ``millis() - last >= 50``, so each loop
  takes the period plus a sub-millisecond overrun (uniform in
  [0, jitter_ms), jitter_ms < 1).  The controller acts at those true instants;
  the printed ``millis()`` is their floor, so consecutive stamps differ by
  exactly 50 or 51 ms.
* Encoder: an ideal quadrature counter, count = round(theta * cpr / 2 pi)
  relative to the angle at power-up (the counter starts at 0 there).
* Current: v = v_zero_part + S*I + noise, v_zero_part = 2.5 V + N(0, ~15 mV)
  per part; the ADC reads floor(v * 1024 / 5 V) clipped to 0..1023, like the
  AVR's successive-approximation converter.
* The zero a user writes in the TOML ("calibrated") is what averaging
  ``analogRead`` at rest gives: the part's zero minus half an ADC step (the
  floor), and -- for a hidden ``current_sensor_offset`` -- wrong by I0*S.
"""

from __future__ import annotations

import math

import numpy as np

NOMINAL_ZERO_V = 2.5            # V  Vcc/2, the ACS712 datasheet zero
COUNT_ROUNDING = ("round", "floor")


def loop_instants(n: int, period_s: float, jitter_ms: float, rng: np.random.Generator,
                  start_ms: float) -> tuple[np.ndarray, np.ndarray]:
    """True loop instants [ms since boot, float] and the ``millis()`` the sketch prints [int].

    Each loop lasts period + U(0, jitter_ms); with jitter_ms < 1 ms the printed
    stamps step by 50 or 51 ms only.
    """
    if not 0.0 <= jitter_ms < 1.0:
        raise ValueError(f"jitter_ms must be in [0, 1) so stamps step by 50 or 51 ms, got {jitter_ms}")
    steps = period_s * 1000.0 + rng.uniform(0.0, jitter_ms, size=max(n - 1, 0))
    true_ms = start_ms + np.concatenate([[0.0], np.cumsum(steps)])
    return true_ms, np.floor(true_ms).astype(np.int64)


def encoder_counts(theta: np.ndarray, counts_per_rev: float, theta_ref: float = 0.0,
                   rounding: str = "round") -> np.ndarray:
    """Quadrature count since power-up at ``theta_ref``: round(theta * cpr / 2 pi) - round(theta_ref * cpr / 2 pi).

    ``rounding="floor"``: the counter reads the edges passed (floor), as a counter whose
    zero sits on an edge does; the two differ by half a count of bias in theta.
    """
    scale = counts_per_rev / (2.0 * math.pi)
    half = 0.5 if rounding == "round" else 0.0
    edges = np.floor(np.asarray(theta) * scale + half).astype(np.int64)
    return edges - int(math.floor(theta_ref * scale + half))


def part_zero_v(zero_sigma_v: float, rng: np.random.Generator) -> float:
    """This ACS712 part's output at 0 A: Vcc/2 plus a per-part error."""
    return NOMINAL_ZERO_V + float(rng.normal(0.0, zero_sigma_v)) if zero_sigma_v > 0 else NOMINAL_ZERO_V


def acs712_volts(current_a: np.ndarray, zero_v: float, sensitivity_v_per_a: float, noise_v: float,
                 rng: np.random.Generator) -> np.ndarray:
    """The sensor output: v = v_zero + S*I + white noise of sigma noise_v."""
    v = zero_v + sensitivity_v_per_a * np.asarray(current_a, dtype=float)
    if noise_v > 0:
        v = v + rng.normal(0.0, noise_v, size=v.shape)
    return v


def adc_read(volts: np.ndarray, vref: float, steps: int) -> np.ndarray:
    """``analogRead``: floor(v * steps / vref), clipped to 0..steps-1 (saturation at the rails)."""
    codes = np.floor(np.asarray(volts) * steps / vref)
    return np.clip(codes, 0, steps - 1).astype(np.int64)


def calibrated_zero_v(part_zero: float, sensitivity_v_per_a: float, offset_a: float,
                      vref: float, steps: int) -> float:
    """The zero_v a user measures at rest and writes down (0.1 mV resolution).

    Averaging floor-quantised readings gives the part's zero minus half a step;
    a sensor offset I0 (docs/MODEL.md ``current_sensor_offset``) means the
    written zero is off by I0*S, so the pipeline reads I + I0.
    """
    return round(part_zero - 0.5 * vref / steps - offset_a * sensitivity_v_per_a, 4)
