"""Serial bytes, as they arrive, -> samples in SI units for the live view (pure state machine).

The grammar and the units are ingest's own (``pipeline.ingest.parse`` for
lines, headers and layouts, ``pipeline.ingest.convert`` for range rules and
units), applied one line at a time because the capture is still growing.
What the live view shows is therefore what the run will hold, up to the
checks that need the whole file (time order, lone outliers).

Chunks carry their byte offset in the capture.  When the live view's queue
dropped some (a slow viewer), the next chunk's offset skips ahead: the
decoder discards the broken line and picks up at the next line ending, so a
dropped frame never becomes a garbled sample.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from pipeline.config import RigConfig
from pipeline.errors import IngestError
from pipeline.ingest.convert import amps, estimate_zero, range_violations, rad_per_count, volts_per_step
from pipeline.ingest.parse import BOM, IDE_PREFIX, TRIM, has_control_bytes, header_fields, layout_from_header, \
    parse_line, positional_layout
from pipeline.ingest.timing import UNIT_S

_PREFIX = re.compile(IDE_PREFIX)
EARLY_LINES = 20              # data lines before any header after which they are read positionally


@dataclass
class Samples:
    """Samples decoded from one batch of chunks, in arrival order."""

    t_s: np.ndarray               # s on the capture's running time axis (segments laid end to end)
    theta_rad: np.ndarray
    current_a: np.ndarray         # NaN while the sensor zero is unknown or adc not logged
    dir: np.ndarray               # int8; 0 when dir is not logged
    segment: np.ndarray           # 1, 2, ...: a repeated header (board reset) starts the next
    has_dir: bool = True          # the sketch logs dir (else the mode is not known sample by sample)

    def __len__(self) -> int:
        return len(self.t_s)


@dataclass
class Tally:
    lines: int = 0                # complete lines seen
    samples: int = 0
    unparsed: int = 0             # lines that are neither data, header, comment nor blank, or break a range rule
    switches: int = 0             # dir reversals (+1 <-> -1) within a segment
    skipped_lines: int = 0        # lines lost to the view (never to the file) by dropped frames
    segment: int = 0


@dataclass
class LineDecoder:
    cfg: RigConfig
    source: str = "live"
    tally: Tally = field(default_factory=Tally)
    _pending: bytes = b""
    _next_offset: int = 0
    _resync: bool = False
    _layout: dict[str, int] | None = None
    _width: int = 0
    _seg_has_data: bool = False
    _t_offset: float = 0.0
    _last_t: float | None = None
    _first_t_raw: float = 0.0
    _time_segment: int = 0
    _last_dir: int = 0            # the last sample's dir, and its segment
    _dir_segment: int = 0
    _zero_v: float | None = None
    _zero_segment: int = 0
    _rest: dict[str, list[int]] = field(default_factory=dict)
    _earlier_zero: float | None = None       # the last earlier segment's own zero (the sensor part's)
    _early: list[str] = field(default_factory=list)
    _sep: bytes = b"\n"
    _seen_lf: bool = False

    def __post_init__(self) -> None:
        zero = self.cfg.current_sensor.zero_v
        self._zero_v = None if zero == "auto" else float(zero)

    def feed(self, chunks: list[tuple[int, bytes]]) -> Samples:
        """Decode every complete line of the chunks (offset, bytes); a partial last line waits for the next."""
        rows: list[tuple[int, dict]] = []
        for offset, data in chunks:
            if offset != self._next_offset:
                self._pending, self._resync = b"", True
                self.tally.skipped_lines += 1
            self._next_offset = offset + len(data)
            buf = self._pending + data
            if self._sep == b"\n" and not self._seen_lf:      # CR-only endings, as ingest accepts them
                self._seen_lf = b"\n" in buf
                if not self._seen_lf and buf.count(b"\r") >= 2:
                    self._sep = b"\r"
            lines = buf.split(self._sep)
            self._pending = lines.pop()
            for raw in lines:
                if self._resync:
                    self._resync = False
                    continue
                self._line(raw, rows)
        return self._samples(rows)

    def _line(self, raw: bytes, rows: list[tuple[int, dict]]) -> None:
        self.tally.lines += 1
        if self.tally.lines == 1 and raw.startswith(BOM):
            raw = raw[len(BOM):]
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            self.tally.unparsed += 1
            return
        if has_control_bytes(np.frombuffer(raw, dtype=np.uint8)):
            self.tally.unparsed += 1
            return
        text = _PREFIX.sub("", text.strip(TRIM)).strip(TRIM)
        if not text or text.startswith("#"):
            return
        columns = self.cfg.columns
        names = header_fields(text)
        if columns.t_ms and columns.t_ms in names:
            try:
                layout, _notes = layout_from_header(names, columns, self.source, self.tally.lines)
            except IngestError:
                self.tally.unparsed += 1
                return
            early, self._early = self._early, []
            if early:                           # rows before the first header: ingest's segment of their own
                self._new_segment(layout, len(names))
                for line in early:
                    self._row(line, rows)
            self._new_segment(layout, len(names))
            return
        if self._layout is None:                # ingest reads these with the first header's layout, if any:
            self._early.append(text)            # wait for it, a few lines at most
            if len(self._early) >= EARLY_LINES:
                self._positional(rows)
            return
        self._row(text, rows)

    def _row(self, text: str, rows: list[tuple[int, dict]]) -> None:
        values = parse_line(text, self._layout, self._width)
        if isinstance(values, str):
            self.tally.unparsed += 1
            return
        self._seg_has_data = True
        rows.append((self.tally.segment, values))

    def _positional(self, rows: list[tuple[int, dict]]) -> None:
        """No header came: the fields in docs/FORMAT.md order, as many as most early lines have (as ingest)."""
        early, self._early = self._early, []
        width = int(np.bincount([len(header_fields(t)) for t in early]).argmax())
        try:
            self._new_segment(positional_layout(width, self.cfg.columns, self.source), width)
        except IngestError:
            self.tally.unparsed += len(early)
            return
        for line in early:
            self._row(line, rows)

    def finish(self) -> Samples:
        """The capture ended: its last line even without a line ending, and any lines still waiting."""
        rows: list[tuple[int, dict]] = []
        pending, self._pending = self._pending, b""
        if pending and not self._resync:
            self._line(pending, rows)
        if self._early:
            self._positional(rows)
        return self._samples(rows)

    def _new_segment(self, layout: dict[str, int], width: int) -> None:
        if self._seg_has_data or self._layout is None:
            self.tally.segment += 1
            self._seg_has_data = False
        self._layout, self._width = layout, width

    def _samples(self, rows: list[tuple[int, dict]]) -> Samples:
        n = len(rows)
        values = {k: np.array([r[1].get(k, 0) for r in rows], dtype=np.float64 if k == "t_raw" else np.int64)
                  for k in ("t_raw", "counts", "adc", "dir")}
        logged = set(self._layout or {})
        checked = {k: v for k, v in values.items() if k in logged or k == "t_raw"}
        bad, _reasons = range_violations(checked, self.cfg) if n else (np.zeros(0, dtype=bool), {})
        self.tally.unparsed += int(bad.sum())
        keep = ~bad
        values = {k: v[keep] for k, v in values.items()}
        segment = np.array([r[0] for r in rows], dtype=np.int64)[keep]
        t_s = np.empty(len(segment))
        unit = UNIT_S[self.cfg.columns.time_unit]
        for i, (t_raw, seg) in enumerate(zip(values["t_raw"], segment)):
            if seg != self._time_segment:       # lay a new segment after the last sample, one period on
                self._time_segment, self._first_t_raw = int(seg), float(t_raw)
                self._t_offset = 0.0 if self._last_t is None else self._last_t + self.cfg.controller.period_s
            self._last_t = t_s[i] = self._t_offset + (t_raw - self._first_t_raw) * unit
        d = values["dir"].astype(np.int8)
        self._count_switches(d, segment)
        self.tally.samples += len(t_s)
        current = self._current(values, segment, logged) if "adc" in logged else np.full(len(t_s), np.nan)
        theta = values["counts"] * rad_per_count(self.cfg) if "counts" in logged else np.full(len(t_s), np.nan)
        return Samples(t_s=t_s, theta_rad=theta, current_a=current,
                       dir=d, segment=segment, has_dir="dir" in logged)

    def _count_switches(self, d: np.ndarray, segment: np.ndarray) -> None:
        """Reversals as the validation counts them, carried across batches within a segment."""
        from pipeline.validate.compare import switch_indices

        for seg in np.unique(segment):
            ds = d[segment == seg]
            prev = self._last_dir if seg == self._dir_segment else 0
            self.tally.switches += len(switch_indices(np.r_[np.int8(prev), ds]))
            self._last_dir, self._dir_segment = int(ds[-1]), int(seg)

    def _current(self, values: dict[str, np.ndarray], segment: np.ndarray, logged: set[str]) -> np.ndarray:
        """Amps with ingest's formula; with ``zero_v = "auto"``, NaN until rest samples give the zero.

        As ingest, each segment (a board reset) gets its own zero, from its
        rest samples: re-estimated with each batch until the motor has run, then kept; a segment with
        none at rest takes the last earlier segment's.
        """
        out = np.full(len(segment), np.nan)
        for seg in np.unique(segment):
            rows = segment == seg
            adc = values["adc"][rows]
            if self._zero_segment != seg and self.cfg.current_sensor.zero_v == "auto":
                if self._zero_v is not None:
                    self._earlier_zero = self._zero_v
                self._zero_segment, self._zero_v, self._rest = int(seg), None, {}
            zero = self._zero_v if self._zero_v is not None else self._estimate_zero(values, rows, logged)
            if zero is not None:
                out[rows] = amps(adc * volts_per_step(self.cfg), zero, self.cfg)
        return out

    def _estimate_zero(self, values: dict[str, np.ndarray], rows: np.ndarray, logged: set[str]) -> float | None:
        motion = "dir" if "dir" in logged else "counts"
        for key in ("adc", *(k for k in ("dir", "counts") if k in logged)):
            self._rest.setdefault(key, []).extend(values[key][rows].tolist())
        rest = {k: np.array(v, dtype=np.int64) for k, v in self._rest.items()}
        try:
            zero = estimate_zero(rest, self.cfg, self.source).zero_v
        except IngestError:
            zero = self._earlier_zero          # none at rest in this segment: the part's, as ingest takes it
        moved = np.any(rest["dir"] != 0) if motion == "dir" else np.any(rest["counts"] != rest["counts"][0])
        if moved and zero is not None:
            self._zero_v = zero
        return zero
