"""Serial terminals' time stamps in front of each line: detect the one the data lines share, strip it (pure).

A terminal that logs a serial port often writes its receive time before every
line (the Arduino IDE monitor, tio, CoolTerm, moreutils ``ts``) or a banner at
the top (PuTTY).  The sketch's own columns follow unchanged, so stripping the
stamp gives back the line the board printed, byte for byte.  Which form a file
uses is decided once, by the dialect that matches the most lines (ties go to
the more specific, earlier entry of ``DIALECTS``) and stripped wherever it
matches: a stamp is common to the data lines (the IDE lets a user switch its
stamps on mid-session, so not every line need carry one), and deciding per
line would let one garbled line pick its own reading.  What the stamp says is kept: the wall-clock time the first sample
arrived is recorded in the ingest report (``PrefixInfo.to_dict``).

Every pattern is RE2 syntax (Arrow's regex engine) as well as Python's, so the
same text detects and strips vectorised and is read back by ``re`` for the one
stamp the report needs.  Fractions of a second have any number of digits.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

_FRAC = r"(?:[.,](?P<frac>[0-9]+))?"
_HMS = r"(?P<time>[0-9]{1,2}:[0-9]{1,2}:[0-9]{1,2})"
_DATE = r"(?P<date>[0-9]{4}[-/.][0-9]{1,2}[-/.][0-9]{1,2})"
_TZ = r"(?P<tz>Z|[+-][0-9]{2}(?::?[0-9]{2})?)?"
_GAP = r"(?:[ \t]*(?:->|>|\|)[ \t]*|[ \t]+|$)"          # what separates a stamp from the line it stamps
_MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")


@dataclass(frozen=True)
class Dialect:
    name: str
    label: str              # how notes name it
    pattern: str            # anchored at the line start, the stamp and its separator
    example: str


DIALECTS: tuple[Dialect, ...] = (
    Dialect("arduino-ide", "Arduino IDE", rf"^{_HMS}{_FRAC}[ \t]*->[ \t]?",
            "Arduino IDE serial monitor: 1.x '12:34:56.789 -> ', 2.x '18:2:13.521 -> '"),
    Dialect("bracketed", "bracketed", rf"^\[(?:{_DATE}[ T])?{_HMS}{_FRAC}{_TZ}\][ \t]*",
            "'[2026-11-25 12:30:00.123] ' (tio, minicom, Serial Studio) or '[12:30:00.123] '"),
    Dialect("iso8601", "ISO 8601", rf"^{_DATE}T{_HMS}{_FRAC}{_TZ}{_GAP}",
            "ISO 8601 '2026-11-25T12:30:00.123456+01:00 '"),
    Dialect("date-time", "date-time", rf"^{_DATE} {_HMS}{_FRAC}{_TZ}{_GAP}",
            "'2026-11-25 12:30:00.123 ' (CoolTerm's date and time stamp, ts '%Y-%m-%d %H:%M:%.S')"),
    Dialect("moreutils-ts", "moreutils ts", r"^(?P<month>" + "|".join(_MONTHS) + r") {1,2}(?P<day>[0-9]{1,2}) "
            + _HMS + _FRAC + _GAP, "moreutils ts default 'Nov 25 12:30:00 ' (or '%b %d %H:%M:%.S')"),
    Dialect("epoch", "Unix-time", r"^(?P<epoch>[0-9]{9,10})(?:\.(?P<frac>[0-9]+))?" + _GAP,
            "Unix time '1764073800.123456 ' (moreutils ts '%.s')"),
    Dialect("time-of-day", "time-of-day", rf"^{_HMS}{_FRAC}{_GAP}",
            "'12:30:00.123 ' (CoolTerm's time stamp, ts '%.T', ts -s / -i elapsed time)"),
)
BY_NAME = {d.name: d for d in DIALECTS}
_PUTTY_RULE = "=~" * 11 + "="
PUTTY_BANNER = (rf"^{_PUTTY_RULE} PuTTY log (?P<date>[0-9]{{4}}\.[0-9]{{2}}\.[0-9]{{2}}) "
                rf"(?P<time>[0-9]{{2}}:[0-9]{{2}}:[0-9]{{2}}) {_PUTTY_RULE}$")
_DATA_START = re.compile(r"^-?[0-9]")   # what a data row starts with once its stamp is gone
SAMPLE = 4096                           # lines the dialect is chosen on


@dataclass(frozen=True)
class PrefixInfo:
    """What the stamps said: the dialect, how many lines carried one, and the wall clock at the first sample."""

    dialect: str
    lines: int
    first_line: int | None          # 1-based line of the first stamped data row (or of the banner)
    stamp: str | None               # that stamp as written
    wall_clock_start: str | None    # ISO 8601: date and time, time of day alone, or '--MM-DD' date without year
    fraction_digits: int
    banner: str | None = None       # PuTTY's log banner, kept as a comment line
    banner_line: int | None = None
    stamped_lines: pa.Array | None = field(default=None, compare=False, repr=False)   # the lines as written

    def wall_clock_at(self, line: int) -> str | None:
        """The wall clock a line's stamp says (1-based line), or None when it carries none."""
        if self.stamped_lines is None or self.dialect not in BY_NAME:
            return None
        m = re.match(BY_NAME[self.dialect].pattern, self.stamped_lines[line - 1].as_py())
        return wall_clock(m, self.dialect) if m else None

    def to_dict(self) -> dict:
        return {"dialect": self.dialect, "example": BY_NAME[self.dialect].example if self.dialect in BY_NAME
                else "PuTTY log banner '=~=~=...= PuTTY log 2026.11.25 12:30:00 =~=~=...='",
                "lines": self.lines, "first_line": self.first_line, "stamp": self.stamp,
                "wall_clock_start": self.wall_clock_start, "fraction_digits": self.fraction_digits,
                "banner": self.banner, "banner_line": self.banner_line}


def detect_dialect(text: pa.Array) -> tuple[Dialect | None, np.ndarray]:
    """The dialect matching the most lines of an even sample of ``SAMPLE`` lines, and its mask over every line.

    The sample keeps detection to one pass over a large capture (stamps that start
    after a user switched them on are still found unless they cover under 1/SAMPLE of it).
    """
    n = len(text)
    sample = text if n <= SAMPLE else text.take(pa.array(np.linspace(0, n - 1, SAMPLE).astype(np.int64)))
    best, best_n = None, 0
    for d in DIALECTS:
        hits = int(pc.sum(pc.match_substring_regex(sample, d.pattern)).as_py() or 0)
        if hits > best_n:
            best, best_n = d, hits
    if best is None:
        return None, np.zeros(n, dtype=bool)
    return best, pc.match_substring_regex(text, best.pattern).to_numpy(zero_copy_only=False)


def wall_clock(match: re.Match, dialect: str) -> str:
    """The stamp as ISO 8601 text, keeping every fraction digit (no float rounding)."""
    g = match.groupdict()
    frac = f".{g['frac']}" if g.get("frac") else ""
    if dialect == "epoch":
        base = datetime.fromtimestamp(int(g["epoch"]), tz=timezone.utc)
        return base.strftime("%Y-%m-%dT%H:%M:%S") + frac + "Z"
    h, m, s = (int(v) for v in g["time"].split(":"))
    time = f"{h:02d}:{m:02d}:{s:02d}{frac}{g.get('tz') or ''}"
    if g.get("date"):
        y, mo, d = (int(v) for v in re.split(r"[-/.]", g["date"]))
        return f"{y:04d}-{mo:02d}-{d:02d}T{time}"
    if g.get("month"):
        return f"--{_MONTHS.index(g['month']) + 1:02d}-{int(g['day']):02d}T{time}"
    return time


_COMPILED = tuple((d.name, re.compile(d.pattern)) for d in DIALECTS)


def strip_stamp(line: str) -> tuple[str, str | None]:
    """One trimmed line without its terminal stamp, and the dialect that matched (the first in ``DIALECTS``).

    For readers that see a line at a time (a live view of a capture); a whole file is read by
    ``strip_prefixes``, which picks one dialect for all its lines.
    """
    for name, pattern in _COMPILED:
        m = pattern.match(line)
        if m:
            return line[m.end():].strip(" \t\r\n"), name
    return line, None


def strip_prefixes(text: pa.Array, trim: str) -> tuple[pa.Array, PrefixInfo | None]:
    """Lines with the common stamp removed (and a PuTTY banner made a '#' comment), and what the stamps said."""
    banner_mask = pc.starts_with(text, "=~=~=")            # cheaper than the regex on every line
    banner_idx = np.flatnonzero(banner_mask.to_numpy(zero_copy_only=False))
    if len(banner_idx):
        banner_mask = pc.and_(banner_mask, pc.match_substring_regex(text, PUTTY_BANNER))
        banner_idx = np.flatnonzero(banner_mask.to_numpy(zero_copy_only=False))
    if len(banner_idx):
        hashed = pc.binary_join_element_wise(pa.scalar("#", text.type), text, pa.scalar("", text.type))
        text = pc.if_else(banner_mask, hashed, text)
    dialect, mask = detect_dialect(text)
    if dialect is None:
        if not len(banner_idx):
            return text, None
        i = int(banner_idx[0])
        m = re.match(PUTTY_BANNER, text[i].as_py()[1:])
        stamp = f"{m['date']} {m['time']}"
        return text, PrefixInfo("putty-log", 0, i + 1, stamp, wall_clock(m, "date-time"), 0, banner=m.group(0),
                                banner_line=i + 1)
    stripped = pc.utf8_trim(pc.replace_substring_regex(text, dialect.pattern, ""), characters=trim)
    stamped = np.flatnonzero(mask)
    first = next((int(i) for i in stamped[:1000] if _DATA_START.match(stripped[int(i)].as_py())), int(stamped[0]))
    m = re.match(dialect.pattern, text[first].as_py())
    stamp = m.group(0).strip(" \t->|")
    banner = re.match(PUTTY_BANNER, text[int(banner_idx[0])].as_py()[1:]).group(0) if len(banner_idx) else None
    info = PrefixInfo(dialect.name, int(mask.sum()), first + 1, stamp, wall_clock(m, dialect.name),
                      len(m["frac"] or ""), banner=banner,
                      banner_line=int(banner_idx[0]) + 1 if len(banner_idx) else None, stamped_lines=text)
    return stripped, info
