"""``pdr run``: every stage on every new or changed recording of ``raw/``.

``stages`` declares the stages and what each reads and writes per run,
``stamp`` is the incremental cache, ``recordings`` sorts the raw folder into
recordings and refusals, ``lock`` guards ``processed/``, ``runner`` drives the
process pool and ``report`` prints the end-of-run summary.  This module holds
the command; importing it stays light so a run with nothing to do starts fast.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import typer

from pipeline.run.lock import processed_lock
from pipeline.run.report import RunReport, print_report
from pipeline.run.pool import CHUNK_MAX, chunks
from pipeline.run.runner import run_pipeline
from pipeline.run.stages import process_recording
from pipeline.run.stamp import Stamp, code_version, stamp_for

__all__ = ["CHUNK_MAX", "RunReport", "Stamp", "chunks", "code_version", "print_report", "process_recording",
           "processed_lock", "run_command", "run_pipeline", "stamp_for"]


def run_command(
    raw: Path = typer.Option(Path("raw"), "--raw", help="Folder of raw recordings (<name>.csv + optional <name>.toml)."),
    processed: Path = typer.Option(Path("processed"), "--processed", help="Output folder."),
    jobs: int = typer.Option(min(2, os.cpu_count() or 1), "--jobs", "-j", min=1, help="Worker processes."),
    force: bool = typer.Option(False, "--force", help="Re-run every recording even if unchanged."),
    cluster: str = typer.Option("", "--cluster", envvar="PDR_CLUSTER", show_envvar=True,
                                help="A dask scheduler (tcp://HOST:8786): the recordings are processed by its "
                                     "workers, the outputs written here."),
) -> None:
    """Run every stage (ingest, derive, validate) on every new or changed recording in raw/;
    unchanged ones are skipped. Exit status 1 if any recording failed.

    Example: pdr run --raw raw --processed processed -j 2   (or --cluster tcp://HOST:8786)
    """
    from pipeline.run.stop import nothing_left_to_stop, stop_signals, stopped_by

    with stop_signals():
        try:
            report = run_pipeline(raw, processed, jobs=jobs, force=force, show_progress=sys.stderr.isatty(),
                                  cluster=cluster or None)
            nothing_left_to_stop()
            print_report(report, processed)
        except BaseException as err:            # a stop is said here: typer turns it into a silent exit 130
            if (stop := stopped_by(err)) is None:
                raise
            typer.echo(f"pdr: {stop}", err=True)
            raise typer.Exit(stop.exit_status) from None
    if report.failed:
        raise typer.Exit(1)
