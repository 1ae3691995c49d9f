"""``pdr calibrate`` end to end on a virtual rig that is not the paper's (its [model] undeclared)."""

import json
import tomllib

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.config import config_for_recording
from pipeline.rig.other_rigs import rigs, truth_of, write_rig
from pipeline.rig.recording import RigSetup, make_recording, write_recording

runner = CliRunner()
RIG = rigs(seed=20261128, count=1)[0]       # a rig off Table I, not one the benchmark reports on


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    raw = tmp_path_factory.mktemp("lab") / "raw"
    paths = write_rig(RIG, raw, seed=5, roles=("cal_a", "cal_b"), duration_s=12.0)
    (raw / "rig.toml").write_text("# our rig\n[drive]\nv_in = 6.0   # the bench supply\n")
    return raw, paths


@pytest.fixture(scope="module")
def calibrated(lab, tmp_path_factory):
    raw, paths = lab
    out = tmp_path_factory.mktemp("out")
    res = runner.invoke(app, ["calibrate", str(paths["cal_a"]), str(paths["cal_b"]), "--json", "--adopt",
                              "--processed", str(out)])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout), out


def test_the_json_has_every_model_key_and_says_what_is_identifiable(calibrated):
    doc, _ = calibrated
    keys = {"R", "J", "Ke", "Kt", "La", "Ra", "K1", "K2", "b"}
    assert set(doc["parameters"]) == keys and set(doc["identifiable"]) == keys and set(doc["intervals"]) == keys
    assert {k for k, v in doc["identifiable"].items() if v} == {"Ra", "Ke", "La"}
    assert all(doc["intervals"][k] is None for k in keys - {"Ra", "Ke", "La"})
    assert {c["name"] for c in doc["combinations"]} == {"Kt/J", "b/J", "R^2 (K1 + K2)/J"}
    assert doc["parameters"]["J"] == pytest.approx(4.857e-4)        # the convention holds J at its prior


def test_identifiable_parameters_and_combinations_hold_the_truth(calibrated):
    doc, _ = calibrated
    truth = truth_of(RIG)
    for k in ("Ra", "Ke", "La"):
        lo, hi = doc["intervals"][k]
        assert lo <= truth[k] <= hi, (k, truth[k], lo, hi)
        assert doc["parameters"][k] == pytest.approx(truth[k], rel=0.05)
    combos = {"Kt/J": truth["Kt"] / truth["J"], "b/J": truth["b"] / truth["J"],
              "R^2 (K1 + K2)/J": truth["R"] ** 2 * (truth["K1"] + truth["K2"]) / truth["J"]}
    for c in doc["combinations"]:
        assert c["value"] == pytest.approx(combos[c["name"]], rel=0.05), c
    assert doc["mse_after"]["theta"] < 0.01 * doc["mse_before"]["theta"]


def test_adopt_writes_model_into_rig_toml_keeping_the_rest(lab, calibrated):
    raw, paths = lab
    doc, out = calibrated
    text = (raw / "rig.toml").read_text()
    assert text.startswith("# our rig\n[drive]\nv_in = 6.0   # the bench supply\n")
    assert tomllib.loads(text)["model"]["Ra"] == pytest.approx(doc["parameters"]["Ra"])
    cfg = config_for_recording(paths["cal_a"])                       # what validation and discovery now use
    assert cfg.model.Ra == pytest.approx(doc["parameters"]["Ra"])
    for name in ("calibration.json", "calibration.md", "model.toml", "calibration.rrd"):
        assert (out / "calibration" / name).is_file()


def test_the_rerun_report_reads_back(calibrated):
    from rerun.chunk import RrdReader

    _, out = calibrated
    reader = RrdReader(out / "calibration" / "calibration.rrd")
    assert reader.recordings()


def test_a_recording_that_cannot_pin_anything_is_refused(tmp_path):
    rec = make_recording(RigSetup(duration_s=0.5, pre_roll_s=3.0, seed=1))     # the motor off but 0.5 s
    write_recording(rec, tmp_path, "idle")
    res = runner.invoke(app, ["calibrate", str(tmp_path / "idle.csv"), "--json", "--processed", str(tmp_path / "p")])
    assert res.exit_code != 0
    message = str(res.exception)
    assert "idle" in message and "never reverses the motor" in message


def test_adopt_needs_raw_csvs_in_one_folder(tmp_path):
    res = runner.invoke(app, ["calibrate", "somerun", "--adopt"])
    assert res.exit_code != 0 and "--adopt" in str(res.exception)
