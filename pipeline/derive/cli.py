"""Placeholder until the derive stage lands."""

from pipeline.errors import PdrError


def derive() -> None:
    """(not built yet)"""
    raise PdrError("the derive command is being built")
