"""The fast path for a clean capture: its bytes straight into typed columns (pure).

Most captures written by a sketch straight to a file (or by ``pdr rig``) are
plain: one header, rows of numbers, nothing else.  For those the whole parse
is one multi-threaded Arrow CSV read, or for a large capture of integers one
compiled pass (``plain_kernel``), which for a capture whose rows all keep the range
rules writes the signals columns themselves (``read_plain_signals``); anything
unusual sends the capture to the general path (``pipeline.ingest.parse.parse_capture``),
which reads line by line (still vectorised) and reports every line it cannot read.
"""

from __future__ import annotations

import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv

from pipeline.config import ColumnsConfig, RigConfig
from pipeline.errors import IngestError
from pipeline.ingest.convert import rad_per_count, volts_per_step
from pipeline.ingest.parse import (LOGICAL, TIME_RE, TRIM, ParsedFile, Segment, has_control_bytes, header_fields,
                                   layout_from_header, positional_layout)
from pipeline.ingest.plausible import needs_cleaning
from pipeline.ingest.timing import COUNTER_RANGE, UNIT_S

_PLAIN = b"0123456789,-.\r\n"
# From ~230k rows on, captures are read by the compiled reader (``plain_kernel``, ~4x less CPU than
# Arrow's read); smaller ones by Arrow, where the saving is under ~20 ms and would not cover the
# numba import and the load of its cached kernels (~0.4-0.5 s once per process).
KERNEL_MIN_BYTES = 4 << 20


@dataclass(frozen=True)
class PlainLayout:
    """What the first line of a plain capture says: where the rows start and which field is which."""

    header: bool                          # the first line names the columns (else it is a row)
    body_start: int                       # byte offset of the first row
    layout: dict[str, int]                # logical column -> field index
    width: int                            # fields per row
    notes: list[str]

    @property
    def first_line(self) -> int:
        """1-based line number of the first row."""
        return 2 if self.header else 1

    def parsed(self, values: dict[str, np.ndarray], line: np.ndarray) -> ParsedFile:
        """The parsed file of a plain capture: one segment, nothing quarantined."""
        n = len(line)
        seg = Segment(index=0, header_line=1 if self.header else None, layout=self.layout, width=self.width,
                      data_lines=n, line=line, values=values, notes=list(self.notes))
        return ParsedFile(segments=[seg], lines_total=n + self.header, blank_lines=0, comment_lines=0,
                          header_lines=[1] if self.header else [], quarantined=[], notes=[])


def plain_layout(data: bytes, columns: ColumnsConfig, source: str) -> PlainLayout | None:
    """The layout of a capture that may be plain, from its first line; None sends it to the general path."""
    first_end = data.find(b"\n") + 1
    if first_end == 0 or not data.endswith(b"\n"):
        return None
    try:
        first = data[:first_end].decode("utf-8").strip(TRIM)
    except UnicodeDecodeError:
        return None
    if not first or first.startswith("#") or first.startswith("\ufeff") or has_control_bytes(
            np.frombuffer(data[:first_end], dtype=np.uint8)):
        return None
    names = header_fields(first)
    header = not all(re.fullmatch(TIME_RE, f) for f in names)
    body_start = first_end if header else 0
    if body_start == len(data):
        return None
    if header:
        if columns.t_ms not in names or len(set(names)) != len(names):
            return None
        layout, notes = layout_from_header(names, columns, source, 1)
    else:
        try:
            layout = positional_layout(len(names), columns, source)
        except IngestError:
            return None                 # the general path looks at every line before refusing
        notes = [f"no header: {len(names)} fields read as {', '.join(layout)}"]
    return PlainLayout(header, body_start, layout, len(names), notes)


def _read_typed(rows: memoryview, lay: PlainLayout) -> dict[str, np.ndarray] | None:
    """The layout's columns of ``rows`` read by Arrow (t_raw float64, the others int64); None if any field fails."""
    col_names = [f"f{j}" for j in range(lay.width)]
    wanted = {col_names[j]: (logical, pa.float64() if logical == "t_raw" else pa.int64())
              for logical, j in lay.layout.items()}
    try:
        table = pcsv.read_csv(pa.py_buffer(rows), read_options=pcsv.ReadOptions(column_names=col_names),
                              parse_options=pcsv.ParseOptions(quote_char=False),
                              convert_options=pcsv.ConvertOptions(column_types={k: t for k, (_, t) in wanted.items()},
                                                                  include_columns=list(wanted), strings_can_be_null=False,
                                                                  null_values=[], quoted_strings_can_be_null=False))
    except pa.ArrowException:
        return None
    return {wanted[k][0]: table.column(k).to_numpy() for k in wanted}


def _read_compiled(rows: memoryview, lay: PlainLayout) -> dict[str, np.ndarray] | None:
    """The layout's columns of ``rows`` read by ``plain_kernel`` (integers only); None if it declines."""
    from pipeline.ingest.plain_kernel import read_int_rows
    out = read_int_rows(rows, lay.width, lay.layout["t_raw"])
    if out is None:
        return None
    return {logical: out[j].astype(np.float64) if logical == "t_raw" else out[j] for logical, j in lay.layout.items()}


def read_plain_rows(data: bytes, lay: PlainLayout) -> dict[str, np.ndarray] | None:
    """The rows of a capture (from ``lay.body_start``) -> raw columns (t_raw float64, the others int64);
    None when any line is not plain.

    Plain: every byte a digit, comma, sign, point or line break, no blank lines,
    every row has ``lay.width`` fields, every field converts, time never goes back.
    A large capture of integers is read by ``plain_kernel``, which checks all of that in
    its one pass.  Anything else (and what the kernel declines, such as decimal times) is
    read by Arrow, with the byte checks run while Arrow reads (it releases the GIL, and its
    reader leaves part of the second core idle); the rows are read in place (a memoryview),
    not copied out of the capture.
    """
    rows = memoryview(data)[lay.body_start:]
    if not rows:
        return None
    if len(rows) >= KERNEL_MIN_BYTES and (values := _read_compiled(rows, lay)) is not None:
        return values
    with ThreadPoolExecutor(max_workers=1) as pool:
        reading = pool.submit(_read_typed, rows, lay)
        # bytes.translate deletes the plain bytes: what is left must be the header's own letters
        plain = len(data.translate(None, _PLAIN)) == len(data[:lay.body_start].translate(None, _PLAIN))
        # one row per line feed: Arrow skips blank lines (also a lone "\r\n") and splits on a stray "\r",
        # so any of those shows as a count mismatch (a numpy count is ~10x cheaper than `b"\n\n" in data`)
        lines = np.count_nonzero(np.frombuffer(rows, dtype=np.uint8) == 10) if plain else 0
        values = reading.result()
    if not plain or values is None:
        return None
    t = values["t_raw"]
    if len(t) == 0 or len(t) != lines or (t[1:] < t[:-1]).any():
        return None
    return values


def parse_plain(data: bytes, columns: ColumnsConfig, source: str) -> ParsedFile | None:
    """Fast path for a clean capture: ``pyarrow.csv.read_csv`` straight into typed columns.

    Taken only when the first line is a header (or a row) the layout rules accept and
    ``read_plain_rows`` reads every other line; anything else returns None and the general
    path (``parse_capture``) reads the file line by line, vectorised, with reasons for the
    lines it cannot read.
    """
    lay = plain_layout(data, columns, source)
    values = read_plain_rows(data, lay) if lay else None
    if values is None:
        return None
    n = len(values["t_raw"])
    return lay.parsed(values, np.arange(lay.first_line, lay.first_line + n, dtype=np.int64))


def read_plain_signals(data: bytes, cfg: RigConfig, source: str) -> tuple[ParsedFile, dict[str, np.ndarray]] | None:
    """A large plain capture whose rows all keep the range rules, read straight into the signals columns
    (``plain_kernel.read_signals``: ``convert.to_signals``' columns and bits, but segment, and current_a
    when zero_v is "auto"), with its parsed file (one segment, nothing quarantined; adc int32, dir int8);
    None for anything else, which ``parse_plain`` or the general path reads.

    What the kernel takes, the general path would read as one segment with no row quarantined, no
    time going back or repeated, no reset (``segments``) and no impossible encoder jump
    (``plausible``): nothing is left to clean but the zero estimate.
    """
    if len(data) < KERNEL_MIN_BYTES:            # before the layout: small captures have theirs read once, by parse_plain
        return None
    lay = plain_layout(data, cfg.columns, source)
    if lay is None or len(data) - lay.body_start < KERNEL_MIN_BYTES or "counts" not in lay.layout:
        return None             # the kernel writes the encoder columns: a capture without them goes to parse_plain
    from pipeline.ingest.plain_kernel import read_signals
    cs, span = cfg.current_sensor, COUNTER_RANGE[cfg.columns.time_unit]
    configured = cs.zero_v != "auto"
    at = np.array([lay.width, *(lay.layout.get(k, -1) for k in LOGICAL), cs.adc_steps], dtype=np.int64)
    scale = [0.0, UNIT_S[cfg.columns.time_unit], span or np.inf, rad_per_count(cfg), volts_per_step(cfg),
             float(cs.zero_v) if configured else np.nan, cs.sensitivity_v_per_a]
    cols = read_signals(memoryview(data)[lay.body_start:], at, scale, lay.first_line, configured)
    if cols is None or needs_cleaning(cols["t_raw"], cols["counts"], cfg.columns.time_unit, cfg):
        return None
    return lay.parsed({k: cols[k] for k in lay.layout}, cols["line"]), cols
