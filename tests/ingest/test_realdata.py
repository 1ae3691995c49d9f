"""The real captures in tests/data/realdata, each with a [columns] TOML, ingest with their defects reported."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import IngestError
from pipeline.ingest.stage import ingest_recording
from tests.ingest.helpers import config_from_toml

REAL = Path(__file__).resolve().parents[1] / "data" / "realdata"     # licences and sources: its README.md
AKAFAEL = REAL / "akafael__discrete-servo-control"
MOUSE = REAL / "opatiny__micromouse"
AKAFAEL_COLUMNS = '[columns]\nt_ms = "time(ms)"\ncounts = "enconder(steps)"\nadc = ""\ndir = ""\n'


def _ingest(tmp_path: Path, csv: Path, toml: str):
    cfg = config_from_toml(tmp_path, toml)
    return ingest_recording(csv, tmp_path / "processed", config=cfg)


def _defects(result) -> str:
    return "\n".join(result.report["defects"])


@pytest.mark.parametrize("name, period, rows, defect", [
    ("expdata_20201120_214756.csv", 0.06, 3000, None),
    ("expdata_20201120_215030.csv", 0.01, 3000, "median sampling period 0.015 s contradicts controller.period_s = 0.01"),
    ("expdata_20201124_220716.csv", 0.1, 3000, None),
    ("expdata_20201126_212205.csv", 0.1, 1000, None),
    ("expdata_20201126_203627.csv", 0.1, 600, "time does not advance: 599 of 599 steps are 0 (timer stuck)"),
])
def test_akafael_files(tmp_path, name, period, rows, defect):
    result = _ingest(tmp_path, AKAFAEL / name, AKAFAEL_COLUMNS + f"[controller]\nperiod_s = {period}\n")
    df = result.tables[Path(name).stem]
    assert len(df) == rows and result.report["rows"]["quarantined"] == 0
    assert "adc" not in df and "dir" not in df
    if defect:
        assert defect in _defects(result)
    else:
        assert result.report["segments"][0]["timing"]["defects"] == []
    raw = np.loadtxt(AKAFAEL / name, delimiter=",", skiprows=1)
    np.testing.assert_array_equal(df["counts"], raw[:, 1])


def test_akafael_phase_shifted_file_is_reframed(tmp_path):
    result = _ingest(tmp_path, AKAFAEL / "expdata_20201126_204516.csv",
                     AKAFAEL_COLUMNS + "[controller]\nperiod_s = 0.1\n")
    df = result.tables["expdata_20201126_204516"]
    defects = _defects(result)
    assert "phase-shifted rows" in defects
    assert "last line has no line ending" in defects
    assert len(df) == 600
    np.testing.assert_allclose(df["t_raw"], np.arange(1, 601) * 100.0)
    assert df["counts"].iloc[:3].tolist() == [0, 41, 109]       # "100,0,941" + "255,200,41,942" + ...
    assert result.report["quarantined"] == [{"line": 602, "reason": "incomplete record at the end: 1 of 4 fields",
                                             "text": ""}]


def test_akafael_mixed_layouts_read_by_name(tmp_path):
    three = _ingest(tmp_path, AKAFAEL / "expdata_20201124_220716.csv", AKAFAEL_COLUMNS)
    four = _ingest(tmp_path, AKAFAEL / "expdata_20201126_212205.csv", AKAFAEL_COLUMNS)
    assert three.report["segments"][0]["columns"] == four.report["segments"][0]["columns"] == ["counts", "t_raw"]


MOUSE_ENCODER = '[columns]\nt_ms = "time"\ncounts = "leftEncoder"\nadc = ""\ndir = ""\n[controller]\nperiod_s = 0.005\n'


@pytest.mark.parametrize("name, rows", [("encoders3.csv", 770), ("encoders5.csv", 856)])
def test_micromouse_encoder_files(tmp_path, name, rows):
    result = _ingest(tmp_path, MOUSE / name, MOUSE_ENCODER)
    df = result.tables[Path(name).stem]
    assert len(df) == rows and result.report["rows"]["quarantined"] == 0
    assert df["t_s"].iloc[0] == 0.0 and df["t_raw"].iloc[0] > 60000          # not zero-based: made so
    assert result.report["segments"][0]["timing"]["median_period_s"] == pytest.approx(0.005)
    assert "last line has no line ending" in _defects(result)
    raw = np.loadtxt(MOUSE / name, delimiter=",", skiprows=1)
    np.testing.assert_array_equal(df["counts"], raw[:, 1])


# The speed and battery files log no encoder count: an integer column stands in for counts so the
# timing path is exercised; without it the refusal names the missing column.
@pytest.mark.parametrize("name, counts, period, defect", [
    ("testPid7.csv", "leftCommand", 0.002, "gaps longer than 1.5 median periods"),
    ("controllerDelayImpact5ms.csv", "leftCommand", 0.005, "median sampling period 0.006 s contradicts"),
    ("batteryVoltage3.csv", "voltage", 0.001, None),
])
def test_micromouse_timing_files(tmp_path, name, counts, period, defect):
    toml = f'[columns]\nt_ms = "time"\ncounts = "{counts}"\nadc = ""\ndir = ""\n[controller]\nperiod_s = {period}\n'
    result = _ingest(tmp_path, MOUSE / name, toml)
    # a battery voltage moves faster than the paper's motor could turn an encoder: its lone spikes are
    # quarantined as encoder jumps, and nothing else is
    reasons = {q["reason"].split(":")[0] for q in result.report["quarantined"]}
    assert reasons == ({"encoder jump"} if counts == "voltage" else set())
    if defect:
        assert defect in _defects(result)
    with pytest.raises(IngestError, match="expected a column named 'leftEncoder'"):
        _ingest(tmp_path, MOUSE / name, MOUSE_ENCODER)


def test_realdata_files_untouched(tmp_path):
    before = {p: p.read_bytes() for p in AKAFAEL.glob("*.csv")}
    for p in before:
        _ingest(tmp_path, p, AKAFAEL_COLUMNS)
    assert all(p.read_bytes() == b for p, b in before.items())
