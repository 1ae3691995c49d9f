"""``discovery.rrd``: the measurement against the base and the augmented model, in the viewer.

The same rows as a run's recording (``validate.rerun_log``): each signal with its
residual before and after beside it, the guards and the command lane, the phase
portrait before (base model) and after (augmented model), and the Markdown
report beside them.  Layout: ``validate.rerun_blueprint.discovery_blueprint``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.discover.stage import Discovery
from pipeline.io.atomic import atomic_path
from pipeline.validate.palette import DISCOVERY_RGB as COLORS
# signal -> (kinematics column, SimResult field)
_SIGNALS = {"theta": ("theta_rad", "theta"), "omega": ("omega_rad_s", "omega"),
            "current": ("current_a", "current_measured")}


def _measured(d: Discovery, name: str) -> np.ndarray | None:
    kin = d.meas.kinematics
    return kin[name].to_numpy(dtype=float, na_value=np.nan) if name in kin.columns else None


def log_discovery(rec, d: Discovery, report_md: str, guard: float, way: str = "replay") -> None:
    """Log one discovery into an open recording stream (no file handling here)."""
    import rerun as rr

    from pipeline.validate.rerun_log import TIMELINE, log_guards, log_mode_lane, log_signal, portrait_strips
    from pipeline.validate.rerun_phase import log_phase_portrait

    t = d.meas.t
    every = rr.TimeColumn(TIMELINE, duration=t)
    models = {"base model": d.base[way]}
    if d.effects:
        models["augmented model"] = d.final[way]
    for sig, (column, field) in _SIGNALS.items():
        y = _measured(d, column)
        lines = {label: (getattr(sim, field), COLORS[label], 1.5) for label, sim in models.items()}
        if y is not None:
            lines["measured"] = (y, COLORS["measured"], 1.5)
        log_signal(rec, f"signals/{sig}", every, lines)
        if y is not None:
            log_signal(rec, f"residuals/{sig}", every, {
                # the base model's residual wide under the augmented one's: both show where they agree
                "before": (y - getattr(d.base[way], field), COLORS["base model"], 3.0),
                "after": (y - getattr(d.final[way], field), COLORS["augmented model"], 1.2)})
    log_guards(rec, "signals/theta/guards", t, guard)
    log_mode_lane(rec, f"mode/{d.meas.dir_source}", t, d.meas.dir)
    kin = d.meas.kinematics
    log_phase_portrait(rec, "trajectory_before", portrait_strips(kin, {"base model": (d.base[way],
                                                                                      COLORS["base model"])}), guard)
    after = ("augmented model", d.final[way]) if d.effects else ("base model (nothing added)", d.base[way])
    log_phase_portrait(rec, "trajectory_after", portrait_strips(kin, {after[0]: (after[1], COLORS["augmented model"])}),
                       guard)
    rec.log("report", rr.TextDocument(report_md, media_type=rr.MediaType.MARKDOWN), static=True)


def write_rrd(target: Path, d: Discovery, report_md: str, way: str = "replay") -> None:
    """Saved atomically and checked with ``rerun rrd verify``."""
    from pipeline.validate.rerun_blueprint import axis_ranges, discovery_blueprint
    from pipeline.validate.rerun_io import blueprint_chunks, verify_rrd, write_recording
    from pipeline.validate.rerun_log import residual_ranges, theta_band

    guard = d.meas.config.plant_spec().guard_rad
    sims = {"base": d.base[way], "final": d.final[way]}
    ranges = axis_ranges(discovery_blueprint, theta_band(d.meas.kinematics, sims, guard),
                         residual_ranges(d.meas.kinematics, sims.values()))
    with atomic_path(Path(target)) as tmp:
        write_recording(tmp, f"discover-{d.meas.name}", blueprint_chunks(discovery_blueprint),
                        lambda rec: log_discovery(rec, d, report_md, guard, way), application_id="pdr-discover",
                        y_ranges=ranges)
        verify_rrd(tmp)
