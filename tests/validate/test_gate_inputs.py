"""`pdr gate` on what a hostile user or a broken disk leaves: corrupt validation.json files, a run without
figures, a thresholds file naming no run, and a gate started while a run holds processed/."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.validate.stage import validate_run
from tests.validate.synthetic import synthetic_run
from tests.validate.test_gate import _derived

PDR = str(Path(sys.executable).with_name("pdr"))
CORRUPT = {
    "garbage": (b"\x89PNG\r\n\x1a\n\xff\xfe", "not UTF-8 text"),
    "truncated": (b'{"run": "truncated", "replay": {"signals": {"theta": {"ms', "not valid JSON at line 1"),
    "not-an-object": (b"[1, 2, 3]", "expected a JSON object, got list"),
    "wrong-types": (b'{"run": "wrong-types", "replay": [1, 2]}', "'replay': expected an object, got list"),
    "mse-string": (b'{"run": "mse-string", "replay": {"signals": {"theta": {"mse": "0.001"}}}}',
                   "'replay.signals.theta.mse': expected a number (MSE in rad^2), got '0.001'"),
    "no-figures": (b'{"run": "no-figures"}', "holds no MSE figures to gate"),
}


def _clean(processed: Path, name: str = "clean") -> None:
    validate_run(synthetic_run(processed, name, kin=_derived()), rrd=False, png=False)


def _gate(processed: Path, *extra: str):
    return CliRunner().invoke(app, ["gate", "--processed", str(processed), *extra])


def test_every_corrupt_validation_json_fails_its_run_by_name_and_the_others_are_still_checked(tmp_path):
    processed = tmp_path / "processed"
    _clean(processed, "a-clean")
    for name, (data, _why) in CORRUPT.items():
        synthetic_run(processed, name)
        (processed / name / "validation.json").write_bytes(data)
    _clean(processed, "z-clean")
    result = _gate(processed)
    assert result.exit_code == 1, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "internal error" not in result.output and "Traceback" not in result.output
    lines = [line for line in result.output.splitlines() if line.startswith("gate: FAIL ")]
    assert len(lines) == len(CORRUPT), result.output
    for name, (_data, why) in CORRUPT.items():
        line = next(line for line in lines if line.startswith(f"gate: FAIL {name}: "))
        if name != "no-figures":
            assert str(processed / name / "validation.json") in line, line
        assert why in line, line
    assert "FAIL a-clean" not in result.output and "FAIL z-clean" not in result.output
    assert f"gate: {len(CORRUPT)} of {len(CORRUPT) + 2} runs failed" in result.output


def test_a_threshold_naming_no_run_fails_the_gate_naming_it(tmp_path):
    processed = tmp_path / "processed"
    _clean(processed, "bench-1")
    _clean(processed, "tank-seg2")
    thresholds = tmp_path / "thresholds.toml"
    thresholds.write_text('[runs."typo".replay]\ntheta = 1.0\n[runs."tank".replay]\ntheta = 1.0\n'
                          '[runs."bench-1".closed_loop]\ntheta = 1.0\n')
    result = _gate(processed, "--thresholds", str(thresholds))
    assert result.exit_code == 1, result.output
    fails = [line for line in result.output.splitlines() if line.startswith("gate: FAIL ")]
    assert fails == [f"gate: FAIL typo: {thresholds} has thresholds for this run, but {processed} holds no such "
                     "run (a misspelt name?)"], result.output
    thresholds.write_text('[runs."tank".replay]\ntheta = 1.0\n')       # a segment's stem names its run
    assert _gate(processed, "--thresholds", str(thresholds)).exit_code == 0


def test_a_run_whose_ways_were_both_skipped_for_a_stated_reason_is_reported_not_failed(tmp_path):
    processed = tmp_path / "processed"
    _clean(processed)
    synthetic_run(processed, "current-only")
    (processed / "current-only" / "validation.json").write_text(json.dumps(
        {"run": "current-only", "skipped": {"replay": "no dir", "closed_loop": "no angle"}}))
    result = _gate(processed)
    assert result.exit_code == 0, result.output
    assert "skipped: no encoder" in result.output


@pytest.mark.slow
def test_gate_while_a_run_holds_the_folder_waits_for_it_instead_of_finding_nothing(tmp_path):
    from filelock import FileLock

    processed = tmp_path / "processed"
    processed.mkdir()
    lock = FileLock(processed / ".pdr.lock")
    lock.acquire()
    try:
        proc = subprocess.Popen([PDR, "gate", "--processed", str(processed)], cwd=tmp_path,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        first = proc.stderr.readline()           # said once it has found the folder locked
        assert first.startswith("pdr: waiting for another pdr process"), first
        time.sleep(0.2)
        assert proc.poll() is None, "the gate did not wait for the lock"
        _clean(processed)                        # what the run was writing
    finally:
        lock.release()
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, out + err
    assert "gate: all 1 runs within their thresholds" in out
