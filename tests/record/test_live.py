"""The live view: fed off the capture thread, logged to a Rerun memory sink and read back with rerun's reader."""

from __future__ import annotations

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from pipeline.config import default_config
from pipeline.errors import PdrError
from pipeline.ingest.stage import ingest_capture
from pipeline.record.live import LiveView, ViewSink
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.rig.serial import Artefacts
from pipeline.validate.compare import switch_indices


def _view(max_chunks: int = 4096):
    rec = rr.RecordingStream("pdr-record-test", recording_id="live")
    memory = rec.memory_recording()
    return LiveView(default_config(), rec, max_chunks=max_chunks, frame_s=0.01), memory


def _chunks_of(data: bytes, size: int) -> list[tuple[int, bytes]]:
    return [(i, data[i:i + size]) for i in range(0, len(data), size)]


def _read(memory, tmp_path):
    path = tmp_path / "live.rrd"
    path.write_bytes(memory.drain_as_bytes())
    return RrdReader(path).stream().to_chunks()


def _scalars(chunks, entity: str) -> np.ndarray:
    values = []
    for ch in chunks:
        if ch.entity_path == entity and not ch.is_static:
            values += ch.to_record_batch().column("Scalars:scalars").to_pylist()
    return np.array(values)


def test_view_shows_theta_with_guards_current_mode_and_counts(tmp_path):
    rec = make_recording(RigSetup(duration_s=5.0, seed=1, zero_v="nominal",
                                  artefacts=Artefacts(garbled=2, reset_after_s=2.5, reset_gap_s=1.0)))
    runs, report = ingest_capture(rec.csv_bytes, default_config(), "x.csv", "x")
    view, memory = _view()
    view.start()
    for offset, data in _chunks_of(rec.csv_bytes, 37):
        view.offer(offset, data)
    view.close()
    assert view.error is None and view.dropped_chunks == 0
    chunks = _read(memory, tmp_path)

    theta = _scalars(chunks, "/signals/theta")
    measured = np.concatenate([r.signals["theta_rad"].to_numpy() for r in runs])
    assert theta.shape == (report["rows"]["kept"], 3)
    np.testing.assert_array_equal(theta[:, 0], measured)
    guard = default_config().controller.guard_rad
    assert np.all(theta[:, 1] == guard) and np.all(theta[:, 2] == -guard)
    current = _scalars(chunks, "/signals/current")[:, 0]
    np.testing.assert_allclose(current, np.concatenate([r.signals["current_a"].to_numpy() for r in runs]))

    states = [s for ch in chunks if ch.entity_path == "/mode"
              for s in ch.to_record_batch().column("StateChange:state").to_pylist()]
    dirs = [r.signals["dir"].to_numpy() for r in runs]
    changes = int(np.count_nonzero(np.diff(np.concatenate(dirs)))) + 1      # the first state, then every change
    assert len(states) == changes and states[0] == ["off"]
    texts = [t for ch in chunks if ch.entity_path == "/counts"
             for t in ch.to_record_batch().column("TextDocument:text").to_pylist()]
    switches = sum(len(switch_indices(d)) for d in dirs)
    assert f"switches {switches}" in texts[-1][0] and "lines that did not parse 2" in texts[-1][0]
    assert "segments 2" in texts[-1][0]


def test_a_view_that_falls_behind_drops_chunks_never_blocks_the_capture(tmp_path):
    rec = make_recording(RigSetup(duration_s=2.0, seed=2, zero_v="nominal"))
    view, memory = _view(max_chunks=8)                   # not started yet: a viewer that is stuck
    chunks = _chunks_of(rec.csv_bytes, 20)
    for offset, data in chunks[:-1]:
        view.offer(offset, data)                        # put_nowait: returns at once even when full
    assert view.dropped_chunks == len(chunks) - 1 - 8
    view.start()
    view.offer(*chunks[-1])                             # after the gap: the view resyncs at a line end
    view.close()
    assert view.error is None
    tally = view.decoder.tally
    assert tally.skipped_lines == 1 and tally.unparsed == 0 and 0 < tally.samples < 12
    theta = _scalars(_read(memory, tmp_path), "/signals/theta")
    assert len(theta) == tally.samples


def test_spawn_without_a_display_is_a_one_line_error(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(PdrError, match="no display.*--save-view"):
        ViewSink("spawn").open(rr.RecordingStream("pdr-record-test"), None)
