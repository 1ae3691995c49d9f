"""``pdr derive``: velocity, phases, guard overshoot, energy and cycles for ingested recordings."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def derive(
    recordings: Annotated[list[str], typer.Argument(
        help="Run name, processed run folder, or raw CSV path (all of its segments).", show_default=False)],
    processed: Annotated[Path, typer.Option(help="Folder holding the processed runs.")] = Path("processed"),
    json_out: Annotated[bool, typer.Option("--json", help="Print the summaries as one JSON object.")] = False,
) -> None:
    """Derive kinematics, phases, overshoot, cycles and summary.json for ingested recordings.
    Every recording it can is derived; exit status 2 if any failed.

    Example: pdr derive raw/paper_run.csv   (or: pdr derive paper_run, pdr derive processed/paper_run)
    """
    import json

    from pipeline.derive.stage import derive_run
    from pipeline.errors import for_each
    from pipeline.run.lock import processed_lock
    from pipeline.runs import resolve_runs

    summaries = {}

    def one(item: str) -> None:
        for paths in resolve_runs(item, processed):
            summary = derive_run(paths)
            summaries[paths.name] = summary
            if not json_out:
                typer.echo(headline(summary))

    with processed_lock(processed):
        failures = for_each(recordings, one, processed)
    if json_out:
        typer.echo(json.dumps(summaries, indent=2, sort_keys=True))
    if failures:
        raise typer.Exit(2)


def headline(summary: dict) -> str:
    """One line per run: what a reviewer checks first."""
    parts = [f"{summary['run']}: {summary['samples']} samples, {summary['phases']['count']} phases "
             f"({summary['dir_source']})"]
    for name, d in summary["overshoot"]["directions"].items():
        o = d["overshoot_rad"]
        if o["n"]:
            parts.append(f"overshoot {name} {o['mean']:.3f}+/-{o['std']:.3f} rad (max {o['max']:.3f})")
    period = summary["cycles"]["period_s"]
    if period["n"]:
        parts.append(f"period {period['mean']:.3f} s")
    if summary["energy"] and summary["energy"]["energy_paper_j"] is not None:
        parts.append(f"paper energy {summary['energy']['energy_paper_j']:.3f} J")
    parts += [f"{k} not computed" for k in summary["not_computed"]]
    parts += summary["overshoot"]["flags"]
    return "; ".join(parts)
