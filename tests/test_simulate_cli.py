"""pdr simulate, through the real typer app."""

import json

import pytest
from typer.testing import CliRunner

from pipeline.cli import app

runner = CliRunner()


def test_simulate_json_reports_the_paper_run():
    res = runner.invoke(app, ["simulate", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert 12 <= out["switches"] <= 14
    assert out["theta_max"] > 0.9425 and out["theta_min"] < -0.9425
    assert out["energy_paper_j"] == pytest.approx(16.496, rel=0.03)
    for key in ("input_energy_j", "copper_loss_j", "friction_loss_j", "spring_energy_change_j",
                "kinetic_energy_change_j", "magnetic_energy_change_j", "balance_residual_j"):
        assert isinstance(out[key], float)
    assert out["samples"] == 500 and out["effects"] == []


def test_simulate_with_config_and_continuous_guard(tmp_path):
    toml = tmp_path / "rig.toml"
    toml.write_text("[model]\nRa = 259.0\n[effects]\ncoulomb_friction = { Tc = 6e-4 }\n")
    res = runner.invoke(app, ["simulate", "--config", str(toml), "--duration", "5", "--json",
                              "--guard", "continuous"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["switches"] == 0 and out["samples"] == 101 and out["guard"] == "continuous"
    assert out["effects"][0]["name"] == "coulomb_friction"


def test_simulate_text_output():
    res = runner.invoke(app, ["simulate", "--duration", "3"])
    assert res.exit_code == 0
    assert "switches" in res.stdout and "energy (paper)" in res.stdout and "copper loss" in res.stdout


@pytest.mark.parametrize("args, key", [(["--duration", "0"], "--duration"), (["--guard", "never"], "--guard")])
def test_simulate_refuses_bad_options(args, key):
    res = runner.invoke(app, ["simulate", *args])
    assert res.exit_code != 0
    assert key in str(res.exception)


def test_simulate_bad_toml_names_the_key(tmp_path):
    toml = tmp_path / "rig.toml"
    toml.write_text("[model]\nRa = -1\n")
    res = runner.invoke(app, ["simulate", "--config", str(toml)])
    assert res.exit_code != 0 and "model.Ra" in str(res.exception)


def test_console_command_turns_a_refusal_into_one_line_and_status_2():
    import subprocess
    import sys
    from pathlib import Path

    pdr = Path(sys.executable).parent / "pdr"
    res = subprocess.run([str(pdr), "simulate", "--duration", "-1"], capture_output=True, text=True)
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "--duration" in res.stderr
