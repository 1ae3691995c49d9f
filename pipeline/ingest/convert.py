"""Raw counts, ADC steps and commands -> SI units, raw values kept beside them (pure).

Equations (MODEL.md, paper's rig):
  theta [rad] = 2*pi*counts / counts_per_rev          (6533.12 counts/rev: 64 CPR x4 x 102.08)
  v [V]       = adc * adc_vref / adc_steps             (UNO: 5.0 V / 1024 steps, ~4.9 mV/step)
  I [A]       = (v - zero_v) / sensitivity_v_per_a     (ACS712-05B: 0.185 V/A, zero near 2.5 V)
  mode        = 1 (q1) for dir = 1, 2 (q2) for dir = -1, 0 (motor off) for dir = 0
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.config import RigConfig
from pipeline.errors import IngestError
from pipeline.ingest.timing import COUNTER_RANGE, UNIT_S

MIN_REST_SAMPLES = 3          # fewest samples at rest that give a zero estimate worth reporting
REST_TRIM = 4.0               # robust sigmas (at least one ADC step) of the rest readings kept for the zero
_MAD = 0.6744897501960817     # median |N(0,1)|


@dataclass(frozen=True)
class ZeroEstimate:
    zero_v: float
    spread_v: float           # standard deviation of the rest samples' voltage
    samples: int              # the rest readings averaged
    method: str               # "configured", "motor off before first driven[, pinion still]", "before the encoder first moves"
    standard_error_v: float = 0.0    # of zero_v (0 when configured: a user's number is taken as exact)

    def to_dict(self) -> dict:
        return {"zero_v": self.zero_v, "spread_v": self.spread_v, "samples": self.samples, "method": self.method,
                "standard_error_v": self.standard_error_v}


def range_violations(values: dict[str, np.ndarray], cfg: RigConfig) -> tuple[np.ndarray, dict[int, str]]:
    """Mask of rows breaking a range rule, and the first rule each of those rows breaks (by row index).

    Each rule is an interval, so a column whose minimum and maximum keep it breaks it nowhere:
    two reductions per column settle the common case without a mask per rule.
    """
    n = len(values["t_raw"])
    span = COUNTER_RANGE[cfg.columns.time_unit]
    rules = [("t_raw", (lambda t: (t < 0) | (t >= span)) if span else (lambda t: t < 0),
              f"time outside 0..{int(span) - 1 if span else 'inf'} {cfg.columns.time_unit}")]
    if "adc" in values:
        steps = cfg.current_sensor.adc_steps
        rules.append(("adc", lambda a: (a < 0) | (a >= steps),
                      f"adc outside 0..{steps - 1} (current_sensor.adc_steps = {steps})"))
    if "dir" in values:
        rules.append(("dir", lambda d: (d < -1) | (d > 1), "dir not -1, 0 or 1"))
    bad = np.zeros(n, dtype=bool)
    reason: dict[int, str] = {}
    for name, breaks, text in rules:
        x = values[name]
        ends = np.array([x.min(), x.max()]) if n else x
        if not (breaks(ends).any() or np.isnan(ends.astype(np.float64)).any()):
            continue                    # both ends inside the interval (and no NaN): every row is
        mask = breaks(x)
        for i in np.flatnonzero(mask & ~bad):
            reason[int(i)] = text
        bad |= mask
    return bad, reason


def at_rest(values: dict[str, np.ndarray]) -> tuple[np.ndarray, str]:
    """Samples with no armature current: the motor-off samples before the motor is first driven, where
    the pinion stands still over them; else the ones before the encoder first moves.

    The winding's current decays over La/Ra (7 s on Table I's motor), so a motor-off sample after a
    driven one still carries it, and so does a segment that opens after a board reset with the pinion
    still moving (the springs push it back against the decaying current for seconds: ~0.1 A on a
    virtual rig, two steps of the 20 A part's ADC).  A pinion that moves more than a count with the motor
    off says the winding is not at rest: that segment has no rest samples.  Without ``dir``, the
    encoder standing still at its first value means the motor has not been driven yet.
    """
    if "dir" in values:
        d = values["dir"]
        driven = np.flatnonzero(d != 0)
        first = int(driven[0]) if len(driven) else len(d)
        rest = np.zeros(len(d), dtype=bool)
        c = values.get("counts")
        if c is None or first == 0 or int(c[:first].max()) - int(c[:first].min()) <= 1:
            rest[:first] = True
        return rest, "motor off before first driven, pinion still" if c is not None else "motor off before first driven"
    if "counts" not in values:
        return np.zeros(len(values["adc"]), dtype=bool), "dir == 0 or the encoder standing still, neither logged"
    counts = values["counts"]
    moved = np.flatnonzero(counts != counts[0])
    first = moved[0] if len(moved) else len(counts)
    mask = np.zeros(len(counts), dtype=bool)
    mask[:max(first - 1, 0)] = True          # the sample just before the first move may already carry current
    return mask, "before the encoder first moves"


def estimate_zero(values: dict[str, np.ndarray], cfg: RigConfig, source: str) -> ZeroEstimate:
    cs = cfg.current_sensor
    if cs.zero_v != "auto":
        return ZeroEstimate(float(cs.zero_v), 0.0, 0, "configured")
    volts = values["adc"] * volts_per_step(cfg)
    rest, method = at_rest(values)
    if rest.sum() < MIN_REST_SAMPLES:
        raise IngestError(f"current_sensor.zero_v = \"auto\" needs at least {MIN_REST_SAMPLES} samples at rest "
                          f"({method}), found {int(rest.sum())}; log a motor-off pre-roll or set zero_v in volts",
                          path=source, key="current_sensor.zero_v")
    kept = trimmed(volts[rest], volts_per_step(cfg))
    return ZeroEstimate(float(np.mean(kept)), float(np.std(kept)), len(kept), method,
                        standard_error_v=float(np.std(kept) / np.sqrt(len(kept))))


def trimmed(v: np.ndarray, step: float) -> np.ndarray:
    """The readings within ``REST_TRIM`` robust sigmas of their median, whose mean is the zero: robust
    to a garbled reading, as the median is, but neither rounded to a whole ADC step, as the median of
    integer codes is (a step of the 20 A part is 49 mA), nor blind to the noise's dithering between
    codes, as a mean of the middle half is (with half a step to two steps of noise its error was
    1.1 to 3 times the mean's).  The robust sigma is at least a step: most rest codes may be one value."""
    v = np.asarray(v, dtype=float)
    centre = float(np.median(v))
    scale = max(float(np.median(np.abs(v - centre))) / _MAD, step)
    return v[np.abs(v - centre) <= REST_TRIM * scale]


def rad_per_count(cfg: RigConfig) -> float:
    return 2.0 * np.pi / cfg.encoder.counts_per_rev


def volts_per_step(cfg: RigConfig) -> float:
    return cfg.current_sensor.adc_vref / cfg.current_sensor.adc_steps


def amps(volts: np.ndarray, zero_v: float, cfg: RigConfig) -> np.ndarray:
    current = volts - zero_v
    current /= cfg.current_sensor.sensitivity_v_per_a    # in place: the same rounding as (volts - zero) / sensitivity
    return current


def to_signals(values: dict[str, np.ndarray], line: np.ndarray, t_s: np.ndarray, segment: int,
               cfg: RigConfig, zero: ZeroEstimate | None) -> pd.DataFrame:
    """The ``signals`` table of one segment; columns a sketch does not log stay absent (counts and
    theta_rad too, for a capture without an encoder).

    ``plain_kernel.signal_rows`` computes the same columns row by row for large plain captures:
    what changes here changes there (tests hold the two to the same bits).
    """
    cols: dict[str, np.ndarray] = {
        "t_s": t_s,
        "t_raw": np.asarray(values["t_raw"], dtype=np.float64),
        "line": np.asarray(line, dtype=np.int64),
        "segment": np.full(len(line), segment, dtype=np.int32),
    }
    if "counts" in values:
        cols |= {"counts": np.asarray(values["counts"], dtype=np.int64), "theta_rad": values["counts"] * rad_per_count(cfg)}
    if "adc" in values and zero is not None:
        volts = values["adc"] * volts_per_step(cfg)
        cols |= {"adc": values["adc"].astype(np.int32), "current_v": volts, "current_a": amps(volts, zero.zero_v, cfg)}
    if "dir" in values:
        d = values["dir"].astype(np.int8)
        cols |= {"dir": d, "mode": d + np.int8(3) * (d < 0)}     # dir -1, 0, 1 -> mode 2, 0, 1
    return pd.DataFrame(cols, copy=False)


def seconds_from_start(t_unwrapped: np.ndarray, unit: str) -> np.ndarray:
    t_s = t_unwrapped - t_unwrapped[0]
    t_s *= UNIT_S[unit]                         # in place: one 8 MB array per million rows instead of two
    return t_s


def saturation(adc: np.ndarray, steps: int) -> dict:
    """Samples pinned at either end of the ADC range (current beyond what the ADC can show)."""
    return {"low": int(np.count_nonzero(adc == 0)), "high": int(np.count_nonzero(adc == steps - 1)),
            "samples": int(len(adc))}
