"""A randomised virtual rig: a lab's own conventions and capture, drawn from everything the format allows.

``randomised_setup(rng)`` draws what one lab's rig and capture could look like
(a rig TOML may declare all of it), with 0-3 hidden effects from
``CATALOGUE`` or one effect outside it.  Discovery tuned on the paper's rig is
only worth something if it holds on these (issue 15).  The drawer walks
``CATALOGUE`` itself, so an effect added there is drawn with no change here;
``MAGNITUDES`` gives the range of each effect's parameter; a parameter missing
from it is drawn around its plug-in's ``typical`` value (``Param``: 0.5-1.5 times
its distance from ``absent``, on either side when it is signed), or, for an
effect class without ``PARAMS``, from the low fifth of its ``BOUNDS``.

Ranges, and why:

* sample period 10-100 ms (whole ms: the sketch waits on ``millis()``);
  supply 5-12 V; ACS712-05B/20A/30A (185/100/66 mV/A); encoder 11-64 lines per
  motor rev, decoded x1/x2/x4, on the paper's 102.08:1 gearbox;
* time printed as millis, micros or seconds, under the lab's own column
  names, with or without ``dir`` and with or without a header;
* the capture opens 0-10 s after the board started (mid-motion when that is
  past the motor-off pre-roll of 0-2 s), the first command is +1 or -1, a
  board reset in one run in five, up to 5 % of rows lost, current noise 1-4x
  one ADC step, counts by round or floor, 10 s to 5 min of logging
  (log-uniform: most labs log short runs), and any serial terminal's stamps.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pipeline.config import CurrentSensorConfig, EncoderConfig, default_config
from pipeline.model.effects import CATALOGUE, Effect, make_effect
from pipeline.model.params import ControllerParams, DriveParams
from pipeline.rig.recording import RigSetup
from pipeline.rig.serial import TERMINAL_STAMPS, Artefacts

GEARBOX = 102.08
ACS712_PARTS = {"ACS712-05B": 0.185, "ACS712-20A": 0.100, "ACS712-30A": 0.066}
ENCODER_LINES = (11, 12, 16, 32, 48, 64)
DECODING = (1, 2, 4)
ONE_ADC_STEP_V = 5.0 / 1024
# parameter -> (low, high) magnitude, drawn log-uniform; SIGNED ones take either sign
MAGNITUDES: dict[str, tuple[float, float]] = {
    "b": (2.5e-4, 7.7e-4), "Tc": (5e-4, 1.5e-3), "Vd": (0.4, 1.2), "gap": (0.03, 0.08), "Td": (0.02, 0.1),
    "I0": (0.06, 0.15), "Jr": (5e-4, 1.94e-3), "k_scale": (1.1, 1.35), "Tl": (8e-4, 2e-3),
}
SIGNED = {"I0", "Tl"}
SHRINKS = {"k_scale"}             # half the draws are 1/value (softer springs)
COLUMN_NAMES = {
    "t": {"ms": ("t_ms", "millis", "time", "t"), "us": ("t_us", "micros", "time_us", "t"),
          "s": ("t_s", "time", "seconds", "t")},
    "counts": ("counts", "enc", "ticks", "position", "encoder"),
    "adc": ("adc", "i_raw", "current_adc", "a0"),
    "dir": ("dir", "mode", "cmd", "direction"),
}
OUTSIDE = ("armature_resistance",)  # effects no catalogued one expresses
P_OUTSIDE = 0.12


@dataclass(frozen=True)
class Draw:
    """One randomised recording: the setup, what is hidden in it, and the conventions drawn (for reports)."""

    setup: RigSetup
    effects: tuple[Effect, ...]
    outside: str | None            # an effect outside the catalogue, or None
    conventions: dict

    @property
    def label(self) -> str:
        """What discovery should say: the effects' names joined by '+', 'clean', or 'outside:<what>'."""
        if self.outside:
            return f"outside:{self.outside}"
        return "+".join(e.name for e in self.effects) or "clean"


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _unlisted(cls: type[Effect], key: str, rng: np.random.Generator) -> float:
    """A parameter ``MAGNITUDES`` does not list: around the plug-in's typical value, else low in its bounds."""
    param = next((p for p in getattr(cls, "PARAMS", ()) if p.name == key), None)
    lo, hi = cls.BOUNDS[key]
    if param is None:
        return float(rng.uniform(lo + 0.05 * (hi - lo), lo + 0.2 * (hi - lo)))
    step = (param.typical - param.absent) * _log_uniform(rng, 0.5, 1.5)
    if param.signed and rng.random() < 0.5:
        step = -step
    return float(np.clip(param.absent + step, lo, hi))


def draw_effect(name: str, rng: np.random.Generator) -> Effect:
    """One catalogued effect with its parameters drawn from ``MAGNITUDES`` (or by ``_unlisted``)."""
    cls = CATALOGUE[name]
    params = {}
    for key in cls.UNITS:
        if key in MAGNITUDES:
            value = _log_uniform(rng, *MAGNITUDES[key])
            if key in SIGNED and rng.random() < 0.5:
                value = -value
            if key in SHRINKS and rng.random() < 0.5:
                value = 1.0 / value
        else:
            value = _unlisted(cls, key, rng)
        params[key] = value
    return make_effect(name, params, where="randomised")


def draw_effects(rng: np.random.Generator) -> tuple[tuple[Effect, ...], str | None]:
    """0-3 distinct catalogued effects (or one outside the catalogue), in the order drawn."""
    if rng.random() < P_OUTSIDE:
        return (), OUTSIDE[int(rng.integers(len(OUTSIDE)))]
    k = int(rng.choice(4, p=[0.2, 0.4, 0.25, 0.15]))
    names = [str(n) for n in rng.choice(sorted(CATALOGUE), size=k, replace=False)]
    return tuple(draw_effect(n, rng) for n in names), None


def _artefacts(rng: np.random.Generator, time_unit: str, dir_column: bool, rows: int,
               reset_after_s: float | None) -> Artefacts:
    names = (str(rng.choice(COLUMN_NAMES["t"][time_unit])), *(str(rng.choice(COLUMN_NAMES[k]))
                                                              for k in ("counts", "adc", "dir")))
    terminal = str(rng.choice(("", "", "ide", "ide2", *TERMINAL_STAMPS)))
    return Artefacts(
        header=bool(rng.random() < 0.85), column_names=names, dir_column=dir_column, time_unit=time_unit,
        ide_prefix={"ide": "classic", "ide2": "ide2"}.get(terminal, ""),
        terminal=terminal if terminal in TERMINAL_STAMPS else "", stamp_digits=int(rng.integers(0, 10)),
        crlf=bool(rng.random() < 0.3), bom=bool(rng.random() < 0.1), comments=int(rng.integers(0, 3)),
        blank_lines=int(rng.integers(0, 3)), garbled=int(rng.integers(0, 3)),
        dropped=int(rng.uniform(0.0, 0.05) * rows), reset_after_s=reset_after_s,
        reset_gap_s=float(rng.uniform(1.0, 60.0)))


def randomised_setup(rng: np.random.Generator) -> Draw:
    """One lab's rig, capture and hidden effects, drawn from ``rng`` (see the module docstring)."""
    base = default_config()
    period_s = int(rng.integers(10, 101)) / 1000.0
    part = str(rng.choice(sorted(ACS712_PARTS)))
    lines, decoding = int(rng.choice(ENCODER_LINES)), int(rng.choice(DECODING))
    config = replace(base,
                     encoder=EncoderConfig(counts_per_rev=round(lines * decoding * GEARBOX, 6)),
                     current_sensor=CurrentSensorConfig(sensitivity_v_per_a=ACS712_PARTS[part]),
                     drive=DriveParams(v_in=round(float(rng.uniform(5.0, 12.0)), 2)),
                     controller=ControllerParams(period_s=period_s, guard_rad=base.controller.guard_rad))
    duration_s = round(_log_uniform(rng, 10.0, 300.0), 2)
    pre_roll_s = round(float(rng.uniform(0.0, 2.0)), 2)
    open_after_s = round(float(rng.uniform(0.0, 10.0)), 2)
    rows = int(duration_s / period_s)
    reset = round(open_after_s + float(rng.uniform(0.3, 0.7)) * duration_s, 2) if rng.random() < 0.2 else None
    time_unit = str(rng.choice(("ms", "ms", "us", "s")))
    dir_column = bool(rng.random() < 0.8)
    art = _artefacts(rng, time_unit, dir_column, rows, reset)
    effects, outside = draw_effects(rng)
    plant_model = None
    if outside == "armature_resistance":         # a hot winding: Ra well above the datasheet value
        plant_model = base.model.with_(Ra=base.model.Ra * float(rng.uniform(1.4, 1.8)))
    rest_logged = pre_roll_s - open_after_s >= 0.5
    # a sensor offset is the zero a user wrote down being off (``sensors.calibrated_zero_v``); an "auto"
    # zero is measured from the data, so with one the hidden offset would not be in the recording
    offset_hidden = any(e.name == "current_sensor_offset" for e in effects)
    zero_v = "auto" if rest_logged and rng.random() < 0.3 and not offset_hidden else "calibrated"
    setup = RigSetup(effects=effects, config=config, duration_s=duration_s, pre_roll_s=pre_roll_s,
                     noise_v=float(rng.uniform(1.0, 4.0)) * ONE_ADC_STEP_V, zero_v=zero_v, artefacts=art,
                     seed=int(rng.integers(2**31)), open_after_s=open_after_s, first_dir=int(rng.choice((1, -1))),
                     counts_rounding=str(rng.choice(("round", "floor"))), plant_model=plant_model)
    conventions = {"period_s": period_s, "v_in": config.drive.v_in, "acs712": part,
                   "encoder": f"{lines} lines x{decoding}", "counts_per_rev": config.encoder.counts_per_rev,
                   "time_unit": time_unit, "columns": list(art.column_names), "dir": dir_column,
                   "header": art.header, "terminal": art.terminal or art.ide_prefix or "none",
                   "duration_s": duration_s, "pre_roll_s": pre_roll_s, "open_after_s": open_after_s,
                   "reset_after_s": reset, "dropped": art.dropped, "noise_x": setup.noise_v / ONE_ADC_STEP_V,
                   "counts_rounding": setup.counts_rounding, "first_dir": setup.first_dir, "zero_v": zero_v}
    return Draw(setup, effects, outside, conventions)
