"""The ``pdr`` command: typer wiring only, the work lives in the stage packages.

Each stage package exposes its commands in its own ``cli.py``; heavy imports
happen inside the command functions so ``pdr --help`` stays instant.
"""

from __future__ import annotations

import gc
import os
import sys

import typer

from pipeline.errors import PdrError, describe_failure

app = typer.Typer(
    help="pdr: pinion-double-rack recordings -> clean data, a validated hybrid model, "
         "a Rerun recording, and what the model is missing.",
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
)


def _register() -> None:
    from pipeline import run as run_stage
    from pipeline import simulate_cli
    from pipeline.derive import cli as derive_cli
    from pipeline.calibrate import cli as calibrate_cli
    from pipeline.discover import cli as discover_cli
    from pipeline.ingest import cli as ingest_cli
    from pipeline.record import cli as record_cli
    from pipeline.rig import cli as rig_cli
    from pipeline.validate import cli as validate_cli

    app.command("run")(run_stage.run_command)
    app.command("ingest")(ingest_cli.ingest)
    app.command("derive")(derive_cli.derive)
    app.command("validate")(validate_cli.validate)
    app.command("simulate")(simulate_cli.simulate)
    app.command("discover")(discover_cli.discover)
    app.command("calibrate")(calibrate_cli.calibrate)
    app.command("gate")(validate_cli.gate)
    app.command("view")(validate_cli.view)
    app.command("record")(record_cli.record)
    app.add_typer(rig_cli.app, name="rig")


_register()


def _run() -> None:
    """The command, then the garbage collector stopped for the interpreter's teardown: its collections
    walk every object of every module imported (~0.4 s after ``pdr discover``, ~15 % of the command)
    only to free what the process's exit frees anyway.  Atexit handlers and flushes still run."""
    try:
        app()
    finally:
        gc.freeze()


def main() -> None:
    """Console entry point: every failure is one line on stderr, never a traceback.

    A ``PdrError`` (the input's fault) exits 2; an ``OSError`` escaping a stage
    (a folder that cannot be written, a full disk) is named the same way; any
    other exception is a bug in pdr, reported as one line that says so
    (``PDR_DEBUG=1`` shows the traceback).
    """
    from pipeline.io.streams import mend_standard_streams

    mend_standard_streams()                      # a shell's 2>&- or >&-: see that module
    for stream in (sys.stdout, sys.stderr):      # file names need not be valid UTF-8 (or fit the console)
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    try:
        _run()
    except PdrError as err:
        print(f"pdr: error: {err}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("pdr: interrupted", file=sys.stderr)
        sys.exit(130)
    except Exception as err:
        if os.environ.get("PDR_DEBUG"):
            raise
        print(f"pdr: error: {describe_failure(err)}", file=sys.stderr)
        sys.exit(2 if isinstance(err, OSError) else 3)
