"""A capture without an encoder column (``columns.counts = ""``): ingested with its angle columns absent,
the current as it would be with the encoder, and one sentence in the report saying what is skipped."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.config import default_config, resolve_config
from pipeline.errors import ConfigError, IngestError
from pipeline.ingest.stage import ingest_recording, summary_text
from pipeline.rig.recording import RigSetup, make_recording
from tests.ingest.helpers import ingest, without_columns
from tests.ingest.test_outputs import _read_mcap

NO_ENCODER = '[columns]\ncounts = ""\n'


@pytest.fixture(scope="module")
def capture() -> bytes:
    return make_recording(RigSetup(duration_s=4.0), seed=3).csv_bytes


def _write(folder, name: str, data: bytes, toml: str | None):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.csv").write_bytes(data)
    if toml is not None:
        (folder / f"{name}.toml").write_text(toml)
    return folder / f"{name}.csv"


def test_current_and_command_as_with_the_encoder_and_no_angle_columns(tmp_path, capture):
    full = ingest_recording(_write(tmp_path / "raw", "full", capture, None), tmp_path / "processed")
    bare = ingest_recording(_write(tmp_path / "raw", "bare", without_columns(capture, b"counts"), NO_ENCODER),
                            tmp_path / "processed")
    table = pq.read_table(bare.runs[0].signals)
    reference = pq.read_table(full.runs[0].signals)
    assert table.column_names == [c for c in reference.column_names if c not in ("counts", "theta_rad")]
    for name in table.column_names:
        assert table.column(name).equals(reference.column(name)), name
    assert table.schema.field("current_a").metadata[b"unit"] == b"A"
    report = bare.report
    assert report["segments"][0]["not_logged"] == ["counts"]
    assert report["without_angle"].startswith("no angle (no encoder column, columns.counts = \"\")")
    assert "closed loop skipped" in report["without_angle"] and "discovery" in report["without_angle"]
    assert full.report["without_angle"] is None
    said = [ln for ln in summary_text(report).splitlines() if "no angle" in ln]
    assert len(said) == 1


def test_the_mcap_has_no_encoder_channel(tmp_path, capture):
    bare = ingest_recording(_write(tmp_path, "bare", without_columns(capture, b"counts"), NO_ENCODER),
                            tmp_path / "processed")
    messages, schemas, _, _, _ = _read_mcap(bare.runs[0].mcap)
    assert sorted(messages) == ["/command", "/current"]
    assert len(messages["/current"]) == len(bare.tables["bare"])
    assert "theta_rad" not in str(schemas)


def test_headerless_rows_of_time_current_and_command(tmp_path):
    cfg = resolve_config([_toml(tmp_path, NO_ENCODER)])
    runs, report = ingest(b"0,511,0\n50,512,0\n100,530,1\n150,545,1\n", cfg)
    assert list(runs[0].signals.columns) == ["t_s", "t_raw", "line", "segment", "adc", "current_v", "current_a",
                                             "dir", "mode"]
    assert report["without_angle"] is not None


def test_a_missing_encoder_column_is_refused_saying_how_to_declare_it():
    with pytest.raises(IngestError, match=r"columns\.counts.*counts = \"\" when the capture has no encoder"):
        ingest(b"t_ms,adc,dir\n0,511,0\n50,512,0\n100,530,1\n", default_config())


def test_neither_encoder_nor_current_is_refused_in_one_line(tmp_path):
    with pytest.raises(ConfigError, match="columns.counts.*with neither, the capture has nothing pdr can process"):
        resolve_config([_toml(tmp_path, '[columns]\ncounts = ""\nadc = ""\n')])
    cfg = resolve_config([_toml(tmp_path, NO_ENCODER)])
    with pytest.raises(IngestError, match="no encoder column .* and no column named 'adc'"):
        ingest(b"t_ms,dir\n0,0\n50,1\n100,1\n", cfg)


def test_an_automatic_zero_needs_dir_without_an_encoder(tmp_path):
    cfg = resolve_config([_toml(tmp_path, NO_ENCODER + 'dir = ""\n[current_sensor]\nzero_v = "auto"\n')])
    with pytest.raises(IngestError, match=r"zero_v = \"auto\" needs at least 3 samples at rest .*found 0"):
        ingest(b"t_ms,adc\n0,511\n50,512\n100,530\n150,545\n", cfg)
    cfg = resolve_config([_toml(tmp_path, NO_ENCODER + '[current_sensor]\nzero_v = "auto"\n')])
    runs, _ = ingest(b"t_ms,adc,dir\n0,511,0\n50,513,0\n100,511,0\n150,600,1\n", cfg)
    assert np.isclose(runs[0].signals["current_a"].iloc[:3].mean(), 0.0)      # the zero is the rest level


def _toml(folder, text: str):
    path = folder / "rig.toml"
    path.write_text(text)
    return path
