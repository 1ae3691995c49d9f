"""Derive on a recording without an encoder: what the current and a logged dir give is derived, the same
figures as with the encoder; what needs the angle is absent and named in not_computed."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import default_config
from pipeline.derive.energy import ELECTRICAL_KEYS
from pipeline.derive.stage import derive_tables
from pipeline.derive.tables import schema_table
from pipeline.ingest.stage import ingest_capture
from pipeline.rig.recording import RigSetup, make_recording

CFG = default_config()


@pytest.fixture(scope="module")
def signals():
    data = make_recording(RigSetup(duration_s=8.0), seed=5).csv_bytes
    runs, _ = ingest_capture(data, CFG, "rec.csv", "rec")
    return runs[0].signals


def test_current_phases_and_electrical_energy_equal_the_encoder_runs(signals):
    full = derive_tables(signals, CFG)
    bare = derive_tables(signals.drop(columns=["counts", "theta_rad"]), CFG)
    assert list(bare.kinematics.columns) == ["t_s", "current_a", "current_smooth_a", "dir", "dir_inferred"]
    for name in bare.kinematics.columns:
        np.testing.assert_array_equal(bare.kinematics[name], full.kinematics[name], err_msg=name)
    assert len(bare.phases) == len(full.phases) > 3
    for name in bare.phases.columns:
        if name != "end_reason":
            np.testing.assert_array_equal(bare.phases[name], full.phases[name], err_msg=name)
    assert set(bare.phases["end_reason"]) <= {"reversed", "motor on", "motor off", "end of recording"}
    assert "reversed" in set(bare.phases["end_reason"])
    energy = bare.summary["energy"]
    assert sorted(k for k in energy if k in ELECTRICAL_KEYS) == sorted(ELECTRICAL_KEYS)
    for key in (*ELECTRICAL_KEYS, "energy_paper_logged_current_j"):
        assert energy[key] == full.summary["energy"][key], key
    for key in energy:
        assert bare.summary["energy_uncertainty_j"].get(key, 0.0) == pytest.approx(
            full.summary["energy_uncertainty_j"].get(key, 0.0), rel=1e-9), key
    assert set(bare.summary["not_computed"]) == {"velocity", "overshoot", "cycles", "energy_mechanical"}
    assert all("columns.counts" in why for why in bare.summary["not_computed"].values())
    assert bare.summary["theta_rad"] is None and bare.summary["velocity"] is None
    assert len(bare.overshoot) == len(bare.cycles) == 0
    for name, table in (("kinematics", bare.kinematics), ("phases", bare.phases), ("overshoot", bare.overshoot),
                        ("cycles", bare.cycles)):
        schema_table(name, table, where=name)          # each keeps to its schema, angle columns absent


def test_without_dir_either_the_current_alone(signals):
    bare = derive_tables(signals.drop(columns=["counts", "theta_rad", "dir", "mode"]), CFG)
    assert list(bare.kinematics.columns) == ["t_s", "current_a", "current_smooth_a"]
    assert len(bare.phases) == 0 and "phases" in bare.summary["not_computed"]
    energy = bare.summary["energy"]
    assert "input_energy_j" not in energy and "input_energy" in bare.summary["not_computed"]
    assert energy["copper_loss_j"] > 0 and np.isfinite(energy["energy_paper_j"])
    assert bare.summary["energy_paper_window"]["first_sample"] == 0
    schema_table("kinematics", bare.kinematics, where="kinematics")
