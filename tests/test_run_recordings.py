"""The raw-folder scan and the run-name rules: what is a recording, what is refused and why (no pipeline run)."""

import os

import pytest

from pipeline.errors import PdrError
from pipeline.run.recordings import scan_raw
from pipeline.runs import check_recording_name


def test_scan_sorts_entries_into_recordings_refusals_and_other_files(tmp_path):
    for name in ("b.csv", "X.CSV", "A.csv", "a.csv", "notes.md", "rig.toml", "data.mat", ".hidden.csv"):
        (tmp_path / name).write_text("t_ms,counts\n0,0\n")
    (tmp_path / "folder.csv").mkdir()
    (tmp_path / "sub").mkdir()
    os.mkfifo(tmp_path / "pipe.csv")
    (tmp_path / "dead.csv").symlink_to(tmp_path / "gone.csv")
    (tmp_path / "ok_link.csv").symlink_to(tmp_path / "b.csv")
    folder = scan_raw(tmp_path)
    assert [p.name for p in folder.recordings] == ["A.csv", "X.CSV", "b.csv", "ok_link.csv"]
    assert folder.refused == {"a.csv": "its run name collides with A.csv (the names differ only in case or Unicode "
                                       "normalisation, and look alike); rename one",
                              "dead.csv": "a symlink whose target is missing",
                              "folder.csv": "a directory, expected a regular CSV file",
                              "pipe.csv": "a FIFO (named pipe), expected a regular CSV file"}
    assert folder.ignored == ["data.mat"]


@pytest.mark.parametrize("stem, says", [
    ("run-seg1", "reserved for the segments"), ("discovery", "reserved for pdr's own entries"),
    ("Summary.CSV", "reserved for pdr's own entries"), (".x", "reserved"), ("n" * 201, "at most 200"),
    ("bad\udcff", "not valid UTF-8"),
])
def test_names_that_could_collide_with_a_run_or_pdr_s_own_entries_are_refused(stem, says):
    with pytest.raises(PdrError, match=says):
        check_recording_name(stem, f"raw/{stem}.csv")


@pytest.mark.parametrize("stem", ["run", "run-seg", "run-segA", "seg1", "run[1]", "n" * 200, "café"])
def test_ordinary_names_are_accepted(stem):
    check_recording_name(stem, f"raw/{stem}.csv")
