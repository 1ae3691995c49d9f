"""Placeholder until the run orchestrator lands."""

from pipeline.errors import PdrError


def run_command() -> None:
    """(not built yet)"""
    raise PdrError("run is being built")
