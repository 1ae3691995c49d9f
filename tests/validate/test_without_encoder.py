"""Validation of a recording without an encoder: the logged commands replayed through the model and the
current compared (closed loop skipped, in a sentence); without dir either, nothing simulated.  Every output
read back by its own library; the gate takes such runs without failing on what they lack."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.derive.stage import derive_and_write
from pipeline.ingest.stage import ingest_recording
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.validate.gate import BUILTIN_DEFAULTS, check_run
from pipeline.validate.stage import validate_run
from tests.ingest.helpers import without_columns
from tests.ingest.test_outputs import _read_mcap


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Three runs of one virtual-rig recording (its calibrated TOML): as logged, without the encoder
    column, and without the encoder and dir columns."""
    base = tmp_path_factory.mktemp("noenc")
    raw, processed = base / "raw", base / "processed"
    raw.mkdir()
    rec = make_recording(RigSetup(duration_s=8.0), seed=2)
    for name, drop, columns in (("full", (), ""), ("bare", (b"counts",), 'counts = ""\n'),
                                ("current", (b"counts", b"dir"), 'counts = ""\ndir = ""\n')):
        (raw / f"{name}.csv").write_bytes(without_columns(rec.csv_bytes, *drop))
        (raw / f"{name}.toml").write_text(rec.toml_text + ("\n[columns]\n" + columns if columns else ""))
        for paths in ingest_recording(raw / f"{name}.csv", processed).runs:
            derive_and_write(paths)
            validate_run(paths)
    return processed


def _validation(processed, name):
    return json.loads((processed / name / "validation.json").read_text())


def test_replay_compares_the_current_as_well_as_with_the_encoder(runs):
    full, bare = _validation(runs, "full"), _validation(runs, "bare")
    assert "closed_loop" not in bare and list(bare["skipped"]) == ["closed_loop"]
    assert bare["skipped"]["closed_loop"].startswith("closed loop skipped: the simulator's guard switches on the angle")
    assert list(bare["replay"]["signals"]) == ["current"]
    assert bare["replay"]["signals"]["current"]["mse"] == pytest.approx(full["replay"]["signals"]["current"]["mse"],
                                                                        rel=0.05)
    assert bare["replay"]["switches"]["n_measured"] == full["replay"]["switches"]["n_measured"] > 2
    assert bare["replay"]["energy_error"]["input_j"] is not None
    assert bare["measured"]["oscillation"] is None and bare["initial_state"] is not None
    verdict = check_run(bare, BUILTIN_DEFAULTS)
    assert [(c.way, c.signal) for c in verdict.checks] == [("replay", "current")] and verdict.passed
    assert verdict.skipped == ("closed_loop",)


def test_the_comparison_table_and_mcap_hold_what_exists(runs):
    table = pq.read_table(runs / "bare" / "comparison.parquet")
    assert not [c for c in table.column_names if "closed_loop" in c or c in ("theta_rad", "omega_rad_s")]
    assert {"current_a", "current_replay_a", "theta_replay_rad", "current_residual_replay_a"} <= set(table.column_names)
    np.testing.assert_array_equal(table.column("current_residual_replay_a").to_numpy(),
                                  table.column("current_a").to_numpy() - table.column("current_replay_a").to_numpy())
    messages, _, _, _, _ = _read_mcap(runs / "bare" / "comparison.mcap")
    assert sorted(messages) == ["/measured/command", "/measured/current", "/model/replay", "/residuals/replay"]
    assert set(messages["/residuals/replay"][0][1]) == {"current_residual_replay_a"}
    only = pq.read_table(runs / "current" / "comparison.parquet")
    assert only.column_names == ["t_s", "current_a"]
    messages, _, _, _, _ = _read_mcap(runs / "current" / "comparison.mcap")
    assert sorted(messages) == ["/measured/current"]


def _scalars(path, entity):
    values = []
    for ch in RrdReader(path).stream().to_chunks():
        if ch.entity_path == entity and not ch.is_static:
            values += ch.to_record_batch().column("Scalars:scalars").to_pylist()
    return np.array(values)


def _text(path, entity):
    for ch in RrdReader(path).stream().to_chunks():
        if ch.entity_path == entity and ch.is_static:
            batch = ch.to_record_batch()
            if "TextDocument:text" in batch.schema.names:
                return batch.column("TextDocument:text").to_pylist()[0][0]
    return None


def test_the_rerun_recording_and_figure_show_what_was_logged(runs):
    comparison = pq.read_table(runs / "bare" / "comparison.parquet")
    current = _scalars(runs / "bare" / "bare.rrd", "/signals/current")
    np.testing.assert_allclose(current[:, 0], comparison.column("current_replay_a").to_numpy())
    np.testing.assert_allclose(current[:, 1], comparison.column("current_a").to_numpy())
    assert len(_scalars(runs / "bare" / "bare.rrd", "/signals/theta/switches_logged")) == 0
    assert "Closed loop skipped" in _text(runs / "bare" / "bare.rrd", "/stats")
    alone = _scalars(runs / "current" / "current.rrd", "/signals/current")
    np.testing.assert_allclose(alone[:, 0], pq.read_table(runs / "current" / "comparison.parquet")
                               .column("current_a").to_numpy())
    assert len(_scalars(runs / "current" / "current.rrd", "/signals/theta")) == 0
    for name in ("bare", "current"):
        assert (runs / name / "overview.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_gate_passes_runs_without_an_encoder_and_says_what_was_skipped(runs):
    current = _validation(runs, "current")
    assert "replay" not in current and sorted(current["skipped"]) == ["closed_loop", "replay"]
    verdict = check_run(current, BUILTIN_DEFAULTS)
    assert verdict.checks == () and verdict.passed
    result = CliRunner().invoke(app, ["gate", "--processed", str(runs)])
    assert result.exit_code == 0, result.output
    assert result.output.count("skipped: no encoder") == 3
    summary = CliRunner().invoke(app, ["validate", "bare", "current", "--processed", str(runs), "--no-png"])
    assert summary.exit_code == 0, summary.output
