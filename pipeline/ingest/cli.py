"""``pdr ingest``: raw CSV captures -> processed/<run>/ signals.parquet, <run>.mcap, ingest_report.json, rig.json."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def ingest(
    recordings: Annotated[list[Path], typer.Argument(help="Raw CSV captures (raw/<name>.csv); their rig TOML "
                                                          "layers raw/rig.toml and raw/<name>.toml apply.")],
    processed: Annotated[Path, typer.Option("--processed", "-o", help="Output folder, one sub-folder per run.")]
    = Path("processed"),
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No console summary.")] = False,
) -> None:
    """Ingest recordings into schema-checked Parquet and MCAP, with units and an ingest report.
    Every recording it can is ingested; exit status 2 if any failed.

    Example: pdr ingest raw/run1.csv raw/run2.csv --processed processed
    """
    from pipeline.errors import IngestError, for_each
    from pipeline.ingest.stage import ingest_recording, summary_text
    from pipeline.names import later_twins
    from pipeline.run.lock import processed_lock

    twins = later_twins(recordings)

    def one(csv_path: Path) -> None:
        if csv_path in twins:       # one run folder per name: the later one would overwrite the earlier
            raise IngestError(f"its run name is that of {twins[csv_path]}, given before it (both would be "
                              f"written to {processed / twins[csv_path].stem}); rename one", path=csv_path)
        result = ingest_recording(csv_path, processed)
        if not quiet:
            typer.echo(summary_text(result.report))

    with processed_lock(processed):
        failures = for_each(recordings, one, processed)
    if failures:
        raise typer.Exit(2)
