"""The randomised rig: draws cover the declared ranges, repeat for a seed, and ingest reads every one right."""

from __future__ import annotations

import math
import tomllib
from collections import Counter
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from pipeline.ingest.stage import ingest_recording
from pipeline.model.effects import CATALOGUE
from pipeline.rig.randomised import ACS712_PARTS, GEARBOX, ONE_ADC_STEP_V, randomised_setup
from pipeline.rig.recording import RigSetup, make_recording

N_DRAWS = 300


@pytest.fixture(scope="module")
def draws():
    rng = np.random.default_rng(2026)
    return [randomised_setup(rng) for _ in range(N_DRAWS)]


def test_same_seed_same_draws():
    a = [randomised_setup(np.random.default_rng(7)) for _ in range(3)]
    b = [randomised_setup(np.random.default_rng(7)) for _ in range(3)]
    assert a == b


def test_pdr_rig_randomise_writes_the_draw_of_its_seed(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from pipeline.cli import app
    from pipeline.rig import randomised

    short = randomised.randomised_setup
    monkeypatch.setattr(randomised, "randomised_setup",
                        lambda rng: (d := short(rng)) and replace(d, setup=_short(d.setup)))
    res = CliRunner().invoke(app, ["rig", "randomise", "lab", "--seed", "42", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    draw = randomised.randomised_setup(np.random.default_rng(42))
    assert (tmp_path / "lab.csv").read_bytes() == make_recording(draw.setup).csv_bytes
    assert f"period_s={draw.conventions['period_s']}" in res.output
    bad = CliRunner().invoke(app, ["rig", "randomise", "no/name", "--out", str(tmp_path)])
    assert bad.exit_code != 0 and "Traceback" not in bad.output


def test_draws_stay_in_the_declared_ranges(draws):
    for d in draws:
        s, cfg = d.setup, d.setup.config
        assert 10 <= round(cfg.controller.period_s * 1000) <= 100
        assert 5.0 <= cfg.drive.v_in <= 12.0
        assert cfg.current_sensor.sensitivity_v_per_a in ACS712_PARTS.values()
        lines_x_decoding = cfg.encoder.counts_per_rev / GEARBOX
        assert abs(lines_x_decoding - round(lines_x_decoding)) < 1e-6
        assert 1.0 <= s.noise_v / ONE_ADC_STEP_V <= 4.0
        assert 10.0 <= s.duration_s <= 300.0 and 0.0 <= s.open_after_s <= 10.0
        assert s.artefacts.dropped <= 0.05 * s.duration_s / cfg.controller.period_s
        assert len(d.effects) <= 3 and len({e.name for e in d.effects}) == len(d.effects)
        assert not (d.outside and d.effects)
        assert (s.plant_model is not None) == (d.outside == "armature_resistance")


def test_draws_cover_every_convention_and_every_catalogued_effect(draws):
    seen = Counter()
    for d in draws:
        c = d.conventions
        seen.update([f"unit:{c['time_unit']}", f"dir:{c['dir']}", f"header:{c['header']}", f"part:{c['acs712']}",
                     f"round:{c['counts_rounding']}", f"first:{c['first_dir']}", f"zero:{c['zero_v']}",
                     f"reset:{c['reset_after_s'] is not None}", f"k:{len(d.effects)}", f"outside:{d.outside}"])
        seen.update(f"effect:{e.name}" for e in d.effects)
        seen.update([f"terminal:{c['terminal']}"])
    wanted = ([f"unit:{u}" for u in ("ms", "us", "s")] + ["dir:True", "dir:False", "header:True", "header:False"]
              + [f"part:{p}" for p in ACS712_PARTS] + ["round:round", "round:floor", "first:1", "first:-1",
                                                       "zero:auto", "zero:calibrated", "reset:True", "reset:False"]
              + [f"k:{k}" for k in range(4)] + ["outside:armature_resistance"]
              + [f"effect:{name}" for name in CATALOGUE] + ["terminal:none", "terminal:classic", "terminal:putty"])
    assert [w for w in wanted if not seen[w]] == []
    assert len([k for k in seen if k.startswith("terminal:")]) >= 10
    opened_mid_motion = [d for d in draws if d.setup.open_after_s > d.setup.pre_roll_s + 1.0]
    assert len(opened_mid_motion) > N_DRAWS / 2


def test_an_effect_the_table_does_not_list_is_drawn_around_its_typical_value():
    """A new catalogue entry needs no change here: its plug-in's Param (typical, absent, signed) sets the range."""
    from types import SimpleNamespace

    from pipeline.rig.randomised import _unlisted

    param = SimpleNamespace(name="Tz", absent=0.0, typical=2e-3, signed=True)
    plugin = SimpleNamespace(PARAMS=(param,), BOUNDS={"Tz": (-1e-2, 1e-2)})
    rng = np.random.default_rng(1)
    values = np.array([_unlisted(plugin, "Tz", rng) for _ in range(200)])
    assert np.all((np.abs(values) >= 1e-3 - 1e-12) & (np.abs(values) <= 3e-3 + 1e-12))
    assert (values > 0).any() and (values < 0).any()
    one_sided = SimpleNamespace(PARAMS=(SimpleNamespace(name="g", absent=1.0, typical=1.5, signed=False),),
                                BOUNDS={"g": (1.0, 5.0)})
    assert all(1.25 <= _unlisted(one_sided, "g", rng) <= 1.75 for _ in range(50))


def _short(setup: RigSetup) -> RigSetup:
    """The draw's conventions on a run of at most 12 s (a reset stays inside it)."""
    art = setup.artefacts
    duration = min(setup.duration_s, 12.0)
    reset = None if art.reset_after_s is None else setup.open_after_s + 0.5 * duration
    rows = duration / setup.config.controller.period_s
    return replace(setup, duration_s=duration,
                   artefacts=replace(art, reset_after_s=reset, dropped=min(art.dropped, int(0.05 * rows))))


@pytest.mark.parametrize("index", [0, 1, 2, 3, 4, 5, 6, 7])
def test_ingest_reads_a_randomised_recording_exactly(tmp_path, draws, index):
    setup = _short(draws[index * 7].setup)
    rec = make_recording(setup)
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "r.csv").write_bytes(rec.csv_bytes)
    (raw / "r.toml").write_text(rec.toml_text)
    result = ingest_recording(raw / "r.csv", tmp_path / "processed")
    ok = rec.truth[rec.truth["status"] == "ok"]
    got = pd.concat(result.tables.values(), ignore_index=True)
    assert got["line"].tolist() == ok["line"].tolist()
    assert got["counts"].tolist() == ok["counts"].tolist()
    assert got["adc"].tolist() == ok["adc"].tolist()
    if setup.artefacts.dir_column:
        assert got["dir"].tolist() == ok["dir"].tolist()
    cpr = setup.config.encoder.counts_per_rev
    np.testing.assert_allclose(got["theta_rad"], ok["counts"] * 2 * np.pi / cpr)
    terminal = setup.artefacts.terminal or setup.artefacts.ide_prefix
    assert (result.report["timestamp_prefix"] is None) == (terminal == "")


def test_capture_opened_mid_motion_starts_where_the_rig_was():
    setup = RigSetup(duration_s=5.0, pre_roll_s=0.5, open_after_s=3.0, first_dir=-1)
    full = make_recording(replace(setup, open_after_s=0.0, duration_s=8.0))
    late = make_recording(setup)
    skipped = late.truth_meta["segments"][0]["uncaptured_samples"]
    assert skipped == 60 and late.truth["t_s"].iloc[0] == 0.0
    assert len(late.truth) == len(full.truth) - skipped      # the same board run, its start not captured
    assert late.truth["counts"].tolist() == full.truth["counts"].iloc[skipped:].tolist()
    assert late.truth["dir"].iloc[0] != 0 and full.truth["dir"].iloc[10] == -1   # moving, first command -1
    assert late.csv_bytes.split(b"\n")[1].split(b",")[0] == str(full.truth["t_ms"].iloc[skipped]).encode()


def test_a_clean_draw_is_its_own_toml_exactly(draws):
    """Whatever the conventions, a recording without hidden effects is what its TOML's model says: the fast
    simulator, replaying the logged commands from the true first state, lands on the rig's true angle."""
    from pipeline.model.simulate import simulate

    clean = [d for d in draws if d.label == "clean"][:3]
    assert len(clean) == 3
    for d in clean:
        setup = _short(d.setup)
        truth = make_recording(setup).truth
        seg = truth[truth["segment"] == 1]
        spec = setup.config.plant_spec()
        x0 = (seg["current_a"].iloc[0], seg["omega_rad_s"].iloc[0], seg["theta_rad"].iloc[0] * spec.params.R)
        dirs = seg["dir"].to_numpy()
        sim = simulate(spec, seg["t_s"].to_numpy(), x0=x0, dir0=int(dirs[0]), dir_log=dirs, closed_loop=False)
        assert np.max(np.abs(sim.theta - seg["theta_rad"].to_numpy())) < 1e-7


def test_floor_counts_are_the_edges_passed():
    rec = make_recording(RigSetup(duration_s=3.0, counts_rounding="floor"))
    cpr = rec.truth_meta["sensor"]["counts_per_rev"]
    expected = [math.floor(th * cpr / (2 * math.pi)) for th in rec.truth["theta_rad"]]
    assert rec.truth["counts"].tolist() == expected


def test_outside_effect_changes_only_the_plant():
    rng = np.random.default_rng(0)
    draw = next(d for d in (randomised_setup(rng) for _ in range(200)) if d.outside)
    setup = _short(draw.setup)
    rec = make_recording(setup)
    assert tomllib.loads(rec.toml_text)["model"]["Ra"] == setup.config.model.Ra      # the user's datasheet value
    assert rec.truth_meta["plant"]["params"]["Ra"] == setup.plant_model.Ra > 1.3 * setup.config.model.Ra


def test_a_hidden_sensor_offset_comes_with_a_written_zero(draws):
    """The offset is the written zero being off; an "auto" zero is measured from the data and would hide it."""
    with_offset = [d for d in draws if any(e.name == "current_sensor_offset" for e in d.effects)]
    assert with_offset and all(d.setup.zero_v == "calibrated" for d in with_offset)
    assert any(d.setup.zero_v == "auto" for d in draws)
