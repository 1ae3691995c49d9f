"""After a board reset every segment's MCAP starts at its own t_s = 0; opened together in Foxglove they
overlapped.  Each segment is placed on its capture's one time axis (by the terminal's stamps when there
are some, back to back when there are none), read back with the mcap library."""

from __future__ import annotations

import json

import pytest
from mcap.reader import make_reader

from pipeline.ingest.stage import ingest_recording
from pipeline.ingest.timeline import BACK_TO_BACK, STAMPED, segment_offsets
from pipeline.rig.recording import RigSetup, make_recording, write_recording
from pipeline.rig.serial import Artefacts


def _spans(path) -> tuple[tuple[int, int], dict]:
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        times = [m.log_time for _, _, m in reader.iter_messages(topics=["/encoder"])]
        meta = {r.name: r.metadata for r in reader.iter_metadata()}
    return (min(times), max(times)), meta


@pytest.mark.parametrize("artefacts, axis, gap_s", [
    (Artefacts(reset_after_s=8.0, reset_gap_s=30.0), BACK_TO_BACK, None),
    (Artefacts(reset_after_s=8.0, reset_gap_s=30.0, ide_prefix="classic"), STAMPED, 30.0),
])
def test_reset_segments_are_placed_one_after_the_other_on_one_time_axis(tmp_path, artefacts, axis, gap_s):
    rec = make_recording(RigSetup(duration_s=16.0, artefacts=artefacts), seed=2)
    write_recording(rec, tmp_path / "raw", "reset")
    first, second = ingest_recording(tmp_path / "raw" / "reset.csv", tmp_path / "processed").runs
    (start1, end1), meta1 = _spans(first.mcap)
    (start2, end2), meta2 = _spans(second.mcap)
    assert start1 == 0 and start2 > end1                    # one axis, in the order logged: no overlap
    report = json.loads(first.ingest_report.read_text())
    assert [s["time_axis"] for s in report["segments"]] == [axis, axis]
    assert axis in meta2["time"]["log_time"]
    if gap_s is not None:                                   # the stamps tell the reset's gap (the rig sat off)
        assert (start2 - end1) / 1e9 == pytest.approx(gap_s, abs=2.0)


def test_stamps_that_would_overlap_or_cross_midnight():
    assert segment_offsets(["23:59:50.000", "00:00:20.000"], [5.0, 5.0], 0.05) == ([0.0, 30.0], STAMPED)
    assert segment_offsets(["12:00:00", "12:00:01"], [5.0, 5.0], 0.05) == ([0.0, 5.05], BACK_TO_BACK)
    assert segment_offsets(["12:00:00", None], [5.0, 5.0], 0.05) == ([0.0, 5.05], BACK_TO_BACK)
