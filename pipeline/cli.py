"""The ``pdr`` command: typer wiring only, the work lives in the stage packages.

Each stage package exposes its commands in its own ``cli.py``; heavy imports
happen inside the command functions so ``pdr --help`` stays instant.
"""

from __future__ import annotations

import sys

import typer

from pipeline.errors import PdrError

app = typer.Typer(
    help="pdr: pinion-double-rack recordings -> clean data, a validated hybrid model, "
         "a Rerun recording, and what the model is missing.",
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
)


def _register() -> None:
    from pipeline import run as run_stage
    from pipeline.derive import cli as derive_cli
    from pipeline.discover import cli as discover_cli
    from pipeline.ingest import cli as ingest_cli
    from pipeline.model import cli as model_cli
    from pipeline.record import cli as record_cli
    from pipeline.rig import cli as rig_cli
    from pipeline.validate import cli as validate_cli

    app.command("run")(run_stage.run_command)
    app.command("ingest")(ingest_cli.ingest)
    app.command("derive")(derive_cli.derive)
    app.command("validate")(validate_cli.validate)
    app.command("simulate")(model_cli.simulate)
    app.command("discover")(discover_cli.discover)
    app.command("gate")(validate_cli.gate)
    app.command("view")(validate_cli.view)
    app.command("record")(record_cli.record)
    app.add_typer(rig_cli.app, name="rig")


_register()


def main() -> None:
    """Console entry point: a ``PdrError`` becomes one line on stderr and exit status 2."""
    try:
        app()
    except PdrError as err:
        print(f"pdr: error: {err}", file=sys.stderr)
        sys.exit(2)
