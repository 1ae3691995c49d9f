"""Rigs that differ from Table I, as a lab's own rig would: recordings for calibration (tests, benchmark).

Each rig is the paper's rig with its own motor, gearbox, inertia, friction and springs, drawn at
random (log-uniform within a stated factor of Table I, keeping the guard reachable).  The TOML the
user has does not declare ``[model]`` (a user who has not calibrated does not know it).  Per rig:

- ``cal_a``, ``cal_b``: two clean recordings to calibrate on (different seeds and first commands);
- ``clean``: a third clean recording (discovery should say ``none`` once calibrated);
- ``hidden``: a fourth with one catalogued effect hidden (discovery should name it).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pipeline.config import default_config
from pipeline.model.effects import Effect
from pipeline.model.params import ModelParams
from pipeline.rig.randomised import draw_effect
from pipeline.rig.recording import RigSetup, make_recording, write_recording

# How far each base parameter may sit from Table I (a factor, log-uniform both ways).
SPREAD = {"Ra": 1.6, "Ke": 1.4, "Kt": 1.4, "La": 1.6, "J": 1.5, "b": 1.8, "K": 1.4}
# Effects hidden in the fourth recording: those no base parameter stands for.
HIDDEN = ("coulomb_friction", "driver_voltage_drop", "backlash", "loop_delay", "current_sensor_offset",
          "constant_load_torque")
ROLES = ("cal_a", "cal_b", "clean", "hidden")

@dataclass(frozen=True)
class OffRig:
    index: int
    model: ModelParams
    hidden: Effect

    def setup(self, role: str, seed: int, duration_s: float = 24.95) -> RigSetup:
        effects = (self.hidden,) if role == "hidden" else ()
        return RigSetup(effects=effects, config=default_config(), plant_model=self.model, seed=seed,
                        first_dir=-1 if role == "cal_b" else 1, duration_s=duration_s)

def _factor(rng: np.random.Generator, spread: float) -> float:
    return float(np.exp(rng.uniform(-np.log(spread), np.log(spread))))

def draw_rig(index: int, rng: np.random.Generator) -> OffRig:
    """One rig off Table I whose controller still reaches the guard with margin."""
    base = ModelParams()
    while True:
        k = base.K1 * _factor(rng, SPREAD["K"])
        model = base.with_(Ra=base.Ra * _factor(rng, SPREAD["Ra"]), Ke=base.Ke * _factor(rng, SPREAD["Ke"]),
                           Kt=base.Kt * _factor(rng, SPREAD["Kt"]), La=base.La * _factor(rng, SPREAD["La"]),
                           J=base.J * _factor(rng, SPREAD["J"]), b=base.b * _factor(rng, SPREAD["b"]),
                           K1=k, K2=k)
        if model.static_gain() * 6.0 > 3.0 * default_config().controller.guard_rad:
            break
    return OffRig(index=index, model=model, hidden=draw_effect(HIDDEN[index % len(HIDDEN)], rng))

def write_rig(rig: OffRig, out: Path, seed: int, roles: tuple[str, ...] = ROLES,
              duration_s: float = 24.95) -> dict[str, Path]:
    """The rig's four recordings as ``rig<i>_<role>.csv`` with TOMLs that do not declare ``[model]``."""
    paths = {}
    for role in roles:
        name = f"rig{rig.index}_{role}"
        rec = make_recording(rig.setup(role, seed * 10 + ROLES.index(role), duration_s))
        rec = replace(rec, toml_text=re.sub(r"\n\[model\]\n(?:[^\[\n][^\n]*\n)*", "\n", rec.toml_text))
        write_recording(rec, out, name)
        paths[role] = out / f"{name}.csv"
    return paths

def rigs(seed: int, count: int = 6) -> list[OffRig]:
    rng = np.random.default_rng(seed)
    return [draw_rig(i, rng) for i in range(count)]


def truth_of(rig: OffRig) -> dict[str, float]:
    return {name: float(getattr(rig.model, name)) for name in ModelParams.names()}

