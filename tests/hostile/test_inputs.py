"""Hostile recordings, rig files and output folders, one at a time: each is processed or refused in one line
that names the file, never with a traceback; the impossible data of a serial capture is quarantined or flagged."""

from __future__ import annotations

import json
import os
import subprocess

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.errors import ConfigError
from pipeline.ingest.stage import ingest_recording
from pipeline.run import run_pipeline
from tests.hostile.folders import CODE, PDR, REALDATA, good_csv, no_traceback, rows, snapshot, with_count_glitch, \
    with_line_repeated


def _one_line_error(result, *needles: str) -> str:
    lines = [ln for ln in result.output.splitlines() if ln.startswith("pdr: error: ")]
    assert len(lines) == 1, result.output
    no_traceback(result.output)
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def test_a_repeated_line_keeps_one_row_and_the_recording_is_processed(workspace):
    raw = workspace.fresh_raw()
    (raw / "dup.csv").write_bytes(with_line_repeated(good_csv(0), 40))
    processed = workspace.processed()
    report = run_pipeline(raw, processed, jobs=1, code=CODE)
    assert [r["status"] for r in report.ran] == ["ok"], report.ran
    ingest = json.loads((processed / "dup" / "ingest_report.json").read_text())
    assert [(q["line"], q["reason"]) for q in ingest["quarantined"]] == [
        (43, "repeated timestamp: the same time as line 42 (that row kept)")]
    assert (processed / "dup" / "validation.json").is_file()


def test_an_encoder_glitch_is_quarantined_with_its_line(tmp_path):
    clean = ingest_recording_bytes(good_csv(0), tmp=tmp_path / "clean")
    glitched = ingest_recording_bytes(with_count_glitch(good_csv(0), 60), tmp=tmp_path / "glitched")
    q = glitched.report["quarantined"]
    assert [x["line"] for x in q] == [62] and q[0]["reason"].startswith("encoder jump")
    sig, ref = glitched.tables["rec"], clean.tables["rec"]
    assert sig["counts"].tolist() == ref[ref["line"] != 62]["counts"].tolist()


def test_a_count_beyond_64_bits_and_a_step_that_stays_are_named_with_their_lines(tmp_path):
    header, body = rows(good_csv(0))
    t, _counts, *rest = body[70].split(b",")
    huge = header + b"".join(body[:70] + [b",".join([t, b"9223372036854775807", *rest])] + body[71:])
    result = ingest_recording_bytes(huge, tmp=tmp_path / "huge")
    assert [x["line"] for x in result.report["quarantined"]] == [72]
    stays = header + b"".join(body[:80] + [_shifted(line, 100_000) for line in body[80:]])
    result = ingest_recording_bytes(stays, tmp=tmp_path / "stays")
    assert result.report["rows"]["quarantined"] == 0
    assert any("1 encoder jump(s) faster than the declared motor can turn" in d and "line 82 (+99"
               in d for d in result.report["defects"]), result.report["defects"]


def _shifted(line: bytes, by: int) -> bytes:
    t, counts, *rest = line.split(b",")
    return b",".join([t, str(int(counts) + by).encode(), *rest])


def ingest_recording_bytes(data: bytes, toml: str | None = None, tmp=None):
    """Ingest ``data`` as ``rec.csv`` in the folder ``tmp`` (a test's own ``tmp_path``: nothing is left
    behind in the system's temporary folder)."""
    from pathlib import Path
    folder = Path(tmp)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "rec.csv").write_bytes(data)
    if toml is not None:
        (folder / "rec.toml").write_text(toml, encoding="utf-8")
    return ingest_recording(folder / "rec.csv", folder / "processed")


@pytest.mark.parametrize("toml, key, says", [
    ("\ufeff[controller]\nperiod_s = 0.05\n", None, "byte-order mark (BOM)"),
    ("[controller]\nperiod_s = 1e300\n", "controller.period_s", "expected a value in [1e-06, 60.0]"),
    ("[model]\nRa = 2.59e20\n", "model.Ra", "expected a value in"),
    ('[columns]\ncounts = "t_ms"\n', "columns.counts", "already the column of columns.t_ms"),
    ('[columns]\ncounts = ""\nadc = ""\n', "columns.counts", "with neither, the capture has nothing pdr can process"),
])
def test_rig_file_mistakes_are_named(tmp_path, toml, key, says):
    with pytest.raises(ConfigError) as err:
        ingest_recording_bytes(good_csv(0), toml, tmp_path)
    message = str(err.value)
    assert "\n" not in message and "rec.toml" in message and says in message
    if key:
        assert f"key '{key}'" in message


def test_a_capture_without_an_encoder_column_is_processed_beside_good_ones(workspace):
    """Regression: `counts = ""` (a current-only capture) was refused, or a KeyError in segments.py before
    that.  Now each stage does what the current (and a logged dir) allow, and says what it skipped."""
    import numpy as np
    import pyarrow.parquet as pq
    from rerun.chunk import RrdReader

    from tests.ingest.helpers import without_columns
    from tests.ingest.test_outputs import _read_mcap
    raw = workspace.fresh_raw()
    (raw / "good0.csv").write_bytes(good_csv(0))
    (raw / "amps.csv").write_bytes(without_columns(good_csv(1), b"counts"))
    (raw / "amps.toml").write_text('[columns]\ncounts = ""\n')
    (raw / "step.csv").write_bytes(without_columns(good_csv(1), b"counts", b"dir"))
    (raw / "step.toml").write_text('[columns]\ncounts = ""\ndir = ""\n')
    (raw / "nocounts.csv").write_bytes(without_columns(good_csv(1), b"counts"))       # no TOML saying so
    before = snapshot(raw)
    processed = workspace.processed()
    report = run_pipeline(raw, processed, jobs=1, code=CODE)
    status = {r["recording"]: r["status"] for r in report.ran}
    assert status == {"good0.csv": "ok", "amps.csv": "ok", "step.csv": "ok", "nocounts.csv": "failed"}, report.ran
    error = report.failed[0]["error"]
    assert "\n" not in error and "(columns.counts)" in error and 'counts = "" when the capture has no encoder' in error
    no_traceback(error)
    assert snapshot(raw) == before
    for run in ("amps", "step"):
        signals = pq.read_table(processed / run / "signals.parquet")
        assert "theta_rad" not in signals.column_names and "current_a" in signals.column_names
        messages, _, _, _, _ = _read_mcap(processed / run / f"{run}.mcap")
        assert "/encoder" not in messages and len(messages["/current"]) == len(signals)
        assert "no angle" in json.loads((processed / run / "ingest_report.json").read_text())["without_angle"]
        chunks = RrdReader(processed / run / f"{run}.rrd").stream().to_chunks()
        current = [ch for ch in chunks if ch.entity_path == "/signals/current" and not ch.is_static]
        logged = np.array([v for ch in current for v in ch.to_record_batch().column("Scalars:scalars").to_pylist()])
        np.testing.assert_allclose(logged[:, -1], signals.column("current_a").to_numpy())   # measured: drawn last
    validation = json.loads((processed / "amps" / "validation.json").read_text())
    assert list(validation["replay"]["signals"]) == ["current"] and list(validation["skipped"]) == ["closed_loop"]
    assert (processed / "summary.csv").read_text().count("\namps,") == 1
    workspace.assert_as_alone(processed, 0)             # last: it empties the raw folder


def test_ingest_of_several_recordings_does_every_good_one_and_exits_nonzero(tmp_path):
    for name, data in (("a.csv", good_csv(0)), ("bad.csv", b"not,a\ncapture\n"), ("c.csv", good_csv(1))):
        (tmp_path / name).write_bytes(data)
    bad_name = os.path.join(os.fsencode(tmp_path), b"na\xefme.csv")
    with open(bad_name, "wb") as fh:
        fh.write(good_csv(0))
    long = tmp_path / ("n" * 240 + ".csv")
    long.write_bytes(good_csv(0))
    os.mkfifo(tmp_path / "fifo.csv")
    (tmp_path / "zero.csv").symlink_to("/dev/zero")
    processed = tmp_path / "processed"
    out = subprocess.run([PDR, "ingest", str(tmp_path / "a.csv"), str(tmp_path / "bad.csv"), bad_name, str(long),
                          str(tmp_path / "fifo.csv"), str(tmp_path / "zero.csv"), str(tmp_path / "c.csv"), "-q",
                          "--processed", str(processed)], capture_output=True, timeout=120)
    stderr = out.stderr.decode()
    no_traceback(stderr)
    assert out.returncode == 2
    errors = stderr.strip().splitlines()
    assert len(errors) == 5 and all(e.startswith("pdr: error: ") for e in errors), errors
    assert "bad.csv" in errors[0] and "na\\xefme.csv: the file name is not valid UTF-8" in errors[1]
    assert "expected at most 200" in errors[2]
    assert "fifo.csv: a FIFO (named pipe)" in errors[3] and "zero.csv: a device" in errors[4]
    assert sorted(p.name for p in processed.iterdir()) == [".pdr.lock", "a", "c"]


def test_output_folder_that_is_a_file_or_read_only_is_one_line(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "a.csv").write_bytes(good_csv(0))
    before = snapshot(raw)
    (tmp_path / "plain").write_text("not a folder")
    out = subprocess.run([PDR, "run", "--raw", str(raw), "--processed", str(tmp_path / "plain")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and out.stderr.strip() == f"pdr: error: {tmp_path / 'plain'}: expected an output " \
                                                        f"folder, found a file"
    locked = tmp_path / "ro"
    locked.mkdir()
    with read_only(locked):
        out = subprocess.run([PDR, "run", "--raw", str(raw), "--processed", str(locked / "processed")],
                             capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and out.stderr.strip() == (f"pdr: error: {locked / 'processed'}: cannot create the "
                                                         f"output folder: Read-only file system"
                                                         if os.geteuid() == 0 else
                                                         f"pdr: error: {locked / 'processed'}: cannot create the "
                                                         f"output folder: Permission denied")
    assert snapshot(raw) == before


class read_only:
    """A folder nobody can write: a read-only mount where this runs as root (root ignores permissions),
    else the permissions."""

    def __init__(self, folder) -> None:
        self.folder = folder

    def __enter__(self):
        if os.geteuid() == 0:
            subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(self.folder)], check=True)
        else:
            self.folder.chmod(0o555)

    def __exit__(self, *exc):
        if os.geteuid() == 0:
            subprocess.run(["umount", str(self.folder)], check=True)
        else:
            self.folder.chmod(0o755)


def test_validate_with_a_constant_current_writes_its_rerun_file(tmp_path):
    """Regression: all ADC 512 gave a zero measured energy and a TypeError in rerun_log (paper_pct None)."""
    header, body = rows(good_csv(0))
    constant = header + b"".join(b",".join([*ln.split(b",")[:2], b"512", ln.split(b",")[3]]) for ln in body)
    (tmp_path / "flat.csv").write_bytes(constant)
    processed = tmp_path / "processed"
    result = CliRunner().invoke(app, ["ingest", str(tmp_path / "flat.csv"), "-q", "--processed", str(processed)])
    assert result.exit_code == 0, result.output
    CliRunner().invoke(app, ["derive", "flat", "--processed", str(processed)])
    result = CliRunner().invoke(app, ["validate", "flat", "--processed", str(processed), "--no-png"])
    assert result.exit_code == 0, result.output
    assert (processed / "flat" / "flat.rrd").stat().st_size > 0


AKAFAEL_TOML = '[columns]\nt_ms = "time(ms)"\ncounts = "enconder(steps)"\nadc = ""\ndir = ""\n'


@pytest.mark.long
def test_discover_on_a_stuck_timer_writes_its_report(tmp_path):
    """Regression: the real capture whose timer is stuck at 0 ended in a ValueError in discover/report.py
    (no localisation table to draw)."""
    import shutil
    shutil.copy(REALDATA / "akafael__discrete-servo-control" / "expdata_20201126_203627.csv", tmp_path / "s.csv")
    (tmp_path / "s.toml").write_text(AKAFAEL_TOML + "[controller]\nperiod_s = 0.1\n")
    result = CliRunner().invoke(app, ["discover", str(tmp_path / "s.csv"), "--processed", str(tmp_path / "p"),
                                      "--no-rrd"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "p" / "discovery" / "s" / "report.md").is_file()


REAL_SIDECARS = {
    # the TOML a user of each real capture would write (SOURCE.txt says what the columns are)
    "akafael__discrete-servo-control": {
        "expdata_20201120_214756": 0.06, "expdata_20201120_215030": 0.01, "expdata_20201124_220716": 0.1,
        "expdata_20201126_212205": 0.1, "expdata_20201126_203627": 0.1, "expdata_20201126_204516": 0.1},
    "opatiny__micromouse": {"encoders3": 0.005, "encoders5": 0.005, "testPid7": 0.002,
                            "controllerDelayImpact5ms": 0.005, "batteryVoltage3": 0.001},
    "Tamaras-hub__ESP32-DC-Motor-PID-Control": {"step_response": 0.05},
}


def _sidecar(folder: str, stem: str, period: float) -> str:
    if folder.startswith("akafael"):
        return AKAFAEL_TOML + f"[controller]\nperiod_s = {period}\n"
    if folder.startswith("opatiny"):
        encoder = "leftEncoder" if stem.startswith("encoders") else ""     # the others log no encoder
        return (f'[columns]\nt_ms = "time"\ncounts = "{encoder}"\nadc = ""\ndir = ""\n'
                f"[encoder]\ncounts_per_rev = 358.3\n[controller]\nperiod_s = {period}\n")
    return f'[columns]\nt_ms = "Tiempo (s)"\ntime_unit = "s"\ncounts = ""\nadc = ""\ndir = ""\n' \
           f"[controller]\nperiod_s = {period}\n"


@pytest.mark.slow
def test_the_real_captures_are_processed_or_refused_in_one_line(workspace):
    import shutil
    raw = workspace.fresh_raw()
    for folder, stems in REAL_SIDECARS.items():
        for stem, period in stems.items():
            shutil.copy(REALDATA / folder / f"{stem}.csv", raw / f"{stem}.csv")
            (raw / f"{stem}.toml").write_text(_sidecar(folder, stem, period))
    (raw / "DATA_EMPS.mat").write_bytes(b"MATLAB 5.0 MAT-file")    # a benchmark's data file, not a capture
    before = snapshot(raw)
    report = run_pipeline(raw, workspace.processed(), jobs=1, code=CODE)
    status = {r["recording"][:-4]: r["status"] for r in report.ran}
    no_encoder = {"testPid7", "controllerDelayImpact5ms", "batteryVoltage3", "step_response"}
    assert status == {stem: "failed" if stem in no_encoder else "ok" for stems in REAL_SIDECARS.values()
                      for stem in stems}, report.failed
    for r in report.failed:
        assert "\n" not in r["error"] and "key 'columns.counts'" in r["error"], r["error"]
        no_traceback(r["error"])
    assert report.ignored == ["DATA_EMPS.mat"]
    assert snapshot(raw) == before


def _interface_capture() -> bytes:
    """good0 as a real serial capture per docs/FORMAT.md: BOM, CRLF, comments, blank lines, IDE prefixes, a
    partial first line, garbled lines, and a repeated header where the board reset and logging restarted."""
    header, body = rows(good_csv(0))
    lines = [b"\xef\xbb\xbf# pdr hostile capture\r\n", b"9,511,1\r\n", header.rstrip() + b"\r\n", b"\r\n"]
    for k, line in enumerate(body[:60]):
        line = line.rstrip()
        lines.append((b"12:34:56.789 -> " + line if k % 3 == 0 else line) + b"\r\n")
        if k == 20:
            lines.append(b"4#1,,x\xff\r\n")
    lines.append(header.rstrip() + b"\r\n")                        # the board reset: time and count from 0
    lines += [ln.rstrip() + b"\r\n" for ln in body[:60]]
    return b"".join(lines)


def test_every_capture_defect_of_the_interface_at_once(workspace):
    raw = workspace.fresh_raw()
    (raw / "serial.csv").write_bytes(_interface_capture())
    before = snapshot(raw)
    processed = workspace.processed()
    report = run_pipeline(raw, processed, jobs=1, code=CODE)
    assert [(r["status"], r["runs"]) for r in report.ran] == [("ok", ["serial-seg1", "serial-seg2"])], report.ran
    ingest = json.loads((processed / "serial-seg1" / "ingest_report.json").read_text())
    assert [q["line"] for q in ingest["quarantined"]] == [2, 26]    # the partial first line, the garbled one
    assert ingest["board_resets"] == 1 and ingest["rows"]["kept"] == 120
    assert snapshot(raw) == before


def test_a_summary_that_cannot_be_written_is_reported_beside_the_recordings(workspace):
    workspace.alone(0)
    raw = workspace.fresh_raw()
    (raw / "good0.csv").write_bytes(good_csv(0))
    processed = workspace.processed()
    (processed / "summary.csv").mkdir(parents=True)         # a folder where pdr writes its summary file
    report = run_pipeline(raw, processed, jobs=1, code=CODE)
    assert [(r["recording"], r["status"]) for r in report.ran] == [("good0.csv", "ok"), ("summary.csv", "failed")]
    assert "Is a directory" in report.failed[0]["error"]
    workspace.assert_as_alone(processed, 0)
