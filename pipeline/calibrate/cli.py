"""``pdr calibrate RECORDING... [--json] [--adopt]``: the user's own rig's base model."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

DEFAULT_PROCESSED = Path("processed")


def calibrate(
    recordings: list[str] = typer.Argument(..., metavar="RECORDING",
                                           help="Raw CSV paths of one rig (ingested and derived on the fly), "
                                                "or processed run folders / run names."),
    json_out: bool = typer.Option(False, "--json", help="Print one JSON object (docs/FORMAT.md) on stdout."),
    adopt: bool = typer.Option(False, "--adopt", help="Write the calibrated \\[model] into raw/rig.toml beside the "
                                                      "recordings, keeping the rest of the file. Never done without it."),
    out: Optional[Path] = typer.Option(None, "--out", help="Folder for the report, model.toml and .rrd "
                                                           "(default: <processed>/calibration)."),
    processed: Path = typer.Option(DEFAULT_PROCESSED, "--processed", help="Folder of processed runs."),
    no_rrd: bool = typer.Option(False, "--no-rrd", help="Skip the Rerun recording."),
) -> None:
    """Fit the base model's [model] parameters to recordings of your own rig, with Table I (or the
    declared [model]) as prior, and say what the recordings can and cannot pin down.

    Example: pdr calibrate raw/rest_a.csv raw/rest_b.csv --adopt

    Two clean recordings (no effect the rig is not known to have) are a good start; afterwards
    `pdr discover` compares new recordings with your rig's model, not the paper's.
    """
    import tempfile

    from pipeline.calibrate.load import adopt_target, load_measurements
    from pipeline.calibrate.report import dumps, model_toml, write_outputs
    from pipeline.calibrate.stage import calibrate as fit_rig
    from pipeline.discover.adopt import replace_table

    target = adopt_target(recordings) if adopt else None       # refuse before the work, not after
    with tempfile.TemporaryDirectory(prefix="pdr-calibrate-") as tmp:
        measurements, prior, declared = load_measurements(recordings, processed, Path(tmp))
        result = fit_rig(measurements, prior, declared)
        written = write_outputs(out if out is not None else processed / "calibration", result, measurements,
                                rrd=not no_rrd)
    doc = result.to_json()
    doc["recordings"] = list(recordings)
    if target is not None:
        doc["adopted"] = str(replace_table(target, "model", model_toml(result)))
    if json_out:
        typer.echo(dumps(doc))
        return
    typer.echo(summary(doc))
    typer.echo(f"report: {written['markdown']}")
    if target is not None:
        typer.echo(f"adopted into {target}")
    else:
        typer.echo(f"[model] table: {written['toml']} (add --adopt to write it into raw/rig.toml)")


def summary(doc: dict) -> str:
    lines = []
    for k, v in doc["parameters"].items():
        span = doc["intervals"][k]
        lines.append(f"  {k:3s} = {v:.5g}  " + (f"[{span[0]:.4g}, {span[1]:.4g}]" if span else "(convention)"))
    for comb in doc["combinations"]:
        span = comb["interval"]
        lines.append(f"  {comb['name']} = {comb['value']:.4g}" + (f"  [{span[0]:.4g}, {span[1]:.4g}]" if span else ""))
    mse = ", ".join(f"{s} {doc['mse_before'][s]:.3g} -> {doc['mse_after'].get(s, float('nan')):.3g}"
                    for s in doc["mse_before"])
    return "calibrated [model] (~95 % intervals):\n" + "\n".join(lines) + f"\nreplay MSE: {mse}"
