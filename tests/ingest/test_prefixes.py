"""Serial terminals' time stamps: every form gives the plain file's signals bit for bit, names its dialect,
and keeps the wall-clock time of the first sample; property tests for the prefix parser."""

from __future__ import annotations

import json
from datetime import datetime, timedelta, timezone

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.ingest.prefix import DIALECTS, strip_prefixes, strip_stamp
from pipeline.ingest.stage import ingest_recording
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.rig.serial import TERMINAL_STAMPS, Artefacts
from tests.ingest.helpers import CLEAN, ingest

TRIM = " \t\r\n"
# rig terminal style -> the dialect ingest must name
EXPECTED = {"bracketed": "bracketed", "bracketed-time": "bracketed", "iso8601": "iso8601", "iso8601-utc": "iso8601",
            "date-time": "date-time", "ts": "moreutils-ts", "ts-fraction": "moreutils-ts", "ts-epoch": "epoch",
            "time-of-day": "time-of-day", "putty": "putty-log"}
FORMS = [("ide", "classic", 3), ("ide", "ide2", 3)] + [
    ("terminal", style, digits) for style in TERMINAL_STAMPS for digits in ((3, 6) if style != "putty" else (3,))]


def _signals_and_report(tmp_path, name: str, art: Artefacts, seed: int = 11):
    rec = make_recording(RigSetup(artefacts=art, duration_s=4.0, pre_roll_s=0.5), seed)
    raw = tmp_path / name
    raw.mkdir()
    (raw / "cap.csv").write_bytes(rec.csv_bytes)
    (raw / "cap.toml").write_text(rec.toml_text)
    result = ingest_recording(raw / "cap.csv", tmp_path / f"processed-{name}")
    paths = result.runs[0]
    return rec, pq.read_table(paths.signals), json.loads(paths.ingest_report.read_text())


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    return _signals_and_report(tmp_path_factory.mktemp("plain"), "plain", Artefacts())


@pytest.mark.parametrize("kind,style,digits", FORMS, ids=[f"{s}-{d}" for _, s, d in FORMS])
def test_prefixed_capture_gives_the_plain_signals_bit_for_bit(tmp_path, plain, kind, style, digits):
    art = Artefacts(ide_prefix=style) if kind == "ide" else Artefacts(terminal=style, stamp_digits=digits)
    rec, table, report = _signals_and_report(tmp_path, "stamped", art)
    plain_rec, plain_table, _ = plain
    assert rec.truth_meta["timing"]["wall_start_s"] == plain_rec.truth_meta["timing"]["wall_start_s"]
    if style == "putty":            # the banner is one line more: every sample sits one line lower
        assert table.column("line").to_pylist() == [v + 1 for v in plain_table.column("line").to_pylist()]
        table, plain_table = table.drop_columns(["line"]), plain_table.drop_columns(["line"])
    assert table.equals(plain_table, check_metadata=False)
    prefix = report["timestamp_prefix"]
    assert prefix["dialect"] == ("arduino-ide" if kind == "ide" else EXPECTED[style])
    assert report["quarantined"] == []
    if style == "putty":
        assert prefix["banner_line"] == 1 and report["lines"]["comment"] == 1
        return
    assert prefix["first_line"] == 2                      # the header is line 1, the first sample line 2
    # the stamp read back is the wall clock at which the first sample's line arrived (the rig's PC receives
    # it 4-6 ms after the sample; stamps are truncated to their digits, the IDE's rounded to the ms)
    stamp_time = prefix["wall_clock_start"].split("T")[-1].rstrip("Z").split("+")[0]
    h, m, sec = stamp_time.split(":")
    local = int(h) * 3600 + int(m) * 60 + float(sec) + (3600 if style in ("iso8601-utc", "ts-epoch") else 0)
    wall = rec.truth_meta["timing"]["wall_start_s"]
    resolution = 1.0 if style == "ts" else 10.0 ** -digits
    assert wall + 0.004 - resolution - 1e-3 <= local <= wall + 0.006 + 1e-3


def test_each_segment_keeps_the_wall_clock_of_its_first_sample(tmp_path):
    art = Artefacts(terminal="bracketed", stamp_digits=6, reset_after_s=2.0, reset_gap_s=5.0)
    rec, _, report = _signals_and_report(tmp_path, "reset", art)
    starts = [seg["wall_clock_start"] for seg in report["segments"]]
    assert starts[0] == report["timestamp_prefix"]["wall_clock_start"]
    first_of_second = rec.truth[rec.truth["segment"] == 2]["line"].iloc[0]
    line = rec.csv_bytes.decode().splitlines()[first_of_second - 1]
    assert starts[1] == line[1:27].replace(" ", "T")      # '[2026-11-25 12:34:56.123456] ...'
    elapsed = (datetime.fromisoformat(starts[1]) - datetime.fromisoformat(starts[0])).total_seconds()
    true = rec.truth.groupby("segment")["t_s"].first()          # the true instants, the reset gap included
    assert abs(elapsed - (true[2] - true[1])) < 0.003           # the PC receives each line 4-6 ms after its sample


def test_plain_capture_has_no_prefix():
    _, report = ingest(CLEAN)
    assert report["timestamp_prefix"] is None


def test_stamps_switched_on_mid_capture_are_stripped_and_another_form_is_not():
    lines = CLEAN.decode().splitlines()
    for k in range(6, len(lines)):            # the user turned the monitor's stamps on at line 7
        lines[k] = f"12:30:{k:02d}.123456 -> " + lines[k]
    lines[4] = "[12:30:00.123] " + lines[4]   # one line in another terminal's form: not this capture's stamp
    runs, report = ingest(("\n".join(lines) + "\n").encode())
    assert report["timestamp_prefix"]["dialect"] == "arduino-ide"
    assert report["timestamp_prefix"]["lines"] == len(lines) - 6
    assert report["timestamp_prefix"]["wall_clock_start"] == "12:30:06.123456"
    assert [q["line"] for q in report["quarantined"]] == [5]
    assert len(runs[0].signals) == 9


# --------------------------------------------------------------------------- properties

_LOCAL = timezone(timedelta(hours=1))
moments = st.datetimes(min_value=datetime(2001, 9, 10), max_value=datetime(2099, 12, 31))


def _stamp(form: str, when: datetime, digits: int) -> tuple[str, str]:
    """(the stamp and its separator, the ISO 8601 wall clock the parser must report)."""
    frac = f"{when.microsecond:06d}{when.microsecond % 1000:03d}"[:digits]
    f = f".{frac}" if digits else ""
    hms, ymd = when.strftime("%H:%M:%S"), when.strftime("%Y-%m-%d")
    iso = f"{ymd}T{hms}{f}"
    return {
        "ide1": (f"{hms}{f} -> ", f"{hms}{f}"),
        "ide2": (f"{when.hour}:{when.minute}:{when.second}{f} -> ", f"{hms}{f}"),
        "bracketed": (f"[{ymd} {hms}{f}] ", iso),
        "bracketed-time": (f"[{hms}{f}]\t", f"{hms}{f}"),
        "iso8601": (f"{iso}+01:00 ", f"{iso}+01:00"),
        "iso8601-utc": (f"{iso}Z\t", f"{iso}Z"),
        "date-time": (f"{ymd} {hms}{f} ", iso),
        "date-time-slash": (f"{when.strftime('%Y/%m/%d')} {hms}{f} | ", iso),
        "ts": (f"{when.strftime('%b %d')} {hms}{f} ", f"--{when.strftime('%m-%d')}T{hms}{f}"),
        "epoch": (f"{int(when.replace(tzinfo=timezone.utc).timestamp())}{f} ", f"{iso}Z"),
        "time-of-day": (f"{hms}{f} ", f"{hms}{f}"),
    }[form]


FORM_DIALECT = {"ide1": "arduino-ide", "ide2": "arduino-ide", "bracketed": "bracketed", "bracketed-time": "bracketed",
                "iso8601": "iso8601", "iso8601-utc": "iso8601", "date-time": "date-time",
                "date-time-slash": "date-time", "ts": "moreutils-ts", "epoch": "epoch", "time-of-day": "time-of-day"}
data_rows = st.lists(st.tuples(st.integers(0, 2**32 - 1), st.integers(-(2**31), 2**31), st.integers(0, 1023),
                               st.sampled_from([-1, 0, 1])), min_size=1, max_size=12)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(form=st.sampled_from(sorted(FORM_DIALECT)), when=moments, digits=st.integers(0, 9), rows=data_rows,
       header=st.booleans(), step_ms=st.integers(1, 1000))
def test_stamp_is_stripped_to_the_line_and_read_back(form, when, digits, rows, header, step_ms):
    plain = (["t_ms,counts,adc,dir"] if header else []) + [",".join(map(str, r)) for r in rows]
    stamped, wall = [], None
    for k, line in enumerate(plain):
        text, iso = _stamp(form, when + timedelta(milliseconds=step_ms * k), digits)
        stamped.append((text + line).strip(TRIM))
        if wall is None and not line.startswith("t"):
            wall = iso
    out, info = strip_prefixes(pa.array(stamped, pa.large_string()), TRIM)
    assert out.to_pylist() == plain
    assert info is not None and info.dialect == FORM_DIALECT[form]
    assert [strip_stamp(line) for line in stamped] == [(line, FORM_DIALECT[form]) for line in plain]
    assert info.lines == len(plain) and info.first_line == (2 if header else 1)
    assert info.wall_clock_start == wall and info.fraction_digits == digits


@settings(max_examples=60, deadline=None)
@given(rows=data_rows, header=st.booleans())
def test_unstamped_lines_are_never_changed(rows, header):
    plain = (["t_ms,counts,adc,dir"] if header else []) + [",".join(map(str, r)) for r in rows]
    out, info = strip_prefixes(pa.array(plain, pa.large_string()), TRIM)
    assert info is None and out.to_pylist() == plain
    assert [strip_stamp(line) for line in plain] == [(line, None) for line in plain]


def test_the_ide_pattern_other_readers_import_still_strips_the_ide_stamp():
    import re

    from pipeline.ingest.parse import IDE_PREFIX

    assert re.sub(IDE_PREFIX, "", "18:2:13.521 -> 0,0,511,1") == "0,0,511,1"
    assert re.sub(IDE_PREFIX, "", "12:34:56.789123 -> 0,0,511,1") == "0,0,511,1"


def test_every_dialect_has_a_form():
    assert set(FORM_DIALECT.values()) == {d.name for d in DIALECTS}
