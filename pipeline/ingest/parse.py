"""Raw serial capture bytes -> per-segment raw columns + quarantined lines (pure).

The hot path is vectorised with pyarrow compute: lines are cut out of the
byte buffer by offset (zero copy), trimmed, split on commas and converted
column by column.  Python only touches the lines that fail that path, to say
why (``parse_line``), so a clean 1,000,000-row file creates no per-row
Python objects.  The grammar of a valid line lives in ``INT_RE``/``TIME_RE``
and is shared by both paths.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pipeline.config import ColumnsConfig
from pipeline.errors import IngestError
from pipeline.ingest.prefix import BY_NAME, PrefixInfo, strip_prefixes

BOM = b"\xef\xbb\xbf"
TRIM = " \t\r\n"
LONE_CR = re.compile(rb"\r(?!\n)")
IDE_PREFIX = BY_NAME["arduino-ide"].pattern        # the Arduino IDE monitor's stamp; every terminal's: prefix.py
INT_RE = r"-?[0-9]{1,18}"
TIME_RE = r"-?[0-9]{1,15}(\.[0-9]{1,9})?"
LOGICAL = ("t_raw", "counts", "adc", "dir")        # raw columns in docs/FORMAT.md order
QUOTE_LIMIT = 80                                   # characters of a bad line kept in the report


@dataclass(frozen=True)
class Quarantined:
    line: int
    reason: str
    text: str

    def to_dict(self) -> dict:
        return {"line": self.line, "reason": self.reason, "text": self.text}


@dataclass
class Segment:
    """One logging segment (a board reset starts the next) with its raw columns."""

    index: int
    header_line: int | None
    layout: dict[str, int]                  # logical column -> field index
    width: int                              # fields per row
    data_lines: int                         # candidate data lines in the segment
    line: np.ndarray                        # 1-based raw line numbers of parsed rows
    values: dict[str, np.ndarray]           # t_raw float64; counts, adc, dir int64 (adc int32, dir int8 from
                                            # plain.read_plain_signals, whose kernel checks their ranges)
    quarantined: list[Quarantined] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    raw_text: pa.Array | None = None        # the segment's data lines, for re-framing phase-shifted rows
    raw_lines: np.ndarray | None = None

    def select(self, keep: np.ndarray) -> None:
        self.line = self.line[keep]
        self.values = {k: v[keep] for k, v in self.values.items()}


@dataclass
class ParsedFile:
    segments: list[Segment]
    lines_total: int
    blank_lines: int
    comment_lines: int
    header_lines: list[int]
    quarantined: list[Quarantined]           # lines outside any segment's rows (text, bad bytes)
    notes: list[str]
    prefix: PrefixInfo | None = None         # the serial terminal's time stamps, when the lines carry them


def _q(line: int, reason: str, text: str) -> Quarantined:
    return Quarantined(line, reason, text[:QUOTE_LIMIT])


# --------------------------------------------------------------------------- lines

def split_lines(data: bytes, source: str) -> tuple[pa.Array, list[Quarantined], list[str], PrefixInfo | None]:
    """Lines without terminators, trimmed and without terminal time stamps; undecodable lines blanked and reported."""
    notes: list[str] = []
    if not data.strip(b" \t\r\n"):
        raise IngestError("empty file: expected CSV lines of samples (t_ms,counts,adc,dir)", path=source)
    if data.startswith(BOM):
        data = data[len(BOM):]
        notes.append("UTF-8 byte-order mark removed")
    sep = b"\n" if b"\n" in data or b"\r" not in data else b"\r"
    if sep == b"\r":
        notes.append("CR-only line endings")
    elif b"\r" in data and LONE_CR.search(data):
        # a capture appended to by tools of different systems: a lone CR ends a line as LF and CRLF do
        data = LONE_CR.sub(b"\n", data)
        notes.append("mixed line endings (a lone CR read as a line ending)")
    if not data.endswith((b"\n", b"\r")):
        notes.append("last line has no line ending (capture stopped mid-line, or the writer left it out)")
    bad: list[Quarantined] = []
    try:
        data.decode("utf-8")
        clean = not has_control_bytes(np.frombuffer(data, dtype=np.uint8))
    except UnicodeDecodeError:
        clean = False
    if not clean:
        data, bad = _blank_undecodable(data, sep)
        content = sum(1 for ln in data.split(sep) if ln.strip(b" \t\r\n")) + len(bad)
        if len(bad) > content / 2:
            raise IngestError(f"binary or non-UTF-8 content: {len(bad)} of {content} lines hold NUL, control "
                              f"or non-UTF-8 bytes; expected a UTF-8 CSV capture", path=source, line=bad[0].line)
    buf = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(buf == sep[0])
    offsets = np.concatenate(([0], ends + 1)).astype(np.int64)
    if offsets[-1] != len(data):
        offsets = np.append(offsets, len(data))
    n = len(offsets) - 1
    lines = pa.LargeStringArray.from_buffers(n, pa.py_buffer(offsets), pa.py_buffer(data))     # zero copy
    text = pc.utf8_trim(lines, characters=TRIM)
    text, prefix = strip_prefixes(text, TRIM)
    if prefix is not None and prefix.lines:
        notes.append(f"{BY_NAME[prefix.dialect].label} timestamp prefix removed from {prefix.lines} lines "
                     f"(first sample at {prefix.wall_clock_start})")
    if prefix is not None and prefix.banner:
        notes.append(f"PuTTY log banner at line {prefix.banner_line} read as a comment")
    return text, bad, notes, prefix


def has_control_bytes(buf: np.ndarray) -> bool:
    """NUL and other C0 control bytes (tab, CR, LF allowed): a binary file, or serial noise on that line."""
    ctrl = (buf < 32) | (buf == 127)
    return bool(ctrl.any() and (ctrl & (buf != 9) & (buf != 10) & (buf != 13)).any())


def _blank_undecodable(data: bytes, sep: bytes) -> tuple[bytes, list[Quarantined]]:
    """Slow path: lines with control bytes or invalid UTF-8 become empty (numbering kept) and are reported."""
    out, bad = [], []
    for i, raw in enumerate(data.split(sep), start=1):
        try:
            raw.decode("utf-8")
            ok = not has_control_bytes(np.frombuffer(raw, dtype=np.uint8))
        except UnicodeDecodeError:
            ok = False
        if ok:
            out.append(raw)
        else:
            bad.append(_q(i, "binary or non-UTF-8 bytes", raw.decode("utf-8", "replace").encode("unicode_escape").decode()))
            out.append(b"")
    return sep.join(out), bad


# --------------------------------------------------------------------------- layout

def header_fields(text: str) -> list[str]:
    return [f.strip(TRIM) for f in text.split(",")]


def layout_from_header(names: list[str], columns: ColumnsConfig, source: str, line: int) -> tuple[dict[str, int], list[str]]:
    """Map logical columns to field positions by the names in ``[columns]``; t and counts (unless
    ``counts = ""``: a capture without an encoder) are required."""
    wanted = {"t_raw": columns.t_ms, "counts": columns.counts, "adc": columns.adc, "dir": columns.dir}
    layout, notes = {}, []
    for logical, name in wanted.items():
        if not name:
            continue
        if name in names:
            layout[logical] = names.index(name)
        elif logical in ("t_raw", "counts"):
            key = "t_ms" if logical == "t_raw" else "counts"
            hint = " (or counts = \"\" when the capture has no encoder)" if key == "counts" else ""
            raise IngestError(f"no recognisable columns: expected a column named '{name}' (columns.{key}) "
                              f"in the header, found {names}; set [columns] in the rig TOML{hint}",
                              path=source, line=line)
        else:
            notes.append(f"column '{name}' (columns.{logical}) not in the header: {logical} not logged")
    if "counts" not in layout and "adc" not in layout:
        raise IngestError(f"no recognisable columns: no encoder column (columns.counts = \"\") and no column named "
                          f"'{columns.adc}' (columns.adc) in the header, found {names}: nothing pdr can process",
                          path=source, line=line)
    return layout, notes


def positional_layout(width: int, columns: ColumnsConfig, source: str) -> dict[str, int]:
    """No header: fields in docs/FORMAT.md order (t_ms, counts, adc, dir), skipping columns not logged."""
    raw = dict(zip(LOGICAL, (columns.t_ms, columns.counts, columns.adc, columns.dir)))
    names = [lg for lg, name in raw.items() if name]
    if width < 2 or "t_raw" not in names[:1] or len(names) < 2:
        first, *rest = [{"t_raw": "t_ms"}.get(lg, lg) for lg in names]
        shown = ",".join([first, *rest[:1]]) + "".join(f"[,{x}" for x in rest[1:]) + "]" * (len(rest) - 1)
        raise IngestError(f"no recognisable columns: no header line naming '{columns.t_ms}' and rows of "
                          f"{width} field(s); expected rows {shown}", path=source)
    return {lg: i for i, lg in enumerate(names[:width])}


# --------------------------------------------------------------------------- one line (slow path, reasons)

def parse_line(text: str, layout: dict[str, int], width: int) -> dict[str, float | int] | str:
    """Parse one trimmed line: the values by logical column, or the reason it cannot be read."""
    fields = [f.strip(TRIM) for f in text.split(",")]
    if len(fields) != width:
        kind = "text, not a data line: " if re.search("[A-Za-z]{3}", text) else ""
        return f"{kind}expected {width} fields, got {len(fields)}"
    out: dict[str, float | int] = {}
    for logical, j in layout.items():
        raw = fields[j]
        pattern = TIME_RE if logical == "t_raw" else INT_RE
        if not re.fullmatch(pattern, raw):
            kind = "a number" if logical == "t_raw" else "an integer"
            return f"{logical}: expected {kind}, got {raw!r}"
        out[logical] = float(raw) if logical == "t_raw" else int(raw)
    return out


def format_line(values: dict[str, float | int], layout: dict[str, int], width: int, sep: str = ",") -> str:
    """Inverse of ``parse_line`` (fields not in the layout are written as 0)."""
    fields = ["0"] * width
    for logical, j in layout.items():
        v = values[logical]
        fields[j] = str(int(v)) if logical != "t_raw" or float(v).is_integer() else repr(float(v))
    return sep.join(fields)


# --------------------------------------------------------------------------- vectorised rows

def _take_column(flat: pa.Array, n: int, width: int, j: int) -> pa.Array:
    return flat.take(pa.array(np.arange(n, dtype=np.int64) * width + j))


def _convert(col: pa.Array, logical: str) -> tuple[np.ndarray, np.ndarray]:
    """Values and validity of one column of field strings (the grammar of ``parse_line``)."""
    pattern = "^" + (TIME_RE if logical == "t_raw" else INT_RE) + "$"
    ok = pc.match_substring_regex(col, pattern)
    okn = ok.to_numpy(zero_copy_only=False)
    filled = col if okn.all() else pc.if_else(ok, col, "0")
    typ = pa.float64() if logical == "t_raw" else pa.int64()
    return pc.cast(filled, typ).to_numpy(zero_copy_only=False), okn


def rows_from_lines(text: pa.Array, line_numbers: np.ndarray, layout: dict[str, int], width: int
                    ) -> tuple[np.ndarray, dict[str, np.ndarray], list[Quarantined]]:
    """Vectorised parse of data lines; the few that fail get their reason from ``parse_line``."""
    parts = pc.split_pattern(text, ",")
    nf = pc.list_value_length(parts).to_numpy(zero_copy_only=False)
    good = nf == width
    goodparts = parts.filter(pa.array(good))
    flat = pc.utf8_trim(pc.list_flatten(goodparts), characters=TRIM)
    n = int(good.sum())
    values, ok = {}, np.ones(n, dtype=bool)
    for logical, j in layout.items():
        values[logical], valid = _convert(_take_column(flat, n, width, j), logical)
        ok &= valid
    good_idx = np.flatnonzero(good)
    keep_idx = good_idx[ok]
    bad_idx = np.sort(np.concatenate((np.flatnonzero(~good), good_idx[~ok])))
    quarantined = []
    for i in bad_idx:
        t = text[int(i)].as_py()
        reason = parse_line(t, layout, width)
        quarantined.append(_q(int(line_numbers[i]), reason if isinstance(reason, str) else "unreadable", t))
    return line_numbers[keep_idx], {k: v[ok] for k, v in values.items()}, quarantined


# --------------------------------------------------------------------------- whole file

def parse_capture(data: bytes, columns: ColumnsConfig, source: str) -> ParsedFile:
    """Bytes of one capture -> segments split at repeated headers, with every unread line reported.

    The general path; ``pipeline.ingest.plain.parse_plain`` is the shortcut for clean captures.
    """
    text, bad_bytes, notes, prefix = split_lines(data, source)
    n = len(text)
    length = pc.utf8_length(text).to_numpy(zero_copy_only=False)
    blank = length == 0
    comment = pc.starts_with(text, "#").to_numpy(zero_copy_only=False)
    wordy = pc.match_substring_regex(text, "[A-Za-z_(]").to_numpy(zero_copy_only=False) & ~comment & ~blank
    header_idx = [int(i) for i in np.flatnonzero(wordy)
                  if columns.t_ms and columns.t_ms in header_fields(text[int(i)].as_py())]
    content = np.flatnonzero(~blank & ~comment)
    if not header_idx and len(content):
        first = header_fields(text[int(content[0])].as_py())
        if len(first) >= 2 and not any(re.fullmatch(TIME_RE, f) for f in first):
            key = "counts" if columns.counts else "adc"
            raise IngestError(f"no recognisable columns: the header names {first}, expected '{columns.t_ms}' "
                              f"(columns.t_ms) and '{getattr(columns, key)}' (columns.{key}); set [columns] in the "
                              f"rig TOML", path=source, line=int(content[0]) + 1)
    quarantined = list(bad_bytes)
    is_header = np.zeros(n, dtype=bool)
    is_header[header_idx] = True
    data_mask = ~blank & ~comment & ~is_header
    bounds = [0, *header_idx, n]
    segments: list[Segment] = []
    first_layout = None
    if header_idx:
        first_layout = layout_from_header(header_fields(text[header_idx[0]].as_py()), columns, source,
                                          header_idx[0] + 1)
    for k in range(len(bounds) - 1):
        start, stop = bounds[k], bounds[k + 1]
        header = start if k > 0 else None
        idx = np.flatnonzero(data_mask[start:stop]) + start
        if header is None and not len(idx):
            continue
        seg_notes: list[str] = []
        if header is not None:
            names = header_fields(text[header].as_py())
            layout, seg_notes = layout_from_header(names, columns, source, header + 1)
            width = len(names)
        elif first_layout is not None:
            layout, seg_notes = first_layout
            width = len(header_fields(text[header_idx[0]].as_py()))
            seg_notes = [*seg_notes, "rows before the first header (logging was running when the capture started)"]
        else:
            counts = pc.list_value_length(pc.split_pattern(text.take(pa.array(idx)), ",")).to_numpy(zero_copy_only=False)
            width = int(np.bincount(counts).argmax())
            layout = positional_layout(width, columns, source)
            seg_notes.append(f"no header: {width} fields read as {', '.join(layout)}")
        seg_text = text.take(pa.array(idx, type=pa.int64()))
        line, values, q = rows_from_lines(seg_text, idx + 1, layout, width)
        seg = Segment(index=len(segments), header_line=None if header is None else header + 1, layout=layout,
                      width=width, data_lines=len(idx), line=line, values=values, quarantined=q, notes=seg_notes,
                      raw_text=seg_text, raw_lines=idx + 1)
        segments.append(seg)
    if not segments and bad_bytes:
        raise IngestError(f"binary or non-UTF-8 content: {len(bad_bytes)} of {n} lines, none readable as text; "
                          f"expected a UTF-8 CSV capture", path=source, line=bad_bytes[0].line)
    if not segments:
        raise IngestError("no recognisable columns: no data rows of numbers found", path=source)
    return ParsedFile(segments=segments, lines_total=n, blank_lines=int(blank.sum()) - len(bad_bytes),
                      comment_lines=int(comment.sum()), header_lines=[i + 1 for i in header_idx],
                      quarantined=quarantined, notes=notes, prefix=prefix)


def reframe(seg: Segment) -> tuple[np.ndarray, dict[str, np.ndarray], list[Quarantined], int]:
    """Re-cut a segment's fields into ``width``-field records, ignoring where the line breaks fell.

    A capture script that reads a fixed number of fields per row and started
    mid-record writes every row phase-shifted (akafael 204516: the first row has
    3 fields, every later row starts with the previous sample's last field).
    The field stream is intact, so records are recovered by re-cutting it; each
    record keeps the line number of its first field.  Returns rows, the
    unreadable records and how many trailing fields were left over.
    """
    parts = pc.split_pattern(seg.raw_text, ",")
    nf = pc.list_value_length(parts).to_numpy(zero_copy_only=False)
    flat = pc.utf8_trim(pc.list_flatten(parts), characters=TRIM)
    field_line = np.repeat(seg.raw_lines, nf)
    w = seg.width
    n = len(flat) // w
    values, ok = {}, np.ones(n, dtype=bool)
    for logical, j in seg.layout.items():
        values[logical], valid = _convert(_take_column(flat, n, w, j), logical)
        ok &= valid
    line = field_line[np.arange(n, dtype=np.int64) * w]
    quarantined = [_q(int(line[i]), "re-framed record: " + str(parse_line(",".join(flat[i * w:(i + 1) * w].to_pylist()),
                                                                          seg.layout, w)), "")
                   for i in np.flatnonzero(~ok)]
    leftover = len(flat) - n * w
    if leftover:
        rest = flat[n * w:].to_pylist()
        quarantined.append(_q(int(field_line[n * w]), f"incomplete record at the end: {len(rest)} of {w} fields",
                              ",".join(rest)))
    return line[ok], {k: v[ok] for k, v in values.items()}, quarantined, leftover
