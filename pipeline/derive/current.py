"""The logged current in derive: the smoothing, its summary (RMS, noise, a stuck sensor) and whether the
energy can be integrated; one module for the stage with an encoder and the one without (``current_only``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.derive.energy import current_noise_a

# the logged current is de-noised within each phase before it is rectified (|I|, paper energy) or squared
# (copper loss), which would otherwise turn sensor noise into energy: cubic over 15 samples (0.75 s)
CURRENT_WINDOW, CURRENT_ORDER = 15, 3
CURRENT_NOTE = ("energy and trigger currents use current_smooth_a: the logged current smoothed within each phase "
                f"(cubic over {CURRENT_WINDOW} samples, never across a command change), because |I| and I^2 turn "
                "sensor noise into energy; energy_paper_logged_current_j is the paper's formula on the raw samples; "
                "phases' peak_current_a comes from one cubic through each phase's logged samples")
UNCERTAINTY_NOTE = ("one standard deviation from the current sensor's noise (current.noise_a), propagated "
                    "linearly; friction, spring and kinetic terms do not depend on the current")


STUCK_SAMPLES = 20      # a logged current that repeats one value this long (1 s at 50 ms) with the motor on


def current_summary(current: np.ndarray, smooth: np.ndarray, dirs: np.ndarray) -> dict[str, Any]:
    """RMS current over the motor-on samples (smoothed: the sensor noise would add in quadrature),
    the sensor noise, and whether the sensor looks stuck (one value repeated ``STUCK_SAMPLES`` with the
    motor on, which a live sensor's noise of about an ADC step never does)."""
    current = np.asarray(current, dtype=float)
    on = np.asarray(dirs) != 0
    finite = current[np.isfinite(current)]
    constant = bool(len(finite) >= 2 and np.ptp(finite) == 0)
    best, at = _longest_repeat(current, on)
    stuck = None
    if constant or best >= STUCK_SAMPLES:
        stuck = (f"current sensor stuck: current_a = {current[at]:.4g} A for {best} samples from sample {at} "
                 "with the motor on (a live sensor's noise changes it every few samples)")
    rms = float(np.sqrt(np.mean(smooth[on] ** 2))) if on.any() and not constant else None
    noise = current_noise_a(current, smooth, CURRENT_WINDOW, CURRENT_ORDER) if not constant else None
    return {"rms_a": rms, "noise_a": noise, "longest_repeat_samples": int(best), "constant": constant,
            "stuck": stuck}


def energy_refusal(t: np.ndarray, current: np.ndarray, stats: dict[str, Any]) -> str | None:
    """Why the run's energy cannot be integrated (``stats``: ``current_summary``'s), or None."""
    if len(t) < 2:
        return "fewer than 2 samples: no interval to integrate over"
    if stats["constant"]:
        return (f"current_a is {current[0]:.4g} A at every sample (a stuck or disconnected sensor): "
                "energy not computed")
    return None


def _longest_repeat(x: np.ndarray, on: np.ndarray) -> tuple[int, int]:
    """Length and first sample of the longest run of one repeated value (each repeat with ``on``)."""
    if len(x) == 0:
        return 0, 0
    same = (x[1:] == x[:-1]) & on[1:]
    # runs of True in ``same``: a run of r repeats is r + 1 equal samples
    edges = np.flatnonzero(np.diff(np.concatenate([[0], same.astype(np.int8), [0]])))
    if len(edges) == 0:
        return 1, 0
    starts, ends = edges[::2], edges[1::2]
    k = int(np.argmax(ends - starts))
    return int(ends[k] - starts[k] + 1), int(starts[k])
