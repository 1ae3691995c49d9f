"""Placeholder until the validate stage lands."""

from pipeline.errors import PdrError


def validate() -> None:
    """(not built yet)"""
    raise PdrError("validate is being built")


def gate() -> None:
    """(not built yet)"""
    raise PdrError("gate is being built")


def view() -> None:
    """(not built yet)"""
    raise PdrError("view is being built")
