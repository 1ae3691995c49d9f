"""Placeholder until the ingest stage lands."""

from pipeline.errors import PdrError


def ingest() -> None:
    """(not built yet)"""
    raise PdrError("the ingest command is being built")
