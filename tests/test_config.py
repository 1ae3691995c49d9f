"""Rig TOML layering and checks: defaults < raw/rig.toml < raw/<name>.toml, errors name file and key."""

from pathlib import Path

import pytest

from pipeline.config import (
    config_for_recording, config_from_dict, default_config, effects_toml_snippet, resolve_config,
)
from pipeline.errors import ConfigError
from pipeline.model.effects import make_effect


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_defaults_are_the_papers_rig():
    cfg = default_config()
    assert cfg.model.Ra == 2.59
    assert cfg.encoder.counts_per_rev == pytest.approx(64 * 102.08)  # 64 counts (x4 quadrature) per motor rev
    assert cfg.controller.guard_rad == pytest.approx(0.9424777960769379)
    assert cfg.drive.v_in == 6.0
    assert cfg.effects == ()
    assert all(src == "default" for src in cfg.sources.values())


def test_sidecar_overrides_rig_toml_and_records_sources(tmp_path):
    csv = write(tmp_path / "run1.csv", "t_ms,counts,adc,dir\n")
    rig = write(tmp_path / "rig.toml", "[drive]\nv_in = 12.0\n[model]\nb = 0.0\n")
    side = write(tmp_path / "run1.toml", "[drive]\nv_in = 5.0\n[current_sensor]\nzero_v = \"auto\"\n")
    cfg = config_for_recording(csv)
    assert cfg.drive.v_in == 5.0
    assert cfg.model.b == 0.0
    assert cfg.current_sensor.zero_v == "auto"
    assert cfg.sources["drive.v_in"] == str(side)
    assert cfg.sources["model.b"] == str(rig)
    assert cfg.sources["model.Ra"] == "default"


def test_effects_fold_into_the_plant_spec(tmp_path):
    toml = write(tmp_path / "r.toml", "[model]\nb = 0\n[effects]\ncoulomb_friction = { Tc = 6e-4 }\n"
                                      "loop_delay = { Td = 0.05 }\nviscous_friction = { b = 7.7e-4 }\n"
                                      "driver_voltage_drop = { Vd = 1.5 }\nspring_stiffness = { k_scale = 2.0 }\n")
    cfg = resolve_config([toml])
    assert make_effect("coulomb_friction", {"Tc": 6e-4}) in cfg.effects and make_effect("loop_delay", {"Td": 0.05}) in cfg.effects
    spec = cfg.plant_spec()
    assert spec.Tc == 6e-4 and spec.Td == 0.05
    assert spec.params.b == pytest.approx(7.7e-4)
    assert spec.v_drive == pytest.approx(4.5)
    assert spec.params.K1 == pytest.approx(2 * 0.8682)
    assert not spec.is_linear


@pytest.mark.parametrize("text, key, expected", [
    ("[model]\nRa = -2.59\n", "model.Ra", "positive"),
    ("[model]\nRaa = 2.59\n", "model.Raa", "unknown key"),
    ("[drive]\nv_in = \"six\"\n", "drive.v_in", "number"),
    ("[encoder]\ncounts_per_rev = 0\n", "encoder.counts_per_rev", "positive"),
    ("[current_sensor]\nzero_v = \"manual\"\n", "current_sensor.zero_v", "auto"),
    ("[current_sensor]\nadc_steps = 1023.5\n", "current_sensor.adc_steps", "integer"),
    ("[columns]\ntime_unit = \"min\"\n", "columns.time_unit", "\"ms\""),
    ("[gearbox]\nratio = 3\n", "gearbox", "unknown section"),
    ("[effects]\nmagic = { x = 1 }\n", "effects.magic", "unknown effect"),
    ("[effects]\nloop_delay = { Td = -0.1 }\n", "effects.loop_delay.Td", "expected a value"),
    ("[effects]\nloop_delay = { delay = 0.1 }\n", "effects.loop_delay", "unknown parameter"),
    ("[ingest]\nmax_bad_fraction = 2\n", "ingest.max_bad_fraction", "[0.0, 1.0]"),
])
def test_bad_keys_are_refused_naming_file_and_key(tmp_path, text, key, expected):
    path = write(tmp_path / "bad.toml", text)
    with pytest.raises(ConfigError) as err:
        resolve_config([path])
    message = str(err.value)
    assert str(path) in message and f"'{key}'" in message and expected in message


def test_invalid_toml_and_non_utf8_name_the_file(tmp_path):
    broken = write(tmp_path / "broken.toml", "[model\nRa = 1\n")
    with pytest.raises(ConfigError, match="broken.toml.*valid TOML"):
        resolve_config([broken])
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00junk")
    with pytest.raises(ConfigError, match="bin.toml.*UTF-8"):
        resolve_config([binary])


def test_to_dict_round_trips_and_snippet_is_accepted(tmp_path):
    toml = write(tmp_path / "r.toml", "[effects]\nbacklash = { gap = 0.05 }\n[current_sensor]\nzero_v = \"auto\"\n")
    cfg = resolve_config([toml])
    assert config_from_dict(cfg.to_dict()) == cfg
    snippet = write(tmp_path / "snippet.toml", effects_toml_snippet(cfg.effects))
    assert resolve_config([snippet]).effects == cfg.effects
