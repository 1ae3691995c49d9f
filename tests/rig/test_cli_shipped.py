"""`pdr rig make` / `pdr rig shipped`, and the shipped recordings in raw/."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.config import resolve_config
from pipeline.errors import PdrError
from pipeline.model.simulate import simulate
from pipeline.rig.recording import make_recording
from pipeline.rig.shipped import SHIPPED

REPO = Path(__file__).resolve().parents[2]
runner = CliRunner()


def test_make_writes_a_recording_with_hidden_effect_and_artefacts(tmp_path):
    res = runner.invoke(app, ["rig", "make", "hb", "--out", str(tmp_path), "--effect", "backlash:gap=0.05",
                              "--declare", "loop_delay:Td=0.02", "--artefact", "crlf", "--artefact", "garbled=2",
                              "--seed", "3", "--duration", "4"])
    assert res.exit_code == 0, res.output
    assert "hidden effects: backlash(gap=0.05)" in res.output
    csv = (tmp_path / "hb.csv").read_bytes()
    assert b"\r\n" in csv and (tmp_path / "truth" / "hb.truth.parquet").is_file()
    toml = (tmp_path / "hb.toml").read_text()
    assert "loop_delay" in toml and "backlash" not in toml
    again = runner.invoke(app, ["rig", "make", "hb2", "--out", str(tmp_path), "--effect", "backlash:gap=0.05",
                                "--declare", "loop_delay:Td=0.02", "--artefact", "crlf", "--artefact", "garbled=2",
                                "--seed", "3", "--duration", "4"])
    assert again.exit_code == 0 and (tmp_path / "hb2.csv").read_bytes() == csv


@pytest.mark.parametrize("args, key", [
    (["--effect", "nope:x=1"], "--effect.nope"),
    (["--effect", "backlash"], "--effect"),
    (["--effect", "backlash:gap=9"], "--effect.backlash.gap"),
    (["--artefact", "sparkles"], "--artefact"),
    (["--artefact", "reset=99"], None),
    (["--zero-v", "guess"], None),
])
def test_make_refuses_bad_options_with_a_pdr_error(tmp_path, args, key):
    res = runner.invoke(app, ["rig", "make", "x", "--out", str(tmp_path), *args])
    assert isinstance(res.exception, PdrError), res.output
    if key:
        assert res.exception.key == key
    assert not (tmp_path / "x.csv").exists()


def test_cli_error_is_one_line_and_exit_2(tmp_path):
    proc = subprocess.run([sys.executable, "-c", "from pipeline.cli import main; main()", "rig", "make", "x",
                           "--out", str(tmp_path), "--effect", "backlash:gap=oops"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "--effect" in proc.stderr


def test_shipped_files_in_raw_are_up_to_date():
    res = runner.invoke(app, ["rig", "shipped", "--check", "--out", str(REPO / "raw")])
    assert res.exit_code == 0, res.output


def test_shipped_check_finds_a_stale_file(tmp_path):
    assert runner.invoke(app, ["rig", "shipped", "--out", str(tmp_path)]).exit_code == 0
    (tmp_path / "paper_clean.csv").write_text("t_ms,counts,adc,dir\n")
    res = runner.invoke(app, ["rig", "shipped", "--check", "--out", str(tmp_path)])
    assert res.exit_code == 1 and "paper_clean.csv" in res.output


@pytest.mark.parametrize("name", list(SHIPPED))
def test_shipped_recordings_are_explained_by_their_own_toml(tmp_path, name):
    """What validation will see: the fast model from the TOML, driven at the logged millis() instants."""
    rec = make_recording(SHIPPED[name][1])
    (tmp_path / "r.toml").write_text(rec.toml_text)
    cfg = resolve_config([tmp_path / "r.toml"])
    spec = cfg.plant_spec()
    cs = cfg.current_sensor
    for _, seg in rec.truth[rec.truth["status"] == "ok"].groupby("segment"):
        t = (seg["t_ms"].to_numpy() - seg["t_ms"].iloc[0]) / 1000.0
        dirs = seg["dir"].to_numpy()
        sim = simulate(spec, t, dir_log=dirs, closed_loop=False)
        theta = seg["counts"].to_numpy() * 2 * np.pi / cfg.encoder.counts_per_rev
        volts = seg["adc"].to_numpy() * cs.adc_vref / cs.adc_steps
        zero = volts[seg["dir"].to_numpy() == 0].mean() if cs.zero_v == "auto" else cs.zero_v
        current = (volts - zero) / cs.sensitivity_v_per_a
        assert np.sqrt(np.mean((theta - sim.theta) ** 2)) < 0.01, "theta rms [rad]"
        assert np.sqrt(np.mean((current - sim.current_measured) ** 2)) < 0.04, "current rms [A]"
        closed = simulate(spec, t, dir_log=dirs, closed_loop=True)
        assert np.array_equal(closed.dir, dirs)                   # see pipeline.rig.shipped on seeds
        assert np.sqrt(np.mean((theta - closed.theta) ** 2)) < 0.01
