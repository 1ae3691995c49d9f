"""Placeholder until the model stage lands."""

from pipeline.errors import PdrError


def simulate() -> None:
    """(not built yet)"""
    raise PdrError("the simulate command is being built")
