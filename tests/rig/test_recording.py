"""The recording API: reproducible bytes, the user's TOML, ground truth that matches the capture."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from pipeline.config import default_config, resolve_config
from pipeline.errors import PdrError
from pipeline.model.effects import make_effect
from pipeline.rig.recording import RigSetup, make_recording, write_recording
from pipeline.rig.serial import Artefacts
from tests.rig.csvread import as_row, lines_of

ALL_ARTEFACTS = Artefacts(ide_prefix="ide2", crlf=True, bom=True, comments=2, blank_lines=2,
                          partial_first_line=True, garbled=4, dropped=3, reset_after_s=10.0)


@pytest.fixture(scope="module")
def paper():
    return make_recording(RigSetup(), seed=11)


def test_same_seed_same_bytes_everywhere(tmp_path):
    setup = RigSetup(effects=(make_effect("coulomb_friction", {"Tc": 5e-4}),), artefacts=ALL_ARTEFACTS)
    a, b = make_recording(setup, seed=3), make_recording(setup, seed=3)
    assert a.csv_bytes == b.csv_bytes and a.toml_text == b.toml_text
    pa, pb = write_recording(a, tmp_path / "a", "x"), write_recording(b, tmp_path / "b", "x")
    for key in pa:
        assert pa[key].read_bytes() == pb[key].read_bytes(), key


def test_different_seeds_differ():
    a, b = make_recording(RigSetup(), seed=1), make_recording(RigSetup(), seed=2)
    assert a.csv_bytes != b.csv_bytes
    assert a.truth_meta["sensor"]["zero_v_part"] != b.truth_meta["sensor"]["zero_v_part"]
    assert make_recording(RigSetup(seed=4)).csv_bytes == make_recording(RigSetup(), seed=4).csv_bytes


def test_capture_is_the_truth_through_the_sensor_chain(paper):
    t = paper.truth
    lines = lines_of(paper.csv_bytes)
    assert lines[0] == "t_ms,counts,adc,dir" and len(lines) == len(t) + 1
    rows = np.array([as_row(ln) for ln in lines[1:]])
    assert np.array_equal(rows, t[["t_ms", "counts", "adc", "dir"]].to_numpy())
    assert set(np.diff(t["t_ms"]).tolist()) == {50, 51}
    assert len(t) == 20 + 500                                    # 1 s motor-off pre-roll + the paper's 500 samples
    assert (t["dir"][:20] == 0).all() and t["dir"][20] == 1
    cpr = 6533.12
    assert np.max(np.abs(t["counts"] * 2 * math.pi / cpr - t["theta_rad"])) <= math.pi / cpr + 1e-12
    assert np.all(np.abs(np.diff(t["t_s"]) - 0.0503) < 0.0004)  # 50 ms + U(0, 0.6 ms)


def test_truth_records_the_plant_and_turning_points(paper):
    meta = paper.truth_meta
    assert meta["synthetic"] is True and meta["hidden_effects"] == [] and meta["seed"] == 11
    turns = meta["turning_points"]
    assert len(turns) >= 12
    assert max(tp["theta_rad"] for tp in turns) >= paper.truth["theta_rad"].max()
    json.dumps(meta)                                             # plain JSON


def test_toml_is_the_believed_rig_without_hidden_effects(tmp_path):
    believed = replace(default_config(), effects=(make_effect("loop_delay", {"Td": 0.05}),))
    rec = make_recording(RigSetup(config=believed, effects=(make_effect("coulomb_friction", {"Tc": 6e-4}),)), seed=1)
    path = tmp_path / "r.toml"
    path.write_text(rec.toml_text)
    cfg = resolve_config([path])
    assert cfg.model == default_config().model
    assert [e.name for e in cfg.effects] == ["loop_delay"]       # declared, not the hidden friction
    assert rec.toml_text.startswith("# SYNTHETIC")
    plant = rec.truth_meta["plant"]
    assert plant["Tc"] == 6e-4 and plant["Td"] == 0.05


def test_hidden_sensor_offset_makes_the_written_zero_wrong_by_i0_s(tmp_path):
    I0 = 0.15
    plain = make_recording(RigSetup(), seed=8)
    off = make_recording(RigSetup(effects=(make_effect("current_sensor_offset", {"I0": I0}),)), seed=8)
    S = 0.185
    z_plain, z_off = plain.truth_meta["sensor"]["zero_v_written"], off.truth_meta["sensor"]["zero_v_written"]
    assert z_plain - z_off == pytest.approx(I0 * S, abs=1e-4)
    assert np.array_equal(plain.truth["adc"], off.truth["adc"])  # the sensor output is the same ...
    path = tmp_path / "o.toml"
    path.write_text(off.toml_text)
    zero = resolve_config([path]).current_sensor.zero_v
    rest = off.truth[off.truth["dir"] == 0]
    decoded = (rest["adc"] * 5.0 / 1024 - zero) / S                # ... but read with the user's zero
    assert decoded.mean() == pytest.approx(I0, abs=0.01)
    assert np.allclose(off.truth["current_measured_a"], off.truth["current_a"] + I0)


def test_zero_v_modes_and_auto_has_rest_data():
    auto = make_recording(RigSetup(zero_v="auto"), seed=2)
    assert 'zero_v = "auto"' in auto.toml_text
    assert (auto.truth["dir"][:20] == 0).all() and np.all(auto.truth["current_a"][:20] == 0.0)
    assert "zero_v = 2.5\n" in make_recording(RigSetup(zero_v="nominal"), seed=2).toml_text
    with pytest.raises(ValueError):
        RigSetup(zero_v="guess")


def test_adc_clips_on_a_sensitive_part():
    cfg = default_config()
    cfg = replace(cfg, current_sensor=replace(cfg.current_sensor, sensitivity_v_per_a=10.0))
    rec = make_recording(RigSetup(config=cfg, duration_s=5.0), seed=1)
    assert rec.truth["adc"].max() == 1023 and rec.truth_meta["sensor"]["adc_clipped_samples"] > 0
    assert make_recording(RigSetup(duration_s=5.0), seed=1).truth_meta["sensor"]["adc_clipped_samples"] == 0


def test_write_recording_layout_and_truth_read_back(tmp_path, paper):
    paths = write_recording(paper, tmp_path, "paper_run")
    assert paths["csv"] == tmp_path / "paper_run.csv" and paths["csv"].read_bytes() == paper.csv_bytes
    assert paths["truth"] == tmp_path / "truth" / "paper_run.truth.parquet"
    back = pq.read_table(paths["truth"]).to_pandas()
    pd.testing.assert_frame_equal(back.astype({"status": "string"}), paper.truth, check_dtype=False)
    assert json.loads(paths["truth_json"].read_text())["seed"] == 11
    with pytest.raises(PdrError):
        write_recording(paper, tmp_path, "../escape")


def test_stick_samples_flagged_in_truth():
    rec = make_recording(RigSetup(effects=(make_effect("coulomb_friction", {"Tc": 3e-3}),), duration_s=8.0), seed=1)
    stuck = rec.truth[rec.truth["stuck"]]
    assert len(stuck) > 5 and (stuck["omega_rad_s"] == 0.0).all()
