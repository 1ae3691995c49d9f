"""Every serial artefact class of the virtual rig: exactly the good samples kept, exactly the bad lines reported."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.ingest.stage import ingest_recording
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.rig.serial import Artefacts

BAD_KINDS = ("partial", "garbled_truncated", "garbled_flipped", "garbled_merged")

ARTEFACT_CLASSES = {
    "plain": Artefacts(),
    "no_header": Artefacts(header=False),
    "renamed_columns": Artefacts(column_names=("time", "enc", "i_raw", "cmd")),
    "no_dir_column": Artefacts(dir_column=False),
    "micros": Artefacts(time_unit="us", column_names=("time_us", "enc", "i_raw", "mode")),
    "seconds": Artefacts(time_unit="s"),
    "ide_classic": Artefacts(ide_prefix="classic"),
    "ide2": Artefacts(ide_prefix="ide2"),
    "crlf_bom": Artefacts(crlf=True, bom=True),
    "comments_blanks": Artefacts(comments=5, blank_lines=4),
    "partial_first_line": Artefacts(partial_first_line=True),
    "garbled": Artefacts(garbled=6),
    "dropped": Artefacts(dropped=4),
    "reset": Artefacts(reset_after_s=3.0, reset_gap_s=2.0),
    "reset_no_header": Artefacts(header=False, reset_after_s=3.0, reset_gap_s=2.0),
    "everything": Artefacts(ide_prefix="ide2", crlf=True, bom=True, comments=3, blank_lines=3,
                            partial_first_line=True, garbled=5, dropped=3, reset_after_s=3.0, reset_gap_s=2.0),
}


def _make(tmp_path: Path, art: Artefacts, seed: int = 3, **setup):
    rec = make_recording(RigSetup(artefacts=art, duration_s=6.0, pre_roll_s=0.5, **setup), seed)
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "cap.csv").write_bytes(rec.csv_bytes)
    (raw / "cap.toml").write_text(rec.toml_text)
    return rec, ingest_recording(raw / "cap.csv", tmp_path / "processed")


@pytest.mark.parametrize("name", list(ARTEFACT_CLASSES))
def test_artefact_class(tmp_path, name):
    art = ARTEFACT_CLASSES[name]
    rec, result = _make(tmp_path, art)
    truth = rec.truth
    ok = truth[truth["status"] == "ok"]
    got = pd.concat(result.tables.values(), ignore_index=True)
    assert got["line"].tolist() == ok["line"].tolist()
    assert got["counts"].tolist() == ok["counts"].tolist()
    assert got["adc"].tolist() == ok["adc"].tolist()
    np.testing.assert_allclose(got["t_raw"], ok["t_raw"])
    if art.dir_column:
        assert got["dir"].tolist() == ok["dir"].tolist()
    else:
        assert "dir" not in got and "mode" not in got
    injected = rec.truth_meta["artefacts"]["injected"]
    bad_lines = sorted(a["line"] for a in injected if a["kind"] in BAD_KINDS)
    assert [q["line"] for q in result.report["quarantined"]] == bad_lines
    n_segments = truth["segment"].nunique()
    assert len(result.runs) == n_segments
    if n_segments > 1:
        assert [r.name for r in result.runs] == ["cap-seg1", "cap-seg2"]
    for df in result.tables.values():
        assert df["t_s"].iloc[0] == 0.0 and np.all(np.diff(df["t_s"]) >= 0)
    if art.dropped:
        gaps = sum(s["timing"]["gaps"] for s in result.report["segments"] if "timing" in s)
        assert gaps >= 1


def test_zero_auto_estimate_matches_the_part(tmp_path):
    rec, result = _make(tmp_path, Artefacts(), zero_v="auto")
    zero = result.report["segments"][0]["current_zero"]
    assert zero["method"] == "motor off before first driven, pinion still" and zero["samples"] >= 5
    part = rec.truth_meta["sensor"]["zero_v_part"]
    assert abs(zero["zero_v"] - part) < 3 * 5.0 / 1024
    assert zero["spread_v"] < 3 * 5.0 / 1024


def test_converted_signals_match_truth(tmp_path):
    rec, result = _make(tmp_path, Artefacts())
    df = result.tables["cap"]
    truth = rec.truth
    cpr = rec.truth_meta["sensor"]["counts_per_rev"]
    np.testing.assert_allclose(df["theta_rad"], truth["counts"] * 2 * np.pi / cpr)
    # one encoder count of quantisation, one ADC step + noise of current
    assert np.max(np.abs(df["theta_rad"] - truth["theta_rad"])) < 2 * np.pi / cpr * 1.01
    np.testing.assert_allclose(df["t_s"], truth["t_ms"] / 1000 - truth["t_ms"].iloc[0] / 1000)
    err = df["current_a"] - truth["current_measured_a"]
    assert np.sqrt(np.mean(err**2)) < 0.1


def test_zero_auto_after_a_board_reset_with_the_pinion_still_moving_is_the_parts(tmp_path):
    """A reset mid-run, logging again 2 s later: the winding still carries current (La/Ra is 7 s) and the
    springs push the pinion back against it, so the new segment's motor-off readings are not at rest.  Its
    zero is the first segment's, which is the part's (the mean of floor-quantised readings: half a step below)."""
    art = Artefacts(reset_after_s=3.0, reset_gap_s=2.0)
    rec, result = _make(tmp_path, art, zero_v="auto")
    step = 5.0 / 1024
    expected = rec.truth_meta["sensor"]["zero_v_part"] - 0.5 * step
    zeros = [s["current_zero"] for s in result.report["segments"]]
    assert len(zeros) == 2 and len(result.runs) == 2
    assert zeros[1]["method"].endswith("of segment 0 (none at rest in this one)")
    for zero in zeros:
        assert abs(zero["zero_v"] - expected) < 0.5 * step
