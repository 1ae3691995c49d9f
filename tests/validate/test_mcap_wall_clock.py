"""comparison.mcap's log_time is on the wall clock when the serial terminal stamped the lines with a date,
and counts from the run's first sample (saying so) when it did not (an Arduino IDE time of day)."""

import json
from datetime import datetime, timezone

import pytest
from mcap.reader import make_reader

from pipeline.derive.stage import derive_run
from pipeline.ingest.stage import ingest_recording
from pipeline.rig.recording import RigSetup, make_recording, write_recording
from pipeline.rig.serial import Artefacts
from pipeline.validate.mcap_log import epoch_ns
from pipeline.validate.stage import validate_run


def _first_log_time(tmp_path, artefacts: Artefacts) -> tuple[int, dict, dict]:
    rec = make_recording(RigSetup(seed=4, duration_s=6.0, artefacts=artefacts))
    write_recording(rec, tmp_path / "raw", "stamped")
    paths = ingest_recording(tmp_path / "raw" / "stamped.csv", tmp_path / "processed").runs[0]
    derive_run(paths)
    validate_run(paths, rrd=False, png=False)
    report = json.loads(paths.ingest_report.read_text())
    with open(paths.comparison_mcap, "rb") as fh:
        reader = make_reader(fh)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        first = next(m.log_time for _, _, m in reader.iter_messages())
    return first, meta["time"], report


def test_a_dated_terminal_stamp_puts_log_time_on_the_wall_clock(tmp_path):
    first, time_meta, report = _first_log_time(tmp_path, Artefacts(terminal="iso8601-utc", stamp_digits=6))
    stamp = report["segments"][0]["wall_clock_start"]
    assert stamp and time_meta["wall_clock"] == stamp
    when = datetime.fromisoformat(stamp).astimezone(timezone.utc)
    assert first == epoch_ns(stamp) == pytest.approx(when.timestamp() * 1e9, abs=1e3)
    assert "Unix epoch" in time_meta["log_time"]


def test_a_time_of_day_alone_keeps_log_time_from_the_first_sample(tmp_path):
    first, time_meta, report = _first_log_time(tmp_path, Artefacts(ide_prefix="ide2"))
    assert report["segments"][0]["wall_clock_start"]              # a stamp, but no date
    assert first == 0 and time_meta["wall_clock"] == "unknown"


def test_epoch_of_stamps():
    assert epoch_ns("1970-01-01T00:00:01.5Z") == 1_500_000_000
    assert epoch_ns("1970-01-01T01:00:00+01:00") == 0
    assert epoch_ns("13:55:21.968") is None and epoch_ns(None) is None and epoch_ns("garbage") is None
