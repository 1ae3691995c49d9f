"""The second process ingests a raw CSV into the same files this one would, and what it cannot ingest is
refused here with the error ingesting here gives."""

from pathlib import Path

import pytest

from pipeline.discover.second_process import SecondProcess, can_fork, ingest_and_derive
from pipeline.errors import PdrError
from pipeline.rig.recording import RigSetup, make_recording, write_recording

pytestmark = pytest.mark.skipif(not can_fork(), reason="the second process ingests only where it is a fork")


@pytest.fixture(scope="module")
def raw_csv(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("second")
    write_recording(make_recording(RigSetup(duration_s=12.0), seed=3), work / "raw", "rec")
    return work / "raw" / "rec.csv"


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_the_fork_ingests_and_derives_the_same_bytes_as_here(raw_csv, tmp_path, monkeypatch):
    from pipeline.discover import second_process

    here = ingest_and_derive(raw_csv, tmp_path / "here")
    with SecondProcess(background=True) as second:
        def not_here(*_):
            raise AssertionError("ingested in the first process")

        monkeypatch.setattr(second_process, "ingest_and_derive", not_here)      # the fork keeps its own
        there = second.ingest(raw_csv, tmp_path / "there")
        assert second._proc.is_alive()                  # still there, to draw
    assert [p.name for p in there] == [p.name for p in here]
    assert all(Path(p.signals).is_relative_to(tmp_path / "there") for p in there)
    files = _files(tmp_path / "here")
    assert any(name.endswith(".parquet") for name in files)
    assert _files(tmp_path / "there") == files


def test_a_csv_the_fork_cannot_ingest_is_refused_here_as_ingesting_here_refuses_it(raw_csv, tmp_path):
    bad = tmp_path / "raw" / "bad.csv"
    bad.parent.mkdir()
    bad.write_text("this is not,a capture\n\x00\x00\n")
    with pytest.raises(PdrError) as here:
        ingest_and_derive(bad, tmp_path / "here")
    with SecondProcess(background=True) as second, pytest.raises(PdrError) as there:
        second.ingest(bad, tmp_path / "there")
    assert str(there.value) == str(here.value) and "bad.csv" in str(there.value)


def test_a_fork_that_died_before_ingesting_leaves_the_ingest_to_this_process(raw_csv, tmp_path):
    with SecondProcess(background=True) as second:
        second._proc.kill()
        second._proc.join()
        runs = second.ingest(raw_csv, tmp_path / "after")
    assert [p.name for p in runs] == [p.name for p in ingest_and_derive(raw_csv, tmp_path / "here")]
