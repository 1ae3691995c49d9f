"""Shared test settings: rerun's strict mode on, so misuse raises instead of dropping data."""

import os

os.environ.setdefault("RERUN_STRICT", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
