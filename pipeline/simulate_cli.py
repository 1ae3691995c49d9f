"""``pdr simulate``: the rig's model alone, closed loop from rest (docs/FORMAT.md).

Not in ``pipeline.model``: the report is the model's run plus the derive
stage's energy balance, and the model package is what the stages import,
never the other way round.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Optional

import typer

from pipeline.errors import PdrError

MAX_SAMPLES = 5_000_000     # 69 h at the paper's 50 ms; the result's arrays ~0.5 GB


def simulate(
    config: Annotated[Optional[Path], typer.Option(
        "--config", help="Rig TOML (sections model, effects, drive, controller) layered over the built-in paper rig.",
        show_default=False)] = None,
    duration: Annotated[float, typer.Option(help="Simulated time in seconds, sampled every controller.period_s.")] = 24.95,
    json_out: Annotated[bool, typer.Option("--json", help="Print one JSON object instead of text.")] = False,
    guard: Annotated[str, typer.Option(
        help="'sampled' (the sketch: reverse at the next sample past the guard) or 'continuous' "
             "(reverse the instant theta reaches it).")] = "sampled",
) -> None:
    """Run the hybrid model from rest and report switches, angle extremes and energies.

    Example: pdr simulate --config raw/rig.toml --duration 24.95 --json
    """
    import json

    from pipeline.config import default_config, resolve_config

    if not (duration > 0.0 and math.isfinite(duration)):
        raise PdrError(f"expected a positive, finite duration in seconds, got {duration!r}", key="--duration")
    if guard not in ("sampled", "continuous"):
        raise PdrError(f"expected 'sampled' or 'continuous', got {guard!r}", key="--guard")
    cfg = resolve_config([config]) if config is not None else default_config()
    samples = duration / cfg.controller.period_s
    if samples > MAX_SAMPLES:       # refused before anything is allocated: each sample costs ~100 bytes
        raise PdrError(f"{duration:g} s at controller.period_s = {cfg.controller.period_s:g} s is {samples:.3g} "
                       f"samples; expected at most {MAX_SAMPLES:,} (a shorter --duration or a longer period)",
                       key="--duration")
    report = simulation_report(cfg, duration, guard)
    if json_out:
        typer.echo(json.dumps(report, indent=2, sort_keys=True))
    else:
        typer.echo(format_report(report))


def simulation_report(cfg, duration: float, guard: str = "sampled") -> dict:
    """What ``pdr simulate`` prints: closed loop from rest in q1 with the rig's model (a pure function)."""
    import numpy as np

    from pipeline.derive.energy import run_energy
    from pipeline.model.simulate import simulate as run

    spec = cfg.plant_spec()
    r = run(spec, duration=duration, guard=guard)
    energy = run_energy(r.t, r.current, r.omega, r.theta, r.dir, spec)
    return {
        "duration_s": round(float(r.t[-1]), 9),
        "samples": int(len(r.t)),
        "guard": guard,
        "guard_rad": float(spec.guard_rad),
        "effects": [e.to_json() for e in cfg.effects],
        "switches": r.switches,
        "switch_times_s": [round(float(v), 9) for v in r.switch_times],
        "theta_max": float(np.max(r.theta)),
        "theta_min": float(np.min(r.theta)),
        **{k: float(v) for k, v in energy.items()},
    }


def format_report(rep: dict) -> str:
    effects = ", ".join(f"{e['name']}({', '.join(f'{k}={v:g}' for k, v in e['parameters'].items())})"
                        for e in rep["effects"]) or "none"
    lines = [
        f"simulated {rep['duration_s']:.2f} s ({rep['samples']} samples, {rep['guard']} guard "
        f"+/-{rep['guard_rad']:.4f} rad), effects: {effects}",
        f"switches        {rep['switches']}",
        f"theta max/min   {rep['theta_max']:+.4f} / {rep['theta_min']:+.4f} rad",
        f"energy (paper)  {rep['energy_paper_j']:.3f} J",
    ]
    from pipeline.derive.energy import ENERGY_KEYS

    # the balance in its physical order: what went in, where it went, what is stored, what is left
    for key in ENERGY_KEYS[1:]:
        lines.append(f"  {key[:-2].replace('_', ' '):<24}{rep[key]:+.4f} J")
    return "\n".join(lines)
