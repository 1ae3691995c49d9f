"""Placeholder until the virtual rig lands."""

import typer

app = typer.Typer(help="The virtual rig (being built).")


@app.command("make")
def make() -> None:
    """(not built yet)"""
