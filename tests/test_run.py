"""`pdr run` end to end on virtual-rig recordings: all stages, incremental, isolation of
failures, the noise floor and the gate, and two concurrent runs on one folder."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from pipeline.model.effects import make_effect
from pipeline.rig.recording import RigSetup, make_recording, write_recording
from pipeline.run import code_version, run_pipeline
from pipeline.runs import run_paths
from pipeline.validate.gate import gate, load_thresholds

SHIPPED_THRESHOLDS = Path(__file__).resolve().parents[1] / "raw" / "thresholds.toml"
PDR = str(Path(sys.executable).with_name("pdr"))
CODE = "pinned"       # the shared source tree may change under a test; the stamps must not notice

# The virtual rig's noise settings (RigSetup defaults) imply these replay MSE floors:
#   theta   encoder step 2*pi/6533.12 = 9.6e-4 rad -> step^2/12 = 7.7e-8, plus millis() rounding
#           of the sample instants (up to 1 ms at ~2 rad/s): 3e-7 .. 1e-6 rad^2 observed
#   current ACS712 noise sigma = one ADC step = 5/1024/0.185 = 26.4 mA -> 7.0e-4, plus ADC
#           rounding 26.4^2/12 mA^2 = 5.8e-5: 7.5e-4 A^2
CURRENT_FLOOR_A2 = (5 / 1024 / 0.185) ** 2 * (1 + 1 / 12)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    raw = tmp_path_factory.mktemp("raw")
    write_recording(make_recording(RigSetup(), seed=11), raw, "clean")
    write_recording(make_recording(RigSetup(effects=(make_effect("driver_voltage_drop", {"Vd": 0.6}),)), seed=12),
                    raw, "vdrop")
    return raw


@pytest.mark.slow
def test_run_validates_every_recording_and_isolates_a_bad_one(recordings, tmp_path):
    raw = tmp_path / "raw"
    shutil.copytree(recordings, raw)
    (raw / "garbage.csv").write_text("this is not\na capture\n")
    processed = tmp_path / "processed"
    report = run_pipeline(raw, processed, jobs=2, code=CODE)
    status = {r["recording"]: r["status"] for r in report.ran}
    assert status == {"clean.csv": "ok", "garbage.csv": "failed", "vdrop.csv": "ok"}
    bad = next(r for r in report.failed)
    assert "garbage.csv" in bad["error"] and bad["error"].startswith("ingest:")
    for name in ("clean", "vdrop"):
        paths = run_paths(processed, name)
        for f in (paths.signals, paths.kinematics, paths.validation, paths.comparison, paths.rrd,
                  paths.overview_png, paths.stamp):
            assert f.is_file(), f
        stamp = json.loads(paths.stamp.read_text())
        assert stamp["recording"] == f"{name}.csv" and stamp["runs"] == [name]
    summary = pd.read_csv(processed / "summary.csv")
    assert list(summary["run"]) == ["clean", "vdrop"]
    assert not list(processed.rglob(".*.tmp*"))

    # Noise floor on the clean recording, and the gate with the shipped thresholds.
    v = json.loads(run_paths(processed, "clean").validation.read_text())
    replay = v["replay"]["signals"]
    assert replay["theta"]["mse"] < 5e-6          # 100 clean recordings: median 9e-7, max 3.4e-6
    assert 0.7 * CURRENT_FLOOR_A2 < replay["current"]["mse"] < 1.4 * CURRENT_FLOOR_A2
    assert v["agreement"]["same_switches"] is True
    # One energy code path: validation's "measured" energy is derive's summary figure, to the bit.
    derived = json.loads(run_paths(processed, "clean").summary.read_text())["energy"]
    assert v["measured"]["energy"]["energy_paper_j"] == derived["energy_paper_j"]
    assert v["measured"]["energy"]["input_energy_j"] == derived["input_energy_j"]
    verdicts = {x.run: x for x in gate(processed, load_thresholds(SHIPPED_THRESHOLDS))}
    assert verdicts["clean"].passed
    assert not verdicts["vdrop"].passed
    out = subprocess.run([PDR, "gate", "--processed", str(processed), "--thresholds", str(SHIPPED_THRESHOLDS)],
                         capture_output=True, text=True)
    assert out.returncode == 1
    assert "FAIL vdrop" in out.stderr and "FAIL clean" not in out.stderr

    # Nothing changed: only the failing recording is tried again.
    again = run_pipeline(raw, processed, jobs=2, code=CODE)
    assert sorted(again.skipped) == ["clean.csv", "vdrop.csv"]
    assert [r["recording"] for r in again.ran] == ["garbage.csv"]

    # A changed rig file re-runs that recording only; a removed recording's runs go away.
    (raw / "garbage.csv").unlink()
    with open(raw / "clean.toml", "a") as fh:
        fh.write("\n# edited\n")
    third = run_pipeline(raw, processed, jobs=2, code=CODE)
    assert [r["recording"] for r in third.ran] == ["clean.csv"] and third.skipped == ["vdrop.csv"]
    (raw / "vdrop.csv").unlink()
    fourth = run_pipeline(raw, processed, jobs=1, code=CODE)
    assert fourth.removed == ["vdrop"] and not (processed / "vdrop").exists()
    assert list(pd.read_csv(processed / "summary.csv")["run"]) == ["clean"]


@pytest.mark.long
@pytest.mark.slow
def test_two_concurrent_runs_leave_processed_consistent(recordings, tmp_path):
    processed = tmp_path / "processed"
    cmd = [PDR, "run", "--raw", str(recordings), "--processed", str(processed), "-j", "1"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=240) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    # The lock made one wait while the other worked; the waiter then found the work done
    # (unless the source tree changed in between, which re-runs everything: still consistent).
    waited = [err for _, err in outs if err.startswith("pdr: waiting for another pdr process")]
    assert len(waited) == 1
    assert "2 unchanged and skipped" in waited[0] or "2 recording(s) processed" in waited[0]
    for name in ("clean", "vdrop"):
        paths = run_paths(processed, name)
        assert json.loads(paths.validation.read_text())["run"] == name
        assert json.loads(paths.stamp.read_text())["runs"] == [name]
    assert not list(processed.rglob(".*.tmp*"))


def test_code_version_is_a_short_stable_hash(tmp_path, monkeypatch):
    """The hash of every source path and its bytes, computed here on a small tree; any edit changes it."""
    import hashlib

    import pipeline.run.stamp as run_module

    pkg, schemas = tmp_path / "pipeline", tmp_path / "schemas"
    (pkg / "sub").mkdir(parents=True)
    schemas.mkdir()
    files = {"pipeline/a.py": b"x = 1\n", "pipeline/sub/b.py": b"y = 2\n", "schemas/s.json": b"{}"}
    for rel, data in files.items():
        (tmp_path / rel).write_bytes(data)
    monkeypatch.setattr(run_module, "PACKAGE_ROOT", pkg)
    monkeypatch.setattr(run_module, "SCHEMA_ROOT", schemas)
    h = hashlib.sha256()
    for rel, data in files.items():
        h.update(rel.encode())
        h.update(data)
    first = code_version()
    assert first == h.hexdigest()[:16]
    (pkg / "sub" / "b.py").write_bytes(b"y = 3\n")
    assert code_version() != first
    (pkg / "sub" / "b.py").write_bytes(b"y = 2\n")
    assert code_version() == first
    (schemas / "s.json").write_bytes(b"{ }")
    assert code_version() != first


def test_run_command_exit_status_and_missing_raw_folder(tmp_path):
    out = subprocess.run([PDR, "run", "--raw", str(tmp_path / "nope"), "--processed", str(tmp_path / "p")],
                         capture_output=True, text=True)
    assert out.returncode == 2
    assert "nope: raw folder not found" in out.stderr


@pytest.mark.slow
def test_without_logged_dir_replay_uses_the_inferred_phases(tmp_path):
    from pipeline.rig.serial import Artefacts

    raw = tmp_path / "raw"
    setup = RigSetup(artefacts=Artefacts(dir_column=False, garbled=3, crlf=True))
    write_recording(make_recording(setup, seed=13), raw, "nodir")
    report = run_pipeline(raw, tmp_path / "processed", jobs=1, code=CODE)
    assert [r["status"] for r in report.ran] == ["ok"]
    v = json.loads(run_paths(tmp_path / "processed", "nodir").validation.read_text())
    assert v["dir_inferred"] is True
    assert v["replay"]["signals"]["theta"]["mse"] < 5e-6           # at the noise floor
    assert v["replay"]["switches"]["n_measured"] >= 10


def test_tables_handed_over_by_derive_validate_as_the_files_do(recordings, tmp_path):
    """``pdr run`` passes derive's tables to validate in memory: the outputs must be those of reading the files."""
    from pipeline.derive.stage import derive_and_write
    from pipeline.ingest.stage import ingest_recording
    from pipeline.validate.rerun_log import stats_markdown
    from pipeline.validate.stage import derived_tables, panel_tables, validate_run

    (paths,) = ingest_recording(recordings / "clean.csv", tmp_path).runs
    tables = derive_and_write(paths)
    outputs = (paths.validation, paths.comparison, paths.overview_png)
    row_files = validate_run(paths, rrd=False)
    from_files = {f: f.read_bytes() for f in outputs}
    row_memory = validate_run(paths, rrd=False, derived={"kinematics": tables.kinematics, "phases": tables.phases,
                                                         "overshoot": tables.overshoot})
    for f in outputs:
        assert f.read_bytes() == from_files[f], f.name
    row_files.pop("timing_s"), row_memory.pop("timing_s")
    assert row_memory == row_files
    assert json.loads(paths.summary.read_text()) == tables.summary
    validation = json.loads(paths.validation.read_text())
    handed = panel_tables({"phases": tables.phases, "overshoot": tables.overshoot})
    assert stats_markdown("clean", validation, handed) == stats_markdown("clean", validation, derived_tables(paths))


def test_chunks_cover_every_recording_once_and_shrink_at_the_end():
    from pipeline.run import CHUNK_MAX, chunks

    for n in range(0, 90):
        for jobs in (1, 2, 3):
            parts = chunks(list(range(n)), jobs)
            assert [x for part in parts for x in part] == list(range(n)) and all(parts)
            assert max(map(len, parts), default=0) <= CHUNK_MAX
    sizes = [len(p) for p in chunks(list(range(100)), 2)]
    assert sizes[0] == CHUNK_MAX and sizes[-4:] == [CHUNK_MAX // 2] * 4
