"""The edge of the ingest stage: Parquet, MCAP, reports and rig.json on disk, all atomic and deterministic."""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor, wait
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.columns import column
from pipeline.config import RigConfig
from pipeline.io.atomic import atomic_path, remove_stale_temporaries, syncs_deferred, write_json
from pipeline.runs import RunPaths
from pipeline.schemas import load_schema

# MCAP channel per signal group; a group whose columns a sketch does not log is left out (/encoder: t_s is
# always there, but without counts the channel has no encoder in it)
CHANNEL_GROUPS = {
    "/encoder": ("t_s", "counts", "theta_rad"),
    "/current": ("adc", "current_v", "current_a"),
    "/command": ("dir", "mode"),
}
GUARDS_TOPIC = "/guards"              # +/-controller.guard_rad at every encoder sample (schemas/guards.json)


# Parquet encoding per column, chosen by measured cost (encode CPU + bytes written) per million rows;
# fixed so re-runs give identical bytes.  Times and the ACS712 voltage are regular in their bytes:
# byte-stream split + snappy stores t_s/t_raw in ~0.6 MB of 8 for ~5 ms.  line and counts step by
# small amounts: byte-stream split + LZ4 stores line in 0.06 MB and a rig's
# smooth counts in ~0.2 MB (a random walk's in ~1 MB) for ~4 ms each, where delta packing is a little
# smaller but takes ~7 ms.  segment, dir, mode (int8/int32 stored as 4-byte INT32) shrink 20x under
# snappy for ~1 ms each.  theta_rad, adc, current_a stay plain: compressing them costs more time than
# writing their bytes.  No dictionaries (hashing every value costs more than it saves here).  Against
# snappy + dictionaries everywhere (the first choice): ~40 vs ~160 ms, about the same size (25 vs 22 MB).
# Min/max statistics (~1 ms per column) only on the columns a reader selects rows by: time, line, segment.
_SPLIT, _PLAIN = "BYTE_STREAM_SPLIT", "PLAIN"
PARQUET_ENCODING = {"t_s": (_SPLIT, "snappy"), "t_raw": (_SPLIT, "snappy"), "line": (_SPLIT, "lz4"),
                    "segment": (_PLAIN, "snappy"), "counts": (_SPLIT, "lz4"), "theta_rad": (_PLAIN, "none"),
                    "adc": (_PLAIN, "none"), "current_v": (_SPLIT, "snappy"), "current_a": (_PLAIN, "none"),
                    "dir": (_PLAIN, "snappy"), "mode": (_PLAIN, "snappy")}
PARQUET_OPTIONS = {"use_dictionary": False,
                   "column_encoding": {c: enc for c, (enc, _) in PARQUET_ENCODING.items()},
                   "compression": {c: comp for c, (_, comp) in PARQUET_ENCODING.items()},
                   "write_statistics": ["t_s", "t_raw", "line", "segment"],
                   "write_batch_size": 1 << 16}     # values per encoder call: 64k instead of 1k saves ~6 ms
ROW_GROUP_ROWS = 1 << 17         # 131,072 rows (~3 MB) per row group: written out while the next is encoded
SINK_BUFFER_BYTES = 1 << 20      # the encoder's pages gathered into writes of 1 MB


def signals_table(df: pd.DataFrame, where: str, cfg: RigConfig, check: bool = True) -> pa.Table:
    """The checked Arrow table with units in field metadata (schemas/signals.json); ``check=False``:
    only a column the schema does not define is refused here, the caller runs ``check_arrow``.

    As ``TableSchema.to_arrow``, but built from the columns' arrays (zero copy) instead of
    ``Table.from_pandas``, which costs ~35 ms per million rows for pandas metadata nobody reads.
    """
    schema = load_schema("signals", cfg)       # the ADC's range is the rig's
    if not set(df.columns) <= {c.name for c in schema.columns}:
        schema.check(df, where)                 # names the column the schema does not define
    arrow = schema.arrow_schema(df.columns)
    table = pa.Table.from_arrays([pa.array(column(df, f.name), f.type) for f in arrow], schema=arrow)
    if check:
        schema.check_arrow(table, where)
    return table


def mcap_channels(df: pd.DataFrame, cfg: RigConfig):
    from pipeline.ingest.mcap_bulk import ChannelBatch
    schema = load_schema("signals", cfg)
    out = []
    for topic, names in CHANNEL_GROUPS.items():
        present = [c for c in names if c in df.columns]
        if len(present) < len(names) and (topic != "/encoder" or "counts" not in present):
            continue
        title = "pdr." + topic.strip("/")
        out.append(ChannelBatch(topic=topic, schema_name=title, json_schema=schema.json_schema(present, title=title),
                                fields={c: column(df, c) for c in present}))
    if "theta_rad" in df.columns:       # the guards as a channel Foxglove plots beside the angle, not only metadata
        t, guard = column(df, "t_s"), float(cfg.controller.guard_rad)
        out.append(ChannelBatch(topic=GUARDS_TOPIC, schema_name="pdr.guards",
                                json_schema=load_schema("guards").json_schema(title="pdr.guards"),
                                fields={"t_s": t, "lower_rad": np.full(len(t), -guard),
                                        "upper_rad": np.full(len(t), guard)}))
    return out


def log_time_ns(t_s: np.ndarray) -> np.ndarray:
    """MCAP log_time: the sample time since the segment's first sample, in ns."""
    return np.round(np.asarray(t_s, dtype=np.float64) * 1e9).astype(np.uint64)


def mcap_metadata(cfg: RigConfig, report: dict, time_record: dict[str, str]) -> dict[str, dict[str, str]]:
    return {
        "rig_config": {"config": json.dumps(cfg.to_dict(), sort_keys=True),
                       "sources": json.dumps(cfg.sources, sort_keys=True)},
        "recording": {"source": str(report["recording"]), "sha256": report["sha256"], "run": report["run"]},
        "time": time_record,
    }


def write_signals(paths: RunPaths, df: pd.DataFrame, cfg: RigConfig, row_group_rows: int = ROW_GROUP_ROWS) -> None:
    """A run's signals.parquet, checked against the schema; the first ingest output of a run.

    The schema check runs in a helper thread while the row groups are encoded (~3 ms per million
    rows off the encoder's path); a table it refuses is never renamed into place (its temporary
    file is removed).  Encoded into Arrow's own buffered file (no Python call per page: ~1,200 of
    them per million rows through a Python file object), each row group's disk write started as
    soon as it is in the file (fdatasync in the helper thread) while the next is encoded: the
    closing fsync of ``atomic_path`` then finds little left to wait for (a 24 MB file synced only
    at the end waits 40-70 ms here).
    """
    remove_stale_temporaries(paths.root)
    where = str(paths.signals)
    table = signals_table(df, where, cfg, check=False)
    with ThreadPoolExecutor(max_workers=1) as helper, atomic_path(paths.signals) as tmp:
        done = [helper.submit(load_schema("signals", cfg).check_arrow, table, where)]
        fd = os.open(tmp, os.O_RDONLY | os.O_CLOEXEC)      # fdatasync through any descriptor syncs the file
        try:
            with pa.BufferedOutputStream(pa.OSFile(str(tmp), "wb"), SINK_BUFFER_BYTES) as sink, \
                    pq.ParquetWriter(sink, table.schema, **PARQUET_OPTIONS) as writer:
                for start in range(0, max(1, len(table)), row_group_rows):
                    writer.write_table(table.slice(start, row_group_rows), row_group_size=row_group_rows)
                    sink.flush()
                    if not syncs_deferred():
                        done.append(helper.submit(os.fdatasync, fd))
            for job in done:
                job.result()                # the check's refusal raised here, before the rename
        finally:
            wait(done)
            os.close(fd)


def write_run(paths: RunPaths, df: pd.DataFrame, report: dict, cfg: RigConfig) -> None:
    """The ingest outputs of one run after its ``write_signals``; each file replaced in one rename, the report last."""
    from pipeline.ingest.mcap_bulk import write_mcap
    from pipeline.ingest.timeline import log_time_origin
    segment = next((s for s in report.get("segments", ()) if s.get("run") == report.get("run")), None)
    origin, time_record = log_time_origin(segment)          # the capture's one time axis
    with atomic_path(paths.mcap) as tmp, open(tmp, "wb") as fh:
        write_mcap(fh, mcap_channels(df, cfg), log_time_ns(column(df, "t_s")) + np.uint64(origin),
                   mcap_metadata(cfg, report, time_record))
    write_json(paths.rig_config, {"config": cfg.to_dict(), "sources": cfg.sources})
    write_json(paths.ingest_report, report)
