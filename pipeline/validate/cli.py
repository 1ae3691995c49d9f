"""``pdr validate``, ``pdr gate`` and ``pdr view``: thin typer commands, heavy imports inside."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from pipeline.errors import PdrError

DEFAULT_PROCESSED = Path("processed")
DEFAULT_THRESHOLDS = Path("raw/thresholds.toml")


def validate(
    recordings: list[str] = typer.Argument(..., help="Raw CSV paths, run names or run folders."),
    model: Optional[Path] = typer.Option(None, "--model", help="TOML with [model]/[effects] to use instead of the rig's."),
    processed: Path = typer.Option(DEFAULT_PROCESSED, "--processed", help="Folder of processed runs."),
    no_rrd: bool = typer.Option(False, "--no-rrd", help="Skip the Rerun recording."),
    no_png: bool = typer.Option(False, "--no-png", help="Skip the overview PNG."),
) -> None:
    """Rerun the hybrid model on derived runs (closed loop and replay) and write validation.json,
    comparison.parquet, <run>.rrd and overview.png. Every run it can is validated; exit status 2 if any failed.

    Example: pdr validate raw/example.csv --model my_model.toml
    """
    from pipeline.errors import for_each
    from pipeline.run.lock import processed_lock
    from pipeline.runs import resolve_runs
    from pipeline.validate.stage import validate_run
    from pipeline.validate.summary import render_summary, write_summary

    done: list[str] = []

    def one(rec: str) -> None:
        for paths in resolve_runs(rec, processed):
            row = validate_run(paths, model, rrd=not no_rrd, png=not no_png)
            done.append(paths.name)
            units = {"theta": "rad^2", "omega": "(rad/s)^2", "current": "A^2"}
            mses = [f"{sig} {row[f'replay_{sig}_mse']:.4g} {unit}" for sig, unit in units.items()
                    if row[f"replay_{sig}_mse"] is not None]      # fewer without an encoder
            typer.echo(f"{row['run']}: replay MSE " + ", ".join(mses) if mses else
                       f"{row['run']}: not compared with the model (no angle and no dir logged)")

    with processed_lock(processed):
        failures = for_each(recordings, one, processed)
        table = write_summary(processed)
    if done:
        render_summary(table[table["run"].isin(done)])
    if failures:
        raise typer.Exit(2)


def gate(
    processed: Path = typer.Option(DEFAULT_PROCESSED, "--processed", help="Folder of processed runs."),
    thresholds: Optional[Path] = typer.Option(
        None, "--thresholds",
        help=f"MSE thresholds TOML [default: {DEFAULT_THRESHOLDS}, else the built-in defaults of README.md]."),
) -> None:
    """Check every processed run's MSEs against its thresholds; exit 1 if any run exceeds, has no figures
    to gate or an unreadable validation.json, or if the thresholds name a run that is not there.

    Without --thresholds, raw/thresholds.toml is used when it exists, else the built-in
    defaults (replay: theta 1e-5 rad^2, omega 5e-4 (rad/s)^2, current 1.5e-3 A^2; closed loop:
    0.3, 1.0, 1.5e-2), and the gate says so.

    Example: pdr gate --thresholds raw/thresholds.toml
    """
    from rich.table import Table

    from pipeline.run.lock import reading_lock
    from pipeline.validate.gate import BUILTIN_SOURCE, UNITS, gate as run_gate, load_thresholds
    from pipeline.validate.console import wide_console

    spec = load_thresholds(thresholds or DEFAULT_THRESHOLDS, missing_ok=thresholds is None)
    with reading_lock(processed):
        verdicts = run_gate(processed, spec)
    if not verdicts:
        raise PdrError("no processed runs to gate (run pdr run first)", path=processed)
    if spec.source == BUILTIN_SOURCE:
        typer.echo(f"gate: no {DEFAULT_THRESHOLDS}: using the built-in defaults ("
                   + "; ".join(f"{way.replace('_', ' ')}: " + ", ".join(f"{s} {v:g} {UNITS[s]}" for s, v in t.items())
                               for way, t in spec.default.items()) + ")")
    console = wide_console(stderr=False)
    table = Table(title=f"MSE gate ({spec.source})", caption="MSE units: theta rad^2, omega (rad/s)^2, current A^2")
    for head in ("run", "way", "signal", "MSE", "threshold", "margin", ""):
        table.add_column(head, justify="left" if head in ("run", "way", "signal", "") else "right")
    for v in verdicts:
        if v.problem:
            table.add_row(v.run, "-", "-", "-", "-", "-", f"[red]FAIL[/] {v.problem}")
            continue
        for c in v.checks:
            margin = c.margin_text()
            status = "[green]ok[/]" if c.threshold is not None and c.passed else (
                "[red]FAIL[/]" if not c.passed else "not gated")
            table.add_row(c.run, c.way, c.signal, f"{c.mse:.4g}" if c.mse is not None else "-",
                          "-" if c.threshold is None else f"{c.threshold:.4g}", margin, status)
        for way in v.skipped:
            table.add_row(v.run, way, "-", "-", "-", "-", "skipped: no encoder (validation.json says why)")
    console.print(table)
    failed = [v for v in verdicts if not v.passed]
    if failed:
        for v in failed:
            typer.echo(f"gate: FAIL {v.run}: " + "; ".join(v.failures()), err=True)
        typer.echo(f"gate: {len(failed)} of {len(verdicts)} runs failed", err=True)
        raise typer.Exit(1)
    typer.echo(f"gate: all {len(verdicts)} runs within their thresholds")


def view(
    names: list[str] = typer.Argument(..., help="Run names (or paths to .rrd files); several open side by side."),
    processed: Path = typer.Option(DEFAULT_PROCESSED, "--processed", help="Folder of processed runs."),
    web: bool = typer.Option(False, "--web", help="Serve Rerun's web viewer over HTTP and print its address "
                             "(for a machine without a display)."),
    bind: str = typer.Option("127.0.0.1", "--bind", help="With --web: the address to listen on "
                             "(0.0.0.0 for every interface)."),
    port: int = typer.Option(9090, "--port", help="With --web: the web viewer's port; the recording is served "
                             "on the next one (0: any free pair)."),
) -> None:
    """Open runs' Rerun recordings (with their saved layout) in the Rerun viewer; several side by side.

    Example: pdr view paper_clean friction_declared      (or, over SSH: pdr view --web paper_clean)
    """
    import time

    from pipeline.runs import run_paths
    from pipeline.validate.view import NO_DISPLAY, display_available, open_native, recording_to_open, serve_web

    rrds: dict[str, Path] = {}
    for name in names:
        path = Path(name) if name.endswith(".rrd") else run_paths(processed, name).rrd
        if not path.is_file():
            raise PdrError("no Rerun recording: validate the run first (pdr run or pdr validate)", path=path)
        key = path.stem if name.endswith(".rrd") else name
        rrds[key if key not in rrds else f"{key}-{len(rrds) + 1}"] = path
    if not web and not display_available():
        raise PdrError(NO_DISPLAY)
    path = recording_to_open(rrds)
    if not web:
        open_native(path)
        return
    server = serve_web(path, bind=bind, port=port)
    port, file_port = server.port, server.file_port
    typer.echo(f"pdr view: {', '.join(rrds)} at {server.url}\n  Ctrl-C stops; from another machine: "
               f"ssh -L {port}:localhost:{port} -L {file_port}:localhost:{file_port} THIS_HOST, then open the address")
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
