"""``comparison.mcap``: the model comparison for Foxglove, written by the validate stage.

The ingest stage's ``<run>.mcap`` holds what the rig logged; the comparison
exists only once the model has run, so validation writes a second file beside
it rather than rewriting the first (each stage owns its outputs, and an
unchanged recording keeps its ingest bytes).  One JSON message per sample per
channel, through the same bulk writer (``ingest/mcap_bulk.py``); every
channel's JSON schema comes from ``schemas/kinematics.json`` or
``schemas/comparison.json``, the tables' one source of truth:

- ``/measured/kinematics``: angle and velocity (both estimators);
- ``/measured/current``: logged and smoothed current (when logged);
- ``/measured/command``: the logged or inferred ``dir``;
- ``/model/closed_loop``, ``/model/replay``: each simulation's angle, velocity,
  current as the sensor reads it, and command;
- ``/residuals/closed_loop``, ``/residuals/replay``: measured minus model.

log_time is placed as the ingest MCAP's (``ingest.timeline``): the wall clock
when the terminal stamped a date, else the time since the capture's first
sample; the ``time`` metadata record says which.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.ingest.timeline import epoch_ns, log_time_origin  # noqa: F401  (epoch_ns: tests)
from pipeline.io.atomic import atomic_path
from pipeline.schemas import load_schema

# topic -> (schema file, columns); a group whose columns the run lacks is left out (a way not run, the
# kinematics of a recording without an encoder)
MEASURED = {
    "/measured/kinematics": ("t_s", "theta_rad", "omega_rad_s", "omega_backward_rad_s"),
    "/measured/current": ("current_a", "current_smooth_a"),
    "/measured/command": ("dir",),
}
SIGNALS = (("theta", "rad"), ("omega", "rad_s"), ("current", "a"))


def model_columns(way: str) -> tuple[str, ...]:
    return (*(f"{s}_{way}_{u}" for s, u in SIGNALS), f"dir_{way}")


def residual_columns(way: str) -> tuple[str, ...]:
    return tuple(f"{s}_residual_{way}_{u}" for s, u in SIGNALS)


def comparison_channels(kin: pd.DataFrame, comparison: pd.DataFrame):
    """The channels of ``comparison.mcap`` (``mcap_bulk.ChannelBatch``), schemas from ``schemas/*.json``."""
    from pipeline.ingest.mcap_bulk import ChannelBatch

    groups = [(topic, "kinematics", kin, cols) for topic, cols in MEASURED.items()]
    for way in ("closed_loop", "replay"):
        groups.append((f"/model/{way}", "comparison", comparison, model_columns(way)))
        groups.append((f"/residuals/{way}", "comparison", comparison, residual_columns(way)))
    out = []
    for topic, schema_name, table, cols in groups:
        present = [c for c in cols if c in table.columns]
        if not set(present) - {"t_s"}:         # nothing of the group logged (no encoder: no kinematics)
            continue
        title = "pdr" + topic.replace("/", ".")
        schema = load_schema(schema_name).json_schema(present, title=title)
        out.append(ChannelBatch(topic=topic, schema_name=title, json_schema=schema,
                                fields={c: column(table, c) for c in present}))
    return out


def write_comparison_mcap(target: Path, run: str, kin: pd.DataFrame, comparison: pd.DataFrame,
                          model: dict, segment: dict | None = None) -> None:
    """Write ``comparison.mcap`` atomically; identical inputs give identical bytes.

    ``segment``: the run's segment in its ingest report, which places log_time on the capture's one time
    axis (``ingest.timeline``): the wall clock when the terminal's stamp carries a date."""
    from pipeline.ingest.mcap_bulk import write_mcap

    t = column(kin, "t_s", dtype=float)
    log_time = np.round((t - t[0]) * 1e9).astype(np.uint64) if len(t) else np.zeros(0, np.uint64)
    origin, time_record = log_time_origin(segment)
    log_time = log_time + np.uint64(origin)
    metadata = {"time": {**time_record, "t0_s": repr(float(t[0])) if len(t) else "0.0"},
                "run": {"run": run},
                "model": {"model": json.dumps(model, sort_keys=True)}}
    with atomic_path(Path(target)) as tmp, open(tmp, "wb") as fh:
        write_mcap(fh, comparison_channels(kin, comparison), log_time, metadata)
