"""``pdr run`` on a raw folder holding every bad entry a user or a tool has put there, beside good
recordings: each bad entry is one line, every good recording is processed as if alone, raw/ is unchanged."""

from __future__ import annotations

import os
import subprocess

import pytest

from pipeline.run import run_pipeline
from tests.hostile.folders import PDR, good_csv, no_traceback, snapshot

BAD_ENTRIES = {
    # entry -> what its FAILED line says
    "x.csv": "a directory",
    "dangling.csv": "a symlink whose target is missing",
    "loop.csv": "Too many levels of symbolic links",
    "fifo.csv": "a FIFO",
    "zero.csv": "a device",
    "GOOD0.CSV": "collides with good0.csv",
    "good0-seg1.csv": "reserved for the segments",
    "discovery.csv": "reserved for pdr's own entries",
    "l" * 240 + ".csv": "expected at most 200",
    "garbage.csv": "no recognisable columns",
    "fifo_rig.csv": "fifo_rig.toml: a FIFO (named pipe), expected a regular TOML file",
}
NON_UTF8 = b"bad\xff.csv"


def _hostile_folder(raw) -> None:
    for seed in (0, 1):
        (raw / f"good{seed}.csv").write_bytes(good_csv(seed))
    (raw / "x.csv").mkdir()
    (raw / "dangling.csv").symlink_to(raw / "missing.csv")
    (raw / "loop.csv").symlink_to(raw / "loop.csv")
    os.mkfifo(raw / "fifo.csv")
    (raw / "zero.csv").symlink_to("/dev/zero")
    (raw / "GOOD0.CSV").write_bytes(good_csv(0))
    (raw / "good0-seg1.csv").write_bytes(good_csv(0))
    (raw / "discovery.csv").write_bytes(good_csv(0))
    (raw / ("l" * 240 + ".csv")).write_bytes(good_csv(0))
    (raw / "garbage.csv").write_text("this is not\na capture\n")
    (raw / "fifo_rig.csv").write_bytes(good_csv(1))
    os.mkfifo(raw / "fifo_rig.toml")
    with open(os.path.join(os.fsencode(raw), NON_UTF8), "wb") as fh:
        fh.write(good_csv(0))
    (raw / "DATA_EMPS.mat").write_bytes(b"MATLAB 5.0 MAT-file")


@pytest.mark.slow
def test_every_bad_entry_is_one_line_and_the_good_recordings_are_processed_as_alone(workspace):
    workspace.alone(0), workspace.alone(1)
    raw = workspace.fresh_raw()
    _hostile_folder(raw)
    before = snapshot(raw)
    processed = workspace.processed()
    out = subprocess.run([PDR, "run", "--raw", str(raw), "--processed", str(processed), "-j", "1"],
                         capture_output=True, timeout=180)
    stdout, stderr = out.stdout.decode(errors="replace"), out.stderr.decode(errors="replace")
    no_traceback(stdout, stderr)
    assert out.returncode == 1, stdout + stderr
    text = stdout + stderr                  # the end-of-run summary goes to stderr
    failed = {line.split(": ", 1)[0][len("FAILED "):]: line for line in text.splitlines()
              if line.startswith("FAILED ")}
    for name, says in BAD_ENTRIES.items():
        assert says in failed.get(name, ""), (name, failed)
    assert any("bad\\xff.csv" in name and "not valid UTF-8" in line for name, line in failed.items()), failed
    assert len(failed) == len(BAD_ENTRIES) + 1
    assert "not recordings (only <name>.csv is read): DATA_EMPS.mat" in text
    for seed in (0, 1):
        workspace.assert_as_alone(processed, seed)
    assert sorted(p.name for p in processed.iterdir()) == [".pdr.lock", "dataset", "good0", "good1", "summary.csv"]
    assert snapshot(raw) == before

    # a second run: every good recording unchanged and skipped, every bad entry refused again
    again = run_pipeline(raw, processed, jobs=1)
    assert again.skipped == ["good0.csv", "good1.csv"] and len(again.failed) == len(failed)
    assert snapshot(raw) == before
