"""Placeholder until the discover stage lands."""

from pipeline.errors import PdrError


def discover() -> None:
    """(not built yet)"""
    raise PdrError("the discover command is being built")
