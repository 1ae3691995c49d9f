"""A rig's ADC is the rig's: a 12-bit converter at 3.3 V (an ESP32, docs/FORMAT.md's ``adc_steps``/``adc_vref``)
is ingested and discovered like the UNO's 10 bits at 5 V; the schema's ADC range follows the rig's TOML."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.config import default_config
from pipeline.errors import SchemaError
from pipeline.model.effects import make_effect
from pipeline.rig.recording import RigSetup, make_recording, write_recording
from pipeline.run import run_pipeline
from pipeline.schemas import load_schema


def _twelve_bit():
    cfg = default_config()
    return replace(cfg, current_sensor=replace(cfg.current_sensor, adc_steps=4096, adc_vref=3.3))


def test_the_adc_range_comes_from_the_rigs_configuration():
    ten, twelve = load_schema("signals", default_config()), load_schema("signals", _twelve_bit())
    assert (ten.column("adc").max, twelve.column("adc").max) == (1023, 4095)
    assert (ten.column("current_v").max, twelve.column("current_v").max) == (5.0, 3.3)
    frame = {"t_s": [0.0], "t_raw": [0.0], "line": [2], "segment": [0], "adc": [4095], "current_v": [3.299],
             "current_a": [4.5]}
    import pandas as pd
    twelve.check(pd.DataFrame(frame))
    with pytest.raises(SchemaError, match=r"column 'adc' above 1023 ADC steps at rows 0; rule: max 1023"):
        ten.check(pd.DataFrame(frame))


def test_a_12_bit_adc_rig_is_ingested_and_discovered_like_a_10_bit_one(tmp_path):
    raw, processed = tmp_path / "raw", tmp_path / "processed"
    hidden = (make_effect("viscous_friction", {"b": 7.7e-4}),)
    recs = {name: make_recording(RigSetup(config=cfg, effects=hidden, duration_s=10.0), seed=4)
            for name, cfg in (("ten", default_config()), ("twelve", _twelve_bit()))}
    for name, rec in recs.items():
        write_recording(rec, raw, name)
    report = run_pipeline(raw, processed, jobs=1, code="pinned")
    assert sorted((r["runs"], r["status"]) for r in report.ran) == [(["ten"], "ok"), (["twelve"], "ok")], report.ran

    sig = pq.read_table(processed / "twelve" / "signals.parquet").to_pandas()
    assert sig["adc"].max() > 1023                                  # 12-bit codes kept as logged
    truth = recs["twelve"].truth.set_index("line").loc[sig["line"]]
    assert np.abs(sig["current_a"].to_numpy() - truth["current_a"].to_numpy()).max() < 0.1
    with open(processed / "twelve" / "twelve.mcap", "rb") as fh:
        schemas = {s.name: json.loads(s.data) for s in make_reader(fh).get_summary().schemas.values()}
    assert schemas["pdr.current"]["properties"]["adc"]["maximum"] == 4095

    fits = {}
    for name in recs:
        res = CliRunner().invoke(app, ["discover", str(raw / f"{name}.csv"), "--json", "--no-rrd",
                                       "--out", str(tmp_path / "discovery" / name)])
        assert res.exit_code == 0, res.output
        fits[name] = json.loads(res.stdout)
    found = {name: {e["name"]: e["parameters"] for e in fit["effects"]} for name, fit in fits.items()}
    assert fits["twelve"]["verdict"] == fits["ten"]["verdict"] == "explained", found
    assert found["twelve"]["viscous_friction"]["b"] == pytest.approx(7.7e-4, rel=0.05), found
    assert set(found["twelve"]) == set(found["ten"]), found
    validation = {n: json.loads((processed / n / "validation.json").read_text()) for n in recs}
    assert validation["twelve"]["replay"]["signals"]["current"]["mse"] < 2 * validation["ten"]["replay"]["signals"]["current"]["mse"]
