"""Switches whose sample the data leave open (``estimate.switch_timing``), settled under a model
(``settled``), again under the effects found (``search.select``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.discover.measurement import Measurement
from pipeline.discover.residuals import noise_floor, residuals
from pipeline.estimate.switch_timing import Timing, inferred_on_guard, lost_on_guard, pattern_misfit, settle
from pipeline.model.effects import Effect


def _half_count(meas: Measurement) -> float:
    return np.pi / meas.config.encoder.counts_per_rev


def ambiguous_switches(meas: Measurement) -> list[int]:
    """Samples where an inferred command may be off by one sample (``switch_timing.inferred_on_guard``)."""
    if meas.dir_source != "inferred":
        return []
    return inferred_on_guard(meas.dir, meas.theta, float(meas.config.controller.guard_rad), _half_count(meas))


def ambiguous_lost_reversals(meas: Measurement) -> list[int]:
    """Logged samples after whose gap of lost rows a reversal or the motor's start is open
    (``switch_timing.lost_on_guard``)."""
    if meas.dir_source != "logged":
        return []
    return lost_on_guard(meas.t, meas.dir, meas.theta, float(meas.config.controller.guard_rad), _half_count(meas))


def ambiguous(meas: Measurement) -> bool:
    return bool(ambiguous_switches(meas) or ambiguous_lost_reversals(meas))


def timing(meas: Measurement) -> bytes:
    """The switches' timing a measurement replays (a key: the commands and the lost rows' moved switches)."""
    return Timing(meas.dir, meas.lost_shifts).key()


def settled(meas: Measurement, effects: tuple[Effect, ...]) -> Measurement:
    """The open switches settled under ``effects`` (``switch_timing.settle``, judged by ``pattern_misfit``)."""
    spec = meas.spec(effects)
    floor = noise_floor(meas)

    def misfit(tm: Timing) -> float:
        m = replace(meas, dir=tm.dir, lost_shifts=tm.shifted)
        return pattern_misfit(residuals(m, m.replay(spec)), floor)

    if meas.dir_source not in ("logged", "inferred"):
        return meas
    tm = settle(Timing(meas.dir, meas.lost_shifts), t=meas.t, theta=meas.theta,
                guard=float(meas.config.controller.guard_rad), half_count=_half_count(meas),
                inferred=meas.dir_source == "inferred", misfit=misfit)
    return meas if tm.key() == timing(meas) else replace(meas, dir=tm.dir, lost_shifts=tm.shifted)
