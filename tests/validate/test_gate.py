"""Thresholds file, per-run verdicts, and the `pdr gate` command's table and exit status."""

from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.config import default_config
from pipeline.errors import ConfigError
from pipeline.model.effects import make_effect
from pipeline.validate.gate import check_run, gate, load_thresholds, parse_thresholds
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
    t = load_thresholds(SHIPPED)
    assert set(t.default) == {"replay", "closed_loop"}
    assert t.default["replay"]["theta"] < t.default["closed_loop"]["theta"]


@pytest.mark.parametrize("text, key", [
    ("[defaults.replay]\ntheta = 1.0\n", "defaults"),
    ("[default.replay]\ntheta = -1.0\n", "default.replay.theta"),
    ("[default.replay]\nangle = 1.0\n", "default.replay.angle"),
    ("[default.sideways]\ntheta = 1.0\n", "default.sideways"),
    ("[runs.x.replay]\ntheta = \"small\"\n", "runs.x.replay.theta"),
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
    validate_run(synthetic_run(processed, "clean", kin=synthetic_kinematics(current_noise_a=0.02)),
                 rrd=False, png=False)
    runner = CliRunner()
    args = ["gate", "--processed", str(processed), "--thresholds", str(thresholds)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "all 1 runs within their thresholds" in result.output
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
