"""The fast path for a clean capture: ``pyarrow.csv.read_csv`` straight into typed columns (pure).

Most captures written by a sketch straight to a file (or by ``pdr rig``) are
plain: one header, rows of numbers, nothing else.  For those the whole parse
is one multi-threaded Arrow CSV read; anything unusual sends the capture to
the general path (``pipeline.ingest.parse.parse_capture``), which reads line by
line (still vectorised) and reports every line it cannot read.
"""

from __future__ import annotations

import re

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv

from pipeline.config import ColumnsConfig
from pipeline.errors import IngestError
from pipeline.ingest.parse import (TIME_RE, TRIM, ParsedFile, Segment, has_control_bytes, header_fields,
                                   layout_from_header, positional_layout)

_PLAIN = b"0123456789,-.\r\n"


def parse_plain(data: bytes, columns: ColumnsConfig, source: str) -> ParsedFile | None:
    """Fast path for a clean capture: ``pyarrow.csv.read_csv`` straight into typed columns.

    Taken only when every byte after the header line is a digit, comma, sign,
    point or line break, there are no blank lines, every row has the header's
    field count, every field converts and time never goes back; anything else
    returns None and the general path (``parse_capture``) reads the file line
    by line, vectorised, with reasons for the lines it cannot read.
    """
    body_start = data.find(b"\n") + 1
    if body_start == 0 or not data.endswith(b"\n"):
        return None
    try:
        first = data[:body_start].decode("utf-8").strip(TRIM)
    except UnicodeDecodeError:
        return None
    if not first or first.startswith("#") or first.startswith("\ufeff") or has_control_bytes(
            np.frombuffer(data[:body_start], dtype=np.uint8)):
        return None
    names = header_fields(first)
    header = not all(re.fullmatch(TIME_RE, f) for f in names)
    body = data[body_start:] if header else data
    if not len(body) or body.translate(None, _PLAIN):
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
    width = len(names)
    col_names = [f"f{j}" for j in range(width)]
    wanted = {col_names[j]: (logical, pa.float64() if logical == "t_raw" else pa.int64())
              for logical, j in layout.items()}
    try:
        table = pcsv.read_csv(pa.py_buffer(body), read_options=pcsv.ReadOptions(column_names=col_names),
                              parse_options=pcsv.ParseOptions(quote_char=False),
                              convert_options=pcsv.ConvertOptions(column_types={k: t for k, (_, t) in wanted.items()},
                                                                  include_columns=list(wanted), strings_can_be_null=False,
                                                                  null_values=[], quoted_strings_can_be_null=False))
    except pa.ArrowException:
        return None
    values = {wanted[k][0]: table.column(k).to_numpy() for k in wanted}
    n = table.num_rows
    t = values["t_raw"]
    # one row per line feed: Arrow skips blank lines (also a lone "\r\n") and splits on a stray "\r",
    # so any of those shows as a count mismatch (a numpy count is ~10x cheaper than `b"\n\n" in data`)
    if n == 0 or n != np.count_nonzero(np.frombuffer(body, dtype=np.uint8) == 10) or (t[1:] < t[:-1]).any():
        return None
    first_line = 2 if header else 1
    seg = Segment(index=0, header_line=1 if header else None, layout=layout, width=width, data_lines=n,
                  line=np.arange(first_line, first_line + n, dtype=np.int64), values=values, notes=notes)
    return ParsedFile(segments=[seg], lines_total=n + (1 if header else 0), blank_lines=0, comment_lines=0,
                      header_lines=[1] if header else [], quarantined=[], notes=[])
