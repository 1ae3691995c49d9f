"""Thresholds file, per-run verdicts, and the `pdr gate` command's table and exit status."""

from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.config import default_config
from pipeline.errors import ConfigError
from pipeline.model.effects import make_effect
from pipeline.validate.gate import (BUILTIN_DEFAULTS, UNITS, Check, builtin_thresholds, check_run, gate,
                                    load_thresholds, parse_thresholds)
from pipeline.validate.stage import validate_run
from tests.validate.synthetic import synthetic_kinematics, synthetic_run

SHIPPED = Path(__file__).resolve().parents[2] / "raw" / "thresholds.toml"
THRESHOLDS = """
[default.replay]
theta = 1e-5
current = 1.5e-3
[runs."loose".replay]
theta = 1.0
"""


def _validation(run: str, theta: float, current: float | None = 7e-4) -> dict:
    signals = {"theta": {"mse": theta}, "omega": {"mse": 1e-5}}
    if current is not None:
        signals["current"] = {"mse": current}
    return {"run": run, "replay": {"signals": signals}, "closed_loop": {"signals": signals}}


def test_shipped_thresholds_parse_and_gate_both_ways():
    """Each of the six shipped thresholds gates: just under passes, just over fails naming that way and signal."""
    t = load_thresholds(SHIPPED)
    assert t.default == BUILTIN_DEFAULTS                      # the file documents the built-in defaults
    for way in ("replay", "closed_loop"):
        for sig in ("theta", "omega", "current"):
            limit = t.default[way][sig]
            doc = {"run": "r", **{w: {"signals": {s: {"mse": 0.5 * t.default[w][s]} for s in t.default[w]}}
                                  for w in ("replay", "closed_loop")}}
            assert check_run(doc, t.for_run("r")).passed
            doc[way]["signals"][sig]["mse"] = limit                 # on the threshold: still within
            assert check_run(doc, t.for_run("r")).passed, (way, sig)
            doc[way]["signals"][sig]["mse"] = limit * (1 + 1e-9)
            verdict = check_run(doc, t.for_run("r"))
            assert not verdict.passed, (way, sig)
            assert verdict.failures() == [f"{way} {sig} MSE {limit * (1 + 1e-9):.4g} > {limit:.4g} {UNITS[sig]}"]


@pytest.mark.parametrize("text, key", [
    ("[defaults.replay]\ntheta = 1.0\n", "defaults"),
    ("[default.replay]\ntheta = -1.0\n", "default.replay.theta"),
    ("[default.replay]\nangle = 1.0\n", "default.replay.angle"),
    ("[default.sideways]\ntheta = 1.0\n", "default.sideways"),
    ("[runs.x.replay]\ntheta = \"small\"\n", "runs.x.replay.theta"),
    ("[default.replay]\ntheta = 0.0\n", "default.replay.theta"),
    ("[default]\nreplay = 1.0\n", "default.replay"),
    ("default = 3\n", "default"),
    ("runs = 1\n", "runs"),
])
def test_bad_thresholds_name_file_and_key(text, key):
    with pytest.raises(ConfigError) as err:
        parse_thresholds(__import__("tomllib").loads(text), "raw/thresholds.toml")
    assert f"raw/thresholds.toml, key '{key}'" in str(err.value)


def test_per_run_overrides_apply_to_the_run_and_its_segments():
    t = parse_thresholds(__import__("tomllib").loads(THRESHOLDS), "t.toml")
    assert t.for_run("other")["replay"]["theta"] == 1e-5
    assert t.for_run("loose")["replay"]["theta"] == 1.0
    assert t.for_run("loose-seg2")["replay"] == {"theta": 1.0, "current": 1.5e-3}


def test_verdicts_margins_and_ungated_signals():
    t = parse_thresholds(__import__("tomllib").loads(THRESHOLDS), "t.toml")
    ok = check_run(_validation("a", 5e-6), t.for_run("a"))
    assert ok.passed
    theta = next(c for c in ok.checks if c.way == "replay" and c.signal == "theta")
    assert theta.margin == pytest.approx(0.5)
    omega = next(c for c in ok.checks if c.signal == "omega")
    assert omega.threshold is None and omega.passed          # reported, not gated
    bad = check_run(_validation("b", 4e-5), t.for_run("b"))
    assert not bad.passed
    assert bad.failures() == ["replay theta MSE 4e-05 > 1e-05 rad^2"]
    no_current = check_run(_validation("c", 5e-6, current=None), t.for_run("c"))
    assert no_current.passed and all(c.signal != "current" for c in no_current.checks)


def test_gate_command_passes_clean_runs_and_fails_naming_the_biased_one(tmp_path):
    processed = tmp_path / "processed"
    thresholds = tmp_path / "thresholds.toml"
    thresholds.write_text(THRESHOLDS)
    for name in ("clean", "loose"):         # every run the thresholds name is there
        validate_run(synthetic_run(processed, name, kin=synthetic_kinematics(current_noise_a=0.02)),
                     rrd=False, png=False)
    runner = CliRunner()
    args = ["gate", "--processed", str(processed), "--thresholds", str(thresholds)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "all 2 runs within their thresholds" in result.output
    biased = default_config().plant_spec((make_effect("driver_voltage_drop", {"Vd": 0.6}),))
    validate_run(synthetic_run(processed, "biased", kin=synthetic_kinematics(biased, current_noise_a=0.02)),
                 rrd=False, png=False)
    synthetic_run(processed, "unvalidated")
    result = runner.invoke(app, args)
    assert result.exit_code == 1
    assert "gate: FAIL biased: replay theta MSE" in result.output
    assert "gate: FAIL unvalidated: no validation.json" in result.output
    assert "FAIL clean" not in result.output
    assert [v.run for v in gate(processed, load_thresholds(thresholds)) if not v.passed] == ["biased", "unvalidated"]


def test_margin_is_a_ratio():
    assert Check("r", "replay", "theta", 1.935e-1, 1e-5).margin_text() == "19,350x over"
    assert Check("r", "replay", "theta", 2.5e-6, 1e-5).margin_text() == "4x under"
    assert Check("r", "replay", "theta", 1e-5, 1e-5).margin_text() == "1x under"
    assert Check("r", "replay", "theta", 0.0, 1e-5).margin_text() == "MSE 0"
    assert Check("r", "replay", "omega", 1e-3, None).margin_text() == "-"


def _derived(spec=None):
    """A clean synthetic table with the derive stage's velocity estimator (what a processed run holds)."""
    from pipeline.derive.velocity import savgol_velocity

    kin = synthetic_kinematics(spec, current_noise_a=0.02)
    kin["omega_rad_s"] = savgol_velocity(kin["t_s"].to_numpy(), kin["theta_rad"].to_numpy())
    return kin


def _guard_mismatch_run(processed, name):
    """A recording whose sketch reversed at 1.1 rad, validated with the rig's 0.942 rad guard: the logged
    switching (replay) fits, the model's own switching (closed loop) does not."""
    from dataclasses import replace

    cfg = default_config()
    sketch = replace(cfg, controller=replace(cfg.controller, guard_rad=1.1)).plant_spec()
    return validate_run(synthetic_run(processed, name, kin=_derived(sketch)), rrd=False, png=False)


def test_gate_passes_a_clean_folder_without_a_thresholds_file_and_fails_a_closed_loop_only_miss(tmp_path, monkeypatch):
    processed = tmp_path / "processed"
    validate_run(synthetic_run(processed, "clean", kin=_derived()), rrd=False, png=False)
    monkeypatch.chdir(tmp_path)                              # no raw/thresholds.toml here
    runner = CliRunner()
    result = runner.invoke(app, ["gate", "--processed", str(processed)])
    assert result.exit_code == 0, result.output
    assert "using the built-in defaults (replay: theta 1e-05 rad^2" in result.output
    assert "MSE gate (built-in defaults)" in result.output
    assert "x under" in result.output and " %" not in result.output
    row = _guard_mismatch_run(processed, "late-guard")
    limits = builtin_thresholds().for_run("late-guard")
    assert all(row[f"replay_{s}_mse"] <= limits["replay"][s] for s in ("theta", "omega", "current"))
    assert row["closed_loop_theta_mse"] > limits["closed_loop"]["theta"]
    result = runner.invoke(app, ["gate", "--processed", str(processed)])
    assert result.exit_code == 1
    assert "gate: FAIL late-guard: closed_loop theta MSE" in result.output
    assert "replay" not in result.output.split("gate: FAIL late-guard:")[1].splitlines()[0]
    assert "FAIL clean" not in result.output
    # a thresholds file named on the command line must exist
    result = runner.invoke(app, ["gate", "--processed", str(processed), "--thresholds", "nope.toml"])
    assert result.exit_code != 0 and "nope.toml: thresholds file not found" in str(result.exception)


def test_margin_text_boundaries_and_checks_of_partly_logged_runs():
    assert Check("r", "replay", "theta", 1.5e-5, 1e-5).margin_text() == "1.5x over"
    assert Check("r", "replay", "theta", 1e-3, 1e-5).margin_text() == "100x over"
    assert Check("r", "replay", "theta", 9.9e-4, 1e-5).margin_text() == "99x over"
    # replay logged theta only, closed loop all three: every present signal is checked, each named by its run
    doc = {"run": "part", "replay": {"signals": {"theta": {"mse": 1e-6}}},
           "closed_loop": {"signals": {s: {"mse": 1e-6} for s in ("theta", "omega", "current")}}}
    verdict = check_run(doc, builtin_thresholds().for_run("part"))
    assert [(c.way, c.signal) for c in verdict.checks] == [("replay", "theta"), ("closed_loop", "theta"),
                                                           ("closed_loop", "omega"), ("closed_loop", "current")]
    assert {c.run for c in verdict.checks} == {"part"} and verdict.passed
    doc["closed_loop"]["signals"]["current"]["mse"] = 1.0
    assert check_run(doc, builtin_thresholds().for_run("part")).failures() == [
        "closed_loop current MSE 1 > 0.015 A^2"]


def test_segment_overrides_keep_the_stem_whole_and_gate_lists_every_run_folder(tmp_path):
    t = parse_thresholds(__import__("tomllib").loads('[runs."tank-segment".replay]\ntheta = 2.0\n'), "t.toml")
    assert t.for_run("tank-segment-seg2")["replay"]["theta"] == 2.0      # the stem is all before the last -seg
    assert t.for_run("tank-seg2")["replay"].get("theta") is None
    processed = tmp_path / "processed"
    synthetic_run(processed, "a-unvalidated")
    validate_run(synthetic_run(processed, "b", kin=synthetic_kinematics(duration=3.0)), rrd=False, png=False)
    (processed / ".hidden").mkdir()
    (processed / ".hidden" / "rig.json").write_text("{}")
    (processed / "no-rig").mkdir()
    verdicts = gate(processed, builtin_thresholds())
    assert [v.run for v in verdicts] == ["a-unvalidated", "b"]
    assert verdicts[0].failures() == ["no validation.json (pipeline failed before validate)"]
    assert verdicts[0].checks == () and len(verdicts[1].checks) == 6


@pytest.mark.parametrize("text, detail", [
    ("[default.sideways]\ntheta = 1.0\n", "unknown way, expected one of replay, closed_loop"),
    ("[default]\nreplay = 1.0\n", "expected a table of MSE thresholds"),
    ("[default.replay]\nangle = 1.0\n", "unknown signal, expected one of theta, omega, current"),
    ("default = 3\n", "expected a table with [..replay] and/or [..closed_loop]"),
    ("[defaults.replay]\ntheta = 1.0\n", 'unknown section, expected [default.<way>] or [runs."<run>".<way>]'),
    ("runs = 1\n", "expected a table of runs"),
])
def test_refusals_say_what_was_expected_and_name_the_file(tmp_path, text, detail):
    path = tmp_path / "thresholds.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_thresholds(path)
    assert str(err.value).startswith(f"{path}, key '") and str(err.value).endswith(detail)


def test_a_missing_signal_does_not_hide_the_next_one_and_a_missing_mse_fails():
    doc = {"run": "r", "replay": {"signals": {"theta": {"mse": 1e-6}, "current": {"mse": 1.0}}},
           "closed_loop": {"signals": {"theta": {}}}}
    verdict = check_run(doc, builtin_thresholds().for_run("r"))
    assert [(c.way, c.signal) for c in verdict.checks] == [("replay", "theta"), ("replay", "current"),
                                                           ("closed_loop", "theta")]
    assert verdict.failures() == ["replay current MSE 1 > 0.0015 A^2", "closed_loop theta MSE missing"]
    assert load_thresholds(SHIPPED).source == str(SHIPPED)
