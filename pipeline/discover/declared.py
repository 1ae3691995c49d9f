"""Over-declared effects: what ``pdr discover`` reports as ``declared_too_large`` beside an
``unexplained`` verdict with nothing named."""

from __future__ import annotations

from dataclasses import replace

from scipy.optimize import minimize_scalar

from pipeline.discover.candidates import Evaluator, make, parameter_of, value_of
from pipeline.discover.measurement import Measurement
from pipeline.discover.policy import DiscoveryPolicy
from pipeline.model.effects import CATALOGUE


def check_declared(meas: Measurement, floor: dict[str, float], policy: DiscoveryPolicy) -> list[dict]:
    """When nothing can be added, is something the rig declares too large?

    Effects only add, so an over-declared effect (a TOML loop delay the rig does not have,
    a friction smaller than written) cannot be "found".  Each declared effect, and the
    [model] friction b, is refitted between none and its declared value; the ones that
    then leave no structure (``policy.structure_floors``) are reported (``pdr discover`` never edits them).
    """
    cfg = meas.config
    declared: list[tuple[str, str, float]] = [(e.name, parameter_of(e.name), value_of(e)) for e in cfg.effects]
    if cfg.model.b > 0:
        declared.append(("model.b", "b", cfg.model.b))
    out = []
    for name, param, value in declared:
        absent = 0.0 if name == "model.b" else CATALOGUE[name].PARAMS[0].absent

        def with_value(v: float, name=name):
            if name == "model.b":
                return replace(cfg, model=cfg.model.with_(b=v))
            return replace(cfg, effects=tuple(make(e.name, v) if e.name == name else e for e in cfg.effects))

        def loss(v: float) -> float:
            trial = replace(meas, config=with_value(v))
            return Evaluator(trial, floor).nll(trial.replay(trial.spec()))

        res = minimize_scalar(loss, bounds=(min(absent, value), max(absent, value)), method="bounded",
                              options={"xatol": 1e-3 * abs(value - absent), "maxiter": 20})
        trial = replace(meas, config=with_value(float(res.x)))
        ev = Evaluator(trial, floor)
        left = {s: m / floor[s] - 1.0 for s, m in ev.mse(trial.replay(trial.spec())).items()}
        if max(left.values()) <= policy.structure_floors:
            out.append({"name": name, "parameter": param, "declared": value, "fitted": float(res.x),
                        "structure_left": left})
    return out
