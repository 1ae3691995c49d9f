"""Serial dialects and artefacts: how the sketch's lines reach a file on the PC.

``render`` turns the samples the board printed into the bytes a serial capture
holds, adding only the artefacts asked for in ``Artefacts`` (all off by
default, so a default recording is the plain docs/FORMAT.md format).  It
returns, for every sample, the physical line (1-based) it ended up on and its
fate ("ok", "garbled" or "dropped"), and a log of every injected artefact with
its line number, so tests can check that the ingest stage reports exactly
those lines.

Garbling is always detectable by a careful reader (a truncated line loses at
least one field, a flipped bit turns a digit into a letter, a merged line has
too many fields): serial noise that forges a valid-looking number is not
something a pipeline could report, so the rig does not produce it.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import numpy as np

STANDARD_COLUMNS = ("t_ms", "counts", "adc", "dir")
_COMMENTS = ("# guard reached", "# loop overrun", "# note: supply 12.0 V", "# pdr sketch v1")
_GARBLE_KINDS = ("truncated", "flipped", "merged")
# Other serial terminals' receive stamps (``terminal_stamp``); "putty" writes a log banner instead.
TERMINAL_STAMPS = ("bracketed", "bracketed-time", "iso8601", "iso8601-utc", "date-time", "ts", "ts-fraction",
                   "ts-epoch", "time-of-day", "putty")
CAPTURE_DAY = datetime(2026, 11, 25, tzinfo=timezone(timedelta(hours=1)))   # the PC's day; wall_s counts from it


@dataclass(frozen=True)
class Artefacts:
    """What the capture looks like; every field at its default gives the plain docs/FORMAT.md format."""

    header: bool = True                       # print the column header line (again after a reset)
    column_names: tuple[str, str, str, str] = STANDARD_COLUMNS   # names the sketch prints, in that order
    dir_column: bool = True                   # the sketch prints dir
    time_unit: str = "ms"                     # "ms" millis(), "us" micros(), "s" seconds with 3 decimals
    ide_prefix: str = ""                      # "", "classic" (12:34:56.789 -> ) or "ide2" (18:2:13.521 -> )
    terminal: str = ""                        # "" or another terminal's stamp, one of TERMINAL_STAMPS
    stamp_digits: int = 3                     # fraction-of-second digits in ``terminal`` stamps (0-9)
    crlf: bool = False                        # CRLF line endings
    bom: bool = False                         # UTF-8 byte-order mark
    comments: int = 0                         # '#' comment lines inserted
    blank_lines: int = 0                      # empty lines inserted
    partial_first_line: bool = False          # the capture starts in the middle of a line
    garbled: int = 0                          # data lines hit by serial noise (truncated, bit-flipped, merged)
    dropped: int = 0                          # data lines lost
    reset_after_s: float | None = None        # the board resets this long into the run (logging restarts)
    reset_gap_s: float = 60.0                 # s the rig sits unpowered before logging restarts (comes to rest)

    def __post_init__(self) -> None:
        if self.time_unit not in ("ms", "us", "s"):
            raise ValueError(f"time_unit must be 'ms', 'us' or 's', got {self.time_unit!r}")
        if self.ide_prefix not in ("", "classic", "ide2"):
            raise ValueError(f"ide_prefix must be '', 'classic' or 'ide2', got {self.ide_prefix!r}")
        if self.terminal not in ("", *TERMINAL_STAMPS):
            raise ValueError(f"terminal must be one of {TERMINAL_STAMPS}, got {self.terminal!r}")
        if self.terminal and self.ide_prefix:
            raise ValueError("a capture has one terminal: set ide_prefix or terminal, not both")
        if not 0 <= self.stamp_digits <= 9:
            raise ValueError(f"stamp_digits must be in 0..9, got {self.stamp_digits}")
        if len(self.column_names) != 4 or len(set(self.column_names)) != 4:
            raise ValueError(f"column_names must be 4 distinct names, got {self.column_names!r}")
        if min(self.comments, self.blank_lines, self.garbled, self.dropped) < 0:
            raise ValueError("artefact counts must be >= 0")
        if self.reset_after_s is not None and self.reset_after_s <= 0:
            raise ValueError(f"reset_after_s must be > 0, got {self.reset_after_s}")
        if self.reset_gap_s < 0:
            raise ValueError(f"reset_gap_s must be >= 0, got {self.reset_gap_s}")

    def columns_toml(self) -> dict[str, str] | None:
        """The ``[columns]`` table a user of this sketch writes, or None when the defaults fit."""
        if self.column_names == STANDARD_COLUMNS and self.dir_column and self.time_unit == "ms":
            return None
        t, c, a, d = self.column_names
        return {"t_ms": t, "counts": c, "adc": a, "dir": d if self.dir_column else "", "time_unit": self.time_unit}


@dataclass(frozen=True)
class SerialRows:
    """What the board printed, one entry per sample (all arrays of equal length)."""

    segment: np.ndarray       # 1, 2, ...: logging session (a reset starts a new one)
    true_ms: np.ndarray       # float ms since that session's boot (millis() is its floor)
    counts: np.ndarray
    adc: np.ndarray
    dir: np.ndarray
    wall_s: np.ndarray        # PC clock, s since midnight, when the line arrived (IDE prefix)


@dataclass(frozen=True)
class Rendered:
    data: bytes
    line: np.ndarray          # per sample: 1-based line in the file, 0 when dropped
    status: np.ndarray        # per sample: "ok", "garbled" or "dropped"
    injected: list[dict]      # {"kind", "line", "sample"} for every artefact line
    n_lines: int


@dataclass
class _Line:
    text: str
    kind: str                 # data, header, reset_header, comment, blank, partial, garbled
    samples: tuple[int, ...]
    wall_s: float


def time_text(true_ms: float, unit: str) -> str:
    """The timestamp field as the sketch prints it."""
    if unit == "us":
        return str(int(np.floor(true_ms * 1000.0)))
    ms = int(np.floor(true_ms))
    return str(ms) if unit == "ms" else f"{ms / 1000:.3f}"


def data_line(rows: SerialRows, i: int, art: Artefacts) -> str:
    fields = [time_text(float(rows.true_ms[i]), art.time_unit), str(int(rows.counts[i])), str(int(rows.adc[i]))]
    if art.dir_column:
        fields.append(str(int(rows.dir[i])))
    return ",".join(fields)


def ide_prefix(wall_s: float, style: str) -> str:
    """The Arduino IDE serial monitor's receive stamp: 1.x pads, 2.x does not."""
    total_ms = int(round(wall_s * 1000.0)) % (24 * 3600 * 1000)
    h, rem = divmod(total_ms, 3600 * 1000)
    m, rem = divmod(rem, 60 * 1000)
    s, ms = divmod(rem, 1000)
    if style == "classic":
        return f"{h:02d}:{m:02d}:{s:02d}.{ms:03d} -> "
    return f"{h}:{m}:{s}.{ms:03d} -> "


def terminal_stamp(wall_s: float, style: str, digits: int) -> str:
    """Another terminal's receive stamp of a line (with its separator), ``digits`` fraction digits, truncated.

    wall_s counts from the local midnight that starts ``CAPTURE_DAY`` (UTC+01:00).
    """
    ticks = int(np.floor(wall_s * 10**digits + 1e-6))
    whole, frac = divmod(ticks, 10**digits)
    local = CAPTURE_DAY + timedelta(seconds=whole)
    fraction = f".{frac:0{digits}d}" if digits else ""
    stamp = local.strftime("%H:%M:%S") + fraction
    ymd = local.strftime("%Y-%m-%d")
    utc = local.astimezone(timezone.utc)
    stamps = {
        "bracketed": f"[{ymd} {stamp}] ",
        "bracketed-time": f"[{stamp}] ",
        "iso8601": f"{ymd}T{stamp}+01:00 ",
        "iso8601-utc": f"{utc.strftime('%Y-%m-%dT%H:%M:%S')}{fraction}Z\t",
        "date-time": f"{ymd} {stamp} ",
        "ts": local.strftime("%b %d %H:%M:%S "),
        "ts-fraction": local.strftime("%b %d ") + stamp + " ",
        "ts-epoch": f"{int(local.timestamp())}{fraction} ",
        "time-of-day": f"{stamp} ",
    }
    if style not in stamps:
        raise ValueError(f"no per-line stamp for terminal {style!r}")
    return stamps[style]


def line_stamp(wall_s: float, art: Artefacts) -> str:
    """What the capture's terminal writes before a line: the IDE's stamp, another terminal's, or nothing."""
    if art.ide_prefix:
        return ide_prefix(wall_s, art.ide_prefix)
    if art.terminal and art.terminal != "putty":
        return terminal_stamp(wall_s, art.terminal, art.stamp_digits)
    return ""


def putty_banner(wall_s: float) -> str:
    """PuTTY's session log starts with one banner line naming when logging began; lines carry no stamps."""
    local = CAPTURE_DAY + timedelta(seconds=int(np.floor(wall_s)))
    return f"=~=~=~=~=~=~=~=~=~=~=~= PuTTY log {local.strftime('%Y.%m.%d %H:%M:%S')} =~=~=~=~=~=~=~=~=~=~=~="


def _eligible(rows: SerialRows) -> np.ndarray:
    """Samples that noise may hit: not the first three of a session, not the very last."""
    n = len(rows.segment)
    ok = np.ones(n, dtype=bool)
    for seg in np.unique(rows.segment):
        idx = np.flatnonzero(rows.segment == seg)
        ok[idx[:3]] = False
    ok[-1] = False
    return np.flatnonzero(ok)


def _garble(text: str, kind: str, rng: np.random.Generator) -> str:
    if kind == "truncated":                    # lose the last separator and what follows: a field goes missing
        cut = text.rfind(",")
        return text[: int(rng.integers(1, cut + 1))]
    digits = [i for i, ch in enumerate(text) if ch.isdigit()]
    i = digits[int(rng.integers(len(digits)))]
    return text[:i] + chr(ord(text[i]) ^ 0x40) + text[i + 1:]      # '0'..'9' -> 'p'..'y'


def render(rows: SerialRows, art: Artefacts, rng: np.random.Generator) -> Rendered:
    """The capture's bytes, with per-sample line numbers and the artefact log."""
    n = len(rows.segment)
    names = list(art.column_names[:4] if art.dir_column else art.column_names[:3])
    header = ",".join(names)
    status = np.array(["ok"] * n, dtype=object)

    eligible = _eligible(rows)
    dropped = set(int(i) for i in rng.choice(eligible, size=min(art.dropped, len(eligible)), replace=False)) \
        if art.dropped else set()
    garbled: dict[int, str] = {}
    if art.garbled:
        pool = [int(i) for i in eligible if int(i) not in dropped]
        order = rng.permutation(len(pool))
        for j in order:
            if sum(k != "merged_tail" for k in garbled.values()) >= art.garbled:
                break
            i = pool[int(j)]
            kind = _GARBLE_KINDS[int(rng.integers(len(_GARBLE_KINDS)))]
            if i in garbled:
                continue
            if kind == "merged" and (i + 1 >= n or i + 1 in garbled or i + 1 in dropped
                                     or rows.segment[i + 1] != rows.segment[i]):
                kind = "flipped"
            garbled[i] = kind
            if kind == "merged":
                garbled[i + 1] = "merged_tail"

    lines: list[_Line] = []
    for i in range(n):
        if i == 0 or rows.segment[i] != rows.segment[i - 1]:
            if art.header:
                lines.append(_Line(header, "header" if i == 0 else "reset_header", (), float(rows.wall_s[i])))
        if i in dropped:
            status[i] = "dropped"
            continue
        kind = garbled.get(i)
        if kind == "merged_tail":
            continue
        text = data_line(rows, i, art)
        if kind == "merged":                   # the newline between two lines was lost
            lines.append(_Line(text + data_line(rows, i + 1, art), "garbled", (i, i + 1), float(rows.wall_s[i + 1])))
            status[i] = status[i + 1] = "garbled"
        elif kind:
            lines.append(_Line(_garble(text, kind, rng), "garbled", (i,), float(rows.wall_s[i])))
            status[i] = "garbled"
        else:
            lines.append(_Line(text, "data", (i,), float(rows.wall_s[i])))

    first_body = 1 if art.header else 0
    for count, kind in ((art.comments, "comment"), (art.blank_lines, "blank")):
        for _ in range(count):
            at = int(rng.integers(first_body, len(lines) + 1))
            text = _COMMENTS[int(rng.integers(len(_COMMENTS)))] if kind == "comment" else ""
            lines.insert(at, _Line(text, kind, (), lines[at - 1].wall_s if at > 0 else float(rows.wall_s[0])))
    if art.partial_first_line:                 # the monitor opened in the middle of a line
        tail = data_line(rows, int(rng.integers(n)), art)
        lines.insert(0, _Line(tail[tail.index(",") + 1:], "partial", (), float(rows.wall_s[0]) - 0.02))

    if art.terminal == "putty":                # the log file opened a moment before the first line arrived
        lines.insert(0, _Line(putty_banner(lines[0].wall_s - 0.5), "banner", (), lines[0].wall_s - 0.5))
    line_of = np.zeros(n, dtype=np.int64)
    injected: list[dict] = []
    out: list[str] = []
    for number, ln in enumerate(lines, start=1):
        for s in ln.samples:
            line_of[s] = number
        if ln.kind == "garbled":
            injected.append({"kind": f"garbled_{garbled[ln.samples[0]]}", "line": number, "sample": ln.samples[0]})
        elif ln.kind not in ("data", "header"):
            injected.append({"kind": ln.kind, "line": number, "sample": None})
        out.append(line_stamp(ln.wall_s, art) + ln.text)
    for i in sorted(dropped):
        injected.append({"kind": "dropped", "line": None, "sample": i})
    eol = "\r\n" if art.crlf else "\n"
    data = (eol.join(out) + eol).encode("utf-8")
    if art.bom:
        data = b"\xef\xbb\xbf" + data
    return Rendered(data=data, line=line_of, status=status, injected=injected, n_lines=len(lines))

