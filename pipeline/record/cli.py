"""``pdr record``: typer wiring for ``pipeline.record.session``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipeline.errors import PdrError


def record(
    port: Annotated[str | None, typer.Argument(help="Serial port, e.g. /dev/ttyACM0 (see --list).")] = None,
    name: Annotated[str | None, typer.Option(help="Recording name: writes RAW/NAME.csv (never overwrites).")] = None,
    baud: Annotated[int, typer.Option(help="Baud rate of the sketch's Serial.begin.")] = 115200,
    duration: Annotated[float | None, typer.Option(help="Stop after S seconds (default: Ctrl-C or unplug).")] = None,
    no_view: Annotated[bool, typer.Option("--no-view", help="No live view.")] = False,
    connect: Annotated[str | None, typer.Option(
        help="Live view in a running Rerun viewer at this gRPC URL instead of spawning one.")] = None,
    save_view: Annotated[Path | None, typer.Option(
        help="Live view into this .rrd file instead of a viewer (headless machines).")] = None,
    no_run: Annotated[bool, typer.Option("--no-run", help="Only capture; do not run the pipeline after.")] = False,
    raw: Annotated[Path, typer.Option(help="Folder of raw recordings.")] = Path("raw"),
    processed: Annotated[Path, typer.Option(help="Output folder of the run.")] = Path("processed"),
    list_: Annotated[bool, typer.Option("--list", help="List serial ports with their USB description and exit.")] = False,
) -> None:
    """Record the rig's serial output byte for byte into RAW/NAME.csv with a live view, then run the
    pipeline on it. Stops on Ctrl-C, at --duration, or when the port goes away.

    Example: pdr record /dev/ttyACM0 --name run_0412     (no rig? pdr rig serve --pty, see README)
    """
    from pipeline.record.live import ViewSink
    from pipeline.record.session import RecordOptions, record as do_record

    if list_:
        from pipeline.record.ports import list_ports

        lines = list_ports()
        typer.echo("\n".join(lines) if lines else "no serial ports found")
        return
    if port is None:
        raise PdrError("expected a serial port (pdr record --list shows them)", key="PORT")
    if name is None:
        raise PdrError("expected --name NAME: the recording is written to RAW/NAME.csv", key="--name")
    if duration is not None and duration <= 0:
        raise PdrError(f"expected a duration > 0 s, got {duration:g}", key="--duration")
    if sum(x is not None and x is not False for x in (connect, save_view, no_view or None)) > 1:
        raise PdrError("expected at most one of --no-view, --connect, --save-view", key="--no-view")
    view = None if no_view else ViewSink("connect", connect) if connect else \
        ViewSink("save", str(save_view)) if save_view else ViewSink("spawn")
    opts = RecordOptions(port=port, name=name, raw=raw, processed=processed, baud=baud, duration_s=duration,
                         view=view, run=not no_run)
    _result, status = do_record(opts, say=typer.echo)
    if status:
        raise typer.Exit(status)
