"""The live view's decoder against the ingest stage on the same bytes, fed in arbitrary chunks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from pipeline.config import resolve_config
from pipeline.ingest.stage import ingest_capture
from pipeline.record.decode import LineDecoder, Samples
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.rig.serial import Artefacts
from pipeline.validate.compare import switch_indices

MESSY = Artefacts(ide_prefix="ide2", crlf=True, bom=True, garbled=5, comments=3, blank_lines=2,
                  partial_first_line=True, reset_after_s=6, reset_gap_s=4)


def _chunks(data: bytes, rng: np.random.Generator) -> list[tuple[int, bytes]]:
    """The bytes cut at random places, as serial reads return them (1 to 40 bytes)."""
    cuts = np.cumsum(rng.integers(1, 41, size=len(data)))
    cuts = np.r_[0, cuts[cuts < len(data)], len(data)]
    return [(int(a), data[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]


def _decode(decoder: LineDecoder, chunks: list[tuple[int, bytes]], per_feed: int) -> Samples:
    parts = [decoder.feed(chunks[i:i + per_feed]) for i in range(0, len(chunks), per_feed)]
    return Samples(**{k: np.concatenate([getattr(p, k) for p in parts])
                      for k in ("t_s", "theta_rad", "current_a", "dir", "segment")})


def _ingested(rec, tmp_path):
    toml = tmp_path / "rig.toml"
    toml.write_text(rec.toml_text)
    cfg = resolve_config([toml])
    runs, report = ingest_capture(rec.csv_bytes, cfg, "live.csv", "live")
    return cfg, pd.concat([r.signals for r in runs], ignore_index=True), report


@pytest.mark.parametrize("zero_v", ["calibrated", "auto"])
def test_decoder_matches_ingest_on_a_messy_capture(tmp_path, zero_v):
    rec = make_recording(RigSetup(artefacts=MESSY, zero_v=zero_v, duration_s=12.0, seed=5))
    cfg, signals, report = _ingested(rec, tmp_path)
    decoder = LineDecoder(cfg)
    got = _decode(decoder, _chunks(rec.csv_bytes, np.random.default_rng(1)), per_feed=7)

    assert len(got) == len(signals) == report["rows"]["kept"]
    np.testing.assert_array_equal(got.theta_rad, signals["theta_rad"].to_numpy())
    np.testing.assert_array_equal(got.dir, signals["dir"].to_numpy())
    np.testing.assert_array_equal(got.segment, signals["segment"].to_numpy())
    driven = np.flatnonzero(signals["dir"].to_numpy() != 0)
    # calibrated: the same zero from the first sample; auto: the same rest samples once the motor has run
    np.testing.assert_allclose(got.current_a[driven], signals["current_a"].to_numpy()[driven], rtol=0, atol=1e-12)
    tally = decoder.tally
    assert tally.unparsed == report["rows"]["quarantined"] == 6          # 5 garbled + the partial first line
    assert tally.segment == 2 and tally.skipped_lines == 0
    expected_switches = sum(len(switch_indices(s["dir"].to_numpy())) for _k, s in signals.groupby("segment"))
    assert tally.switches == expected_switches > 0
    # time runs on: the second segment is laid after the first, each at its own sample spacing
    assert np.all(np.diff(got.t_s) > 0)
    seg2 = signals["segment"].to_numpy() == 2
    np.testing.assert_allclose(np.diff(got.t_s[seg2]), np.diff(signals["t_s"].to_numpy()[seg2]))


def test_a_dropped_chunk_costs_the_view_one_line_never_a_wrong_sample(tmp_path):
    rec = make_recording(RigSetup(duration_s=4.0, seed=2))
    cfg, signals, _report = _ingested(rec, tmp_path)
    chunks = _chunks(rec.csv_bytes, np.random.default_rng(3))
    lost = len(chunks) // 2
    decoder = LineDecoder(cfg)
    got = _decode(decoder, chunks[:lost] + chunks[lost + 1:], per_feed=5)

    assert decoder.tally.skipped_lines == 1 and decoder.tally.unparsed == 0
    truth = signals["theta_rad"].to_numpy()
    assert len(truth) - 2 <= len(got) < len(truth)          # the broken line, and a line inside the chunk
    assert set(got.theta_rad.tolist()) <= set(truth.tolist())
    assert np.all(np.isin(got.t_s, signals["t_s"].to_numpy()))


def test_partial_line_waits_for_its_end_and_a_cut_last_line_is_counted(tmp_path):
    rec = make_recording(RigSetup(duration_s=1.0, seed=4))
    cfg, signals, _report = _ingested(rec, tmp_path)
    data = rec.csv_bytes
    decoder = LineDecoder(cfg)
    cut = data.index(b"\n", data.index(b"\n") + 1) + 4                 # header, one row, 4 bytes of the next
    first = decoder.feed([(0, data[:cut])])
    assert len(first) == 1
    rest = decoder.feed([(cut, data[cut:] + b"12345,6")])              # the capture ends mid-line
    assert len(first) + len(rest) == len(signals)
    assert rest.theta_rad[0] == signals["theta_rad"].iloc[1]
    assert decoder.tally.unparsed == 0
    assert len(decoder.finish()) == 0 and decoder.tally.unparsed == 1     # as ingest: a short row, reported


@pytest.mark.parametrize("art, cr_only", [(Artefacts(header=False, dir_column=False, blank_lines=1), False),
                                          (Artefacts(time_unit="us", column_names=("us", "pos", "cur", "d"),
                                                     garbled=2), False),
                                          (Artefacts(comments=2), True)],
                         ids=["no header, no dir", "micros, own names", "CR-only line endings"])
def test_decoder_reads_other_sketches_as_ingest_does(tmp_path, art, cr_only):
    rec = make_recording(RigSetup(artefacts=art, duration_s=3.0, seed=8))
    if cr_only:
        rec = replace(rec, csv_bytes=rec.csv_bytes.replace(b"\n", b"\r"))
    cfg, signals, report = _ingested(rec, tmp_path)
    decoder = LineDecoder(cfg)
    chunks = _chunks(rec.csv_bytes, np.random.default_rng(5))
    got = _decode(decoder, chunks, per_feed=3)
    last = decoder.finish()
    assert len(got) + len(last) == len(signals)
    np.testing.assert_array_equal(np.r_[got.theta_rad, last.theta_rad], signals["theta_rad"].to_numpy())
    np.testing.assert_allclose(np.r_[got.t_s, last.t_s], signals["t_s"].to_numpy(), rtol=0, atol=1e-9)
    assert decoder.tally.unparsed == report["rows"]["quarantined"]
    assert last.has_dir == ("dir" in signals.columns)
