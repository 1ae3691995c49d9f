"""Calibration's outputs: ``calibration.json`` (the ``--json`` object), ``calibration.md`` (per
parameter with its prior), ``model.toml`` (the ``[model]`` table to adopt) and ``calibration.rrd``
(each recording against the model before and after, in the Rerun viewer)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.calibrate.stage import MODEL_KEYS, Calibration
from pipeline.calibrate.structure import CONVENTION, UNITS
from pipeline.io.atomic import atomic_path, write_json, write_text

COLORS = {"measured": (90, 90, 90), "before (prior)": (230, 120, 0), "after (calibrated)": (0, 120, 220)}
SIGNALS = {"theta": ("theta_rad", "theta", "rad"), "current": ("current_a", "current_measured", "A")}


def model_toml(c: Calibration) -> str:
    lines = ["[model]                         # pdr calibrate: " + ", ".join(c.recordings)]
    lines += [f"{k} = {float(getattr(c.calibrated, k))!r}" for k in MODEL_KEYS]
    return "\n".join(lines) + "\n"


def _g(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g}"


def markdown(c: Calibration, doc: dict) -> str:
    out = [f"# Calibration of {', '.join(c.recordings)}", "",
           f"Prior: {doc['prior']['source']}. {CONVENTION}.", "",
           "| parameter | prior | calibrated | ~95 % interval | identifiable | unit |", "|---|---|---|---|---|---|"]
    for k in MODEL_KEYS:
        span = doc["intervals"][k]
        out.append(f"| {k} | {_g(getattr(c.prior, k))} | {_g(doc['parameters'][k])} | "
                   f"{'-' if span is None else f'[{span[0]:.4g}, {span[1]:.4g}]'} | "
                   f"{'yes' if doc['identifiable'][k] else 'no (convention)'} | {UNITS[k]} |")
    out += ["", "What the data pin instead of the parameters held by the convention:", "",
            "| combination | value | ~95 % interval | unit |", "|---|---|---|---|"]
    for comb in doc["combinations"]:
        span = comb["interval"]
        out.append(f"| {comb['name']} | {comb['value']:.4g} | "
                   f"{'-' if span is None else f'[{span[0]:.4g}, {span[1]:.4g}]'} | {comb['unit']} |")
    out += ["", "| MSE (replay) | before | after |", "|---|---|---|"]
    for s in doc["mse_before"]:
        out.append(f"| {s} | {doc['mse_before'][s]:.3g} | {doc['mse_after'].get(s, float('nan')):.3g} |")
    fit = doc["fit"]
    out += ["", f"Fit: {fit['free_parameters']} free parameters on {fit['samples']} weighted samples, "
                f"chi-square {fit['chi2']:.1f}, {fit['evaluations']} evaluations"
                f"{'' if fit['converged'] else ' (not converged: the intervals are rough)'}.",
            "", "Adopt it: `pdr calibrate ... --adopt` writes this `[model]` into `raw/rig.toml`."]
    return "\n".join(out) + "\n"


def log_calibration(rec, c: Calibration, measurements, report_md: str) -> None:
    import rerun as rr

    from pipeline.validate.rerun_log import TIMELINE, log_signal

    for meas, before, after in zip(measurements, c.replays_before, c.replays_after):
        every = rr.TimeColumn(TIMELINE, duration=meas.t)
        for sig, (column, field, _unit) in SIGNALS.items():
            if column not in meas.kinematics.columns:
                continue
            y = meas.kinematics[column].to_numpy(dtype=float, na_value=np.nan)
            log_signal(rec, f"{meas.name}/{sig}", every, {
                "before (prior)": (getattr(before, field), COLORS["before (prior)"], 1.5),
                "after (calibrated)": (getattr(after, field), COLORS["after (calibrated)"], 1.5),
                "measured": (y, COLORS["measured"], 1.5)})
            log_signal(rec, f"{meas.name}/residuals/{sig}", every, {
                "before (prior)": (y - getattr(before, field), COLORS["before (prior)"], 1.5),
                "after (calibrated)": (y - getattr(after, field), COLORS["after (calibrated)"], 1.5)})
    rec.log("report", rr.TextDocument(report_md, media_type=rr.MediaType.MARKDOWN), static=True)


def calibration_blueprint(names: tuple[str, ...]):
    import rerun.blueprint as rrb

    columns = [rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/{n}/{s}", name=f"{n}: {s} [{SIGNALS[s][2]}]")
                              for s in SIGNALS],
                            *[rrb.TimeSeriesView(origin=f"/{n}/residuals/{s}", name=f"{n}: {s} residual")
                              for s in SIGNALS]) for n in names]
    return rrb.Blueprint(rrb.Horizontal(*columns, rrb.TextDocumentView(origin="/report", name="report")),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(state="collapsed"), auto_views=False)


def write_rrd(target: Path, c: Calibration, measurements, report_md: str) -> None:
    """Saved atomically through ``rerun_io.write_recording`` (the stream ends with the file)."""
    from pipeline.validate.rerun_io import blueprint_chunks, verify_rrd, write_recording

    layout = blueprint_chunks(calibration_blueprint, tuple(m.name for m in measurements))
    with atomic_path(target) as tmp:
        write_recording(tmp, "calibrate-" + "+".join(c.recordings), layout,
                        lambda rec: log_calibration(rec, c, measurements, report_md), application_id="pdr-calibrate")
        verify_rrd(tmp)


def write_outputs(out_dir: Path, c: Calibration, measurements, *, rrd: bool = True) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = c.to_json()
    md = markdown(c, doc)
    paths = {"json": out_dir / "calibration.json", "markdown": out_dir / "calibration.md",
             "toml": out_dir / "model.toml", "rrd": out_dir / "calibration.rrd"}
    write_json(paths["json"], doc)
    write_text(paths["markdown"], md)
    write_text(paths["toml"], model_toml(c))
    if rrd:
        write_rrd(paths["rrd"], c, measurements, md)
    else:
        del paths["rrd"]
    return paths


def dumps(doc: dict) -> str:
    return json.dumps(doc, indent=2, allow_nan=False)
