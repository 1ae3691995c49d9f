"""Hand-made captures: every tolerated artefact, every refusal, units."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.errors import IngestError, PdrError
from tests.ingest.helpers import CLEAN, config_from_toml, ingest, quarantined_lines


def test_clean_file_converts_units():
    runs, report = ingest(CLEAN)
    assert [r.name for r in runs] == ["rec"]
    df = runs[0].signals
    assert list(df.columns) == ["t_s", "t_raw", "line", "segment", "counts", "theta_rad", "adc", "current_v",
                                "current_a", "dir", "mode"]
    assert df["line"].tolist() == list(range(2, 12))
    np.testing.assert_allclose(df["t_s"], np.arange(10) * 0.05)
    np.testing.assert_allclose(df["theta_rad"], df["counts"] * 2 * np.pi / 6533.12)
    np.testing.assert_allclose(df["current_v"], df["adc"] * 5.0 / 1024)
    np.testing.assert_allclose(df["current_a"], (df["adc"] * 5.0 / 1024 - 2.5) / 0.185)
    assert df["mode"].tolist() == [0, 0, 0, 0, 1, 1, 1, 1, 2, 2]
    assert report["rows"] == {"read": 10, "kept": 10, "quarantined": 0}
    assert report["quarantined"] == []


def test_tolerated_artefacts_keep_every_good_row():
    body = CLEAN.decode().splitlines()
    lines = ["\ufeff12:34:56.789 -> " + body[0], "# sketch v1", ""]
    lines += [f"18:2:{13 + i}.5 -> {b}" for i, b in enumerate(body[1:4])]
    lines += ["", "# guard reached"] + body[4:]
    data = "\r\n".join(lines).encode() + b"\r\n"
    runs, report = ingest(data)
    assert len(runs[0].signals) == 10
    assert report["quarantined"] == []
    assert report["lines"]["comment"] == 2 and report["lines"]["blank"] == 2
    assert any("IDE timestamp prefix removed from 4 lines" in d for d in report["defects"])
    assert any("byte-order mark" in d for d in report["defects"])


def test_partial_and_garbled_lines_are_reported_with_line_and_reason(tmp_path):
    cfg = config_from_toml(tmp_path, "[ingest]\nmax_bad_fraction = 0.5\n")
    data = (b"11,1\n" + CLEAN.replace(b"100,0,511,0\n", b"100,0,5x1,0\n")
            .replace(b"250,12,545,1\n", b"250,12,54\n").replace(b"300,30,550,1\n", b"300,30,550,1350,55,549,1\n"))
    runs, report = ingest(data, cfg)
    assert quarantined_lines(report) == [1, 5, 8, 9]
    reasons = {q["line"]: q["reason"] for q in report["quarantined"]}
    assert reasons[1] == "expected 4 fields, got 2"
    assert reasons[5] == "adc: expected an integer, got '5x1'"
    assert reasons[8] == "expected 4 fields, got 3"
    assert reasons[9] == "expected 4 fields, got 7"
    assert report["rows"] == {"read": 11, "kept": 7, "quarantined": 4}


def test_board_reset_splits_segments_into_runs():
    runs, report = ingest(CLEAN + CLEAN)          # the board restarts and prints its header again
    assert [r.name for r in runs] == ["rec-seg1", "rec-seg2"]
    assert report["lines"]["header"] == [1, 12]
    assert runs[1].signals["line"].iloc[0] == 13
    assert runs[1].signals["segment"].iloc[0] == 1
    assert runs[1].signals["t_s"].iloc[0] == 0.0
    assert any("board reset" in d for d in report["defects"])
    assert report["board_resets"] == 1


def test_reset_without_header_restarts_time_near_zero():
    body = b"\n".join(CLEAN.splitlines()[1:]) + b"\n"
    runs, report = ingest(body + body)
    assert [r.name for r in runs] == ["rec-seg1", "rec-seg2"]
    assert runs[1].signals["line"].iloc[0] == 11 and runs[1].signals["t_s"].iloc[0] == 0.0
    assert report["board_resets"] == 1
    assert any("board reset without a header line" in d for d in report["defects"])


def test_time_drop_with_counts_not_restarting_is_not_a_reset():
    body = b"\n".join(CLEAN.splitlines()[1:]) + b"\n"
    with pytest.raises(IngestError, match="time goes back from 450 to 0"):
        ingest(body + body.replace(b"0,0,511,0\n", b"0,7,511,0\n", 1))


def test_large_time_drop_is_not_a_reset():
    data = CLEAN.replace(b"300,30", b"30300,30").replace(b"350,55", b"30350,55").replace(b"400,80", b"20400,0") \
        .replace(b"450,90", b"20450,90")
    with pytest.raises(IngestError, match="time goes back from 30350 to 20400"):
        ingest(data)


def test_rows_before_first_header_form_their_own_segment():
    runs, report = ingest(b"900,4,511,0\n950,4,511,0\n" + CLEAN)
    assert [r.name for r in runs] == ["rec-seg1", "rec-seg2"]
    assert report["board_resets"] == 0
    assert runs[0].signals["line"].tolist() == [1, 2]


def test_single_row_segment_is_flagged_not_a_run():
    runs, report = ingest(CLEAN + b"t_ms,counts,adc,dir\n0,0,511,0\n")
    assert [r.name for r in runs] == ["rec"]
    assert "flagged" in report["segments"][1]


def test_headerless_positional_columns():
    data = b"\n".join(CLEAN.splitlines()[1:]) + b"\n"
    runs, report = ingest(data)
    assert len(runs[0].signals) == 10
    three = b"0,0,511\n50,1,512\n100,2,513\n"
    runs, _ = ingest(three)
    assert "dir" not in runs[0].signals and "adc" in runs[0].signals


def test_millis_wrap_is_undone():
    top = 2**32
    data = f"t_ms,counts,adc,dir\n{top - 100},0,511,0\n{top - 50},0,511,0\n0,0,511,0\n50,0,511,0\n".encode()
    runs, report = ingest(data)
    np.testing.assert_allclose(runs[0].signals["t_s"], [0, 0.05, 0.1, 0.15])
    assert report["segments"][0]["counter_wraps"] == 1


def test_lone_out_of_order_time_is_quarantined():
    data = CLEAN.replace(b"150,0,510,0", b"950,0,510,0")
    runs, report = ingest(data)
    assert quarantined_lines(report) == [5]
    assert "out of order" in report["quarantined"][0]["reason"]


def test_out_of_range_values_are_quarantined():
    data = CLEAN.replace(b"150,0,510,0", b"150,0,1024,0").replace(b"200,3,530,1", b"200,3,530,2")
    runs, report = ingest(data)
    assert quarantined_lines(report) == [5, 6]
    assert "adc outside 0..1023" in report["quarantined"][0]["reason"]
    assert "dir not -1, 0 or 1" in report["quarantined"][1]["reason"]


@pytest.mark.parametrize("data, expected", [
    (b"", "empty file"),
    (b"\n\r\n  \n", "empty file"),
    (bytes(range(256)) * 40, "binary or non-UTF-8"),
    (b"\x00\x01\x02PNG" * 100 + b"\n" + b"\xff\xfe" * 50, "binary or non-UTF-8"),
    (b"time,enc,i\n1,2,3\n", "no recognisable columns"),
    (b"hello world\n", "no recognisable columns"),
    (b"1\n2\n3\n", "no recognisable columns"),
    (CLEAN + b"x\n" * 5, "too many unreadable rows"),
    (CLEAN.replace(b"300,30", b"30,30").replace(b"350,55", b"35,55"), "time goes back"),
])
def test_refusals_name_the_problem(data, expected):
    with pytest.raises(IngestError) as err:
        ingest(data)
    assert expected in str(err.value)
    assert str(err.value).startswith("rec.csv")
    assert "\n" not in str(err.value)


def test_bad_fraction_threshold_is_configurable(tmp_path):
    data = CLEAN + b"x\n" * 5
    cfg = config_from_toml(tmp_path, "[ingest]\nmax_bad_fraction = 0.5\n")
    runs, report = ingest(data, cfg)
    assert report["rows"]["quarantined"] == 5


def test_columns_mapping_and_time_units(tmp_path):
    cfg = config_from_toml(tmp_path, '[columns]\nt_ms = "us"\ncounts = "enc"\nadc = ""\ndir = ""\ntime_unit = "us"\n')
    runs, report = ingest(b"enc , us, pwm\n5, 1000000, 3\n7, 1050000, 3\n9, 1100000, 3\n", cfg)
    df = runs[0].signals
    assert "adc" not in df and "dir" not in df and "current_a" not in df
    np.testing.assert_allclose(df["t_s"], [0, 0.05, 0.1])
    assert df["counts"].tolist() == [5, 7, 9]
    assert report["segments"][0]["not_logged"] == ["adc", "dir"]
    cfg = config_from_toml(tmp_path, '[columns]\ntime_unit = "s"\n')
    runs, _ = ingest(b"t_ms,counts,adc,dir\n0.000,0,511,0\n0.050,1,511,0\n0.100,2,511,0\n", cfg)
    np.testing.assert_allclose(runs[0].signals["t_s"], [0, 0.05, 0.1])


def test_missing_optional_column_is_absent_not_invented():
    runs, report = ingest(b"t_ms,counts,adc\n0,0,511\n50,1,511\n100,2,511\n")
    assert "dir" not in runs[0].signals and "mode" not in runs[0].signals
    assert any("not in the header" in d for d in report["defects"])


def test_zero_auto_from_motor_off_preroll(tmp_path):
    cfg = config_from_toml(tmp_path, '[current_sensor]\nzero_v = "auto"\n')
    runs, report = ingest(CLEAN, cfg)
    zero = report["segments"][0]["current_zero"]
    assert zero["method"] == "motor off before first driven, pinion still" and zero["samples"] == 4
    assert zero["zero_v"] == pytest.approx(511 * 5.0 / 1024)
    assert zero["spread_v"] == pytest.approx(np.std(np.array([511, 512, 511, 510]) * 5.0 / 1024))
    np.testing.assert_allclose(runs[0].signals["current_a"].iloc[0], 0.0, atol=1e-12)


def test_zero_auto_without_dir_uses_samples_before_the_encoder_moves(tmp_path):
    cfg = config_from_toml(tmp_path, '[current_sensor]\nzero_v = "auto"\n')
    data = b"t_ms,counts,adc\n0,0,500\n50,0,502\n100,0,500\n150,0,530\n200,5,540\n250,9,540\n"
    runs, report = ingest(data, cfg)
    zero = report["segments"][0]["current_zero"]
    assert zero["method"] == "before the encoder first moves" and zero["samples"] == 3


def test_zero_auto_refuses_without_samples_at_rest(tmp_path):
    cfg = config_from_toml(tmp_path, '[current_sensor]\nzero_v = "auto"\n')
    with pytest.raises(IngestError, match="current_sensor.zero_v"):
        ingest(b"t_ms,counts,adc,dir\n0,0,530,1\n50,3,540,1\n100,9,541,1\n", cfg)


def test_zero_auto_of_a_segment_without_rest_is_the_sensors_from_another_segment(tmp_path):
    """A board reset does not change the sensor part: a segment that opens driven takes the zero read at
    rest in another segment, and says whose it is."""
    cfg = config_from_toml(tmp_path, '[current_sensor]\nzero_v = "auto"\n')
    driven = b"t_ms,counts,adc,dir\n0,0,530,1\n50,3,540,1\n100,9,541,1\n150,14,541,1\n"
    runs, report = ingest(driven + CLEAN, cfg)
    zeros = [s["current_zero"] for s in report["segments"]]
    assert zeros[0]["zero_v"] == zeros[1]["zero_v"] == pytest.approx(511 * 5.0 / 1024)
    assert zeros[0]["method"] == "motor off before first driven, pinion still, of segment 1 (none at rest in this one)"
    assert zeros[1]["method"] == "motor off before first driven, pinion still"


def test_zero_auto_is_not_read_where_the_pinion_moves_with_the_motor_off(tmp_path):
    """After a board reset the winding can still carry current (La/Ra is seconds), and the springs then push
    the pinion back against it: those motor-off readings are not the zero; the earlier segment's is."""
    cfg = config_from_toml(tmp_path, '[current_sensor]\nzero_v = "auto"\n')
    swinging = (b"t_ms,counts,adc,dir\n0,0,530,0\n50,-3,529,0\n100,-5,528,0\n150,-6,528,0\n200,-7,528,0\n"
                b"250,-6,545,1\n300,2,550,1\n350,12,549,1\n")
    runs, report = ingest(CLEAN + swinging, cfg)
    zeros = [s["current_zero"] for s in report["segments"]]
    assert zeros[1]["zero_v"] == zeros[0]["zero_v"] == pytest.approx(511 * 5.0 / 1024)
    assert zeros[1]["method"].endswith("of segment 0 (none at rest in this one)")
    assert len(runs) == 2


def test_timing_report_gaps_and_period_contradiction():
    data = CLEAN.replace(b"250,12,545,1\n", b"")
    _, report = ingest(data)
    timing = report["segments"][0]["timing"]
    assert timing["median_period_s"] == pytest.approx(0.05)
    assert timing["gaps"] == 1 and timing["gap_list"][0]["line"] == 7
    _, report = ingest(CLEAN.replace(b"0,", b"0,"), None)
    assert report["segments"][0]["timing"]["defects"] == []


def test_adc_saturation_counted():
    data = CLEAN.replace(b"545", b"1023").replace(b"480", b"0")
    _, report = ingest(data)
    assert report["segments"][0]["adc_saturation"] == {"low": 1, "high": 1, "samples": 10}


def test_only_pdr_errors_escape_for_odd_input():
    for data in (b",,,\n,,,\n", b"t_ms,counts,adc,dir\n", b"#only comments\n", b"t_ms,counts\n1,2\n"):
        with pytest.raises(PdrError):
            ingest(data)


def test_noise_bytes_on_a_line_quarantine_that_line_only():
    data = CLEAN.replace(b"150,0,510,0", b"150,0,5\xff\x0010,0")
    runs, report = ingest(data)
    assert quarantined_lines(report) == [5]
    assert report["quarantined"][0]["reason"] == "binary or non-UTF-8 bytes"
    assert report["lines"]["blank"] == 0 and len(runs[0].signals) == 9
