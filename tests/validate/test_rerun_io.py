"""Every Rerun stream pdr saves a file with is ended when the file is written: the file is complete
(``rerun rrd verify``, read back with its layout) and the process holds no thread more than before."""

import psutil
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from pipeline.validate.rerun_blueprint import run_blueprint
from pipeline.validate.rerun_io import blueprint_chunks, end_streams, verify_rrds, write_recording

FILES = 12


def _log_a_scalar(rec) -> None:
    rec.send_columns("signals/theta", indexes=[rr.TimeColumn("time", duration=[0.0, 0.05])],
                     columns=rr.Scalars.columns(scalars=[0.1, 0.2]))


def test_files_written_one_after_another_leave_no_stream_running(tmp_path):
    layout = blueprint_chunks(run_blueprint)
    end_streams()                                   # what other tests in this process left behind
    before = psutil.Process().num_threads()
    paths = [tmp_path / f"r{i}.rrd" for i in range(FILES)]
    for i, path in enumerate(paths):
        write_recording(path, f"r{i}", layout, _log_a_scalar)
    assert psutil.Process().num_threads() <= before     # each file's stream and its layout's: gone
    assert verify_rrds(paths) == {}
    reader = RrdReader(paths[-1])
    assert len(reader.blueprints()) == 1
    assert "/signals/theta" in {chunk.entity_path for chunk in reader.stream().to_chunks()}


def test_a_stream_whose_logging_fails_is_ended_too(tmp_path):
    def fail(rec) -> None:
        _log_a_scalar(rec)
        raise ValueError("a bug while logging")

    end_streams()
    before = psutil.Process().num_threads()
    for i in range(3):
        with pytest.raises(ValueError, match="a bug while logging"):
            write_recording(tmp_path / f"bad{i}.rrd", f"bad{i}", blueprint_chunks(run_blueprint), fail)
    end_streams()                       # the last failure's traceback held its stream until now
    assert psutil.Process().num_threads() <= before


@pytest.mark.long
@pytest.mark.slow
def test_a_live_stream_that_cannot_flush_fails_no_file(tmp_path):
    """``pdr record --connect URL`` whose viewer cannot be reached: its stream's flush fails, and the
    files written meanwhile are still complete.  Slow: rerun tries to connect for seconds each time."""
    live = rr.RecordingStream("pdr-record-test", recording_id="unreachable")
    live.connect_grpc("rerun+http://127.0.0.1:9/proxy")         # the discard port: nothing listens
    live.log("x", rr.Scalars([1.0]))
    try:
        write_recording(tmp_path / "r.rrd", "r", blueprint_chunks(run_blueprint), _log_a_scalar)
    finally:
        live.disconnect()
    assert verify_rrds([tmp_path / "r.rrd"]) == {}
