"""validate_run on a processed run folder: every output written, readable, deterministic."""

import json

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from PIL import Image

from pipeline.config import default_config
from pipeline.errors import PdrError
from pipeline.model.effects import make_effect
from pipeline.runs import run_paths
from pipeline.validate.stage import validate_run
from tests.validate.synthetic import synthetic_kinematics, synthetic_run


def test_validate_run_writes_every_output(tmp_path):
    paths = synthetic_run(tmp_path)
    row = validate_run(paths)
    for f in (paths.validation, paths.comparison, paths.comparison_mcap, paths.rrd, paths.overview_png):
        assert f.is_file() and f.stat().st_size > 0
    v = json.loads(paths.validation.read_text())
    assert v["run"] == "synth" and v["n_samples"] == 500
    assert set(v["replay"]["signals"]) == {"theta", "omega", "current"}
    assert v["model"]["params"]["Ra"] == 2.59
    assert row["replay_theta_mse"] == v["replay"]["signals"]["theta"]["mse"]
    assert set(row["timing_s"]) == {"load", "simulate", "metrics", "write_tables", "rrd", "png"}
    table = pq.read_table(paths.comparison)
    assert table.num_rows == 500
    assert table.schema.field("current_replay_a").metadata[b"unit"] == b"A"
    with Image.open(paths.overview_png) as im:
        assert im.size == (1200, 800)
    assert not list(paths.root.glob(".*tmp*"))        # no temporary files left behind


def test_rerun_gives_identical_json_parquet_and_png(tmp_path):
    paths = synthetic_run(tmp_path)
    validate_run(paths)
    first = {f: f.read_bytes() for f in (paths.validation, paths.comparison, paths.comparison_mcap,
                                         paths.overview_png)}
    validate_run(paths)
    for f, data in first.items():
        assert f.read_bytes() == data, f.name


def test_model_file_overrides_the_rig_model(tmp_path):
    cfg = default_config()
    truth = cfg.plant_spec((make_effect("viscous_friction", {"b": 1.5e-3}),))
    paths = synthetic_run(tmp_path, kin=synthetic_kinematics(truth))
    base = validate_run(paths, rrd=False, png=False)
    model = tmp_path / "model.toml"
    model.write_text("[effects]\nviscous_friction = { b = 1.5e-3 }\n")
    fixed = validate_run(paths, model, rrd=False, png=False)
    assert fixed["replay_theta_mse"] < base["replay_theta_mse"] / 100
    v = json.loads(paths.validation.read_text())
    assert v["model"]["source"] == str(model)
    assert v["model"]["params"]["b"] == pytest.approx(7.7e-4 + 1.5e-3)


def test_without_current_the_current_metrics_are_absent(tmp_path):
    kin = synthetic_kinematics(current=False)
    paths = synthetic_run(tmp_path, kin=kin)
    row = validate_run(paths, rrd=False)
    v = json.loads(paths.validation.read_text())
    assert "current" not in v["replay"]["signals"] and v["replay"]["energy_error"] is None
    assert row["replay_current_mse"] is None
    assert "current_a" not in pq.read_schema(paths.comparison).names


def test_refusals_name_the_file(tmp_path):
    paths = run_paths(tmp_path, "empty")
    paths.root.mkdir()
    with pytest.raises(PdrError, match="kinematics.parquet"):
        validate_run(paths)
    paths = synthetic_run(tmp_path, "nodir", kin=synthetic_kinematics().drop(columns=["dir"]))
    with pytest.raises(PdrError, match="lacks column 'dir'"):
        validate_run(paths)
    paths = synthetic_run(tmp_path, "ok")
    with pytest.raises(PdrError, match="model file not found"):
        validate_run(paths, tmp_path / "missing.toml")


def test_undefined_figures_are_null_in_json(tmp_path):
    kin = synthetic_kinematics(duration=0.5)
    paths = synthetic_run(tmp_path, kin=kin)
    validate_run(paths, rrd=False, png=False)
    v = json.loads(paths.validation.read_text())
    assert v["measured"]["oscillation"]["period_s"] is None
    assert np.isnan(pd.read_parquet(paths.comparison)["omega_rad_s"]).sum() == 0


def test_overview_png_decodes_to_the_rendered_pixels():
    import io

    from pipeline.validate.plots import png_rgb

    rgb = np.random.default_rng(3).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    rgb[2] = 255
    with Image.open(io.BytesIO(png_rgb(rgb))) as im:
        assert im.size == (7, 5) and im.mode == "RGB"
        np.testing.assert_array_equal(np.asarray(im), rgb)


def test_overview_title_is_drawn_in_the_top_band_only():
    """The per-run title (drawn by Pillow over the cached background) changes the top band and nothing else."""
    import io

    from pipeline.model.simulate import simulate
    from pipeline.validate.plots import overview_png

    spec = default_config().plant_spec()
    sim = simulate(spec, duration=5.0)
    kin = pd.DataFrame({"t_s": sim.t, "theta_rad": sim.theta, "omega_rad_s": sim.omega,
                        "current_a": sim.current_measured})

    def pixels(title: str) -> np.ndarray:
        png = overview_png(title, kin, {"closed_loop": sim, "replay": sim}, spec.guard_rad)
        with Image.open(io.BytesIO(png)) as im:
            return np.asarray(im.convert("RGB"), dtype=int)

    blank, short, long = pixels(""), pixels("run-a"), pixels("run-b   MSE replay: theta 1.2e-06 rad^2")
    band = slice(0, 40)
    np.testing.assert_array_equal(blank[40:], long[40:])           # lines and axes untouched
    dark_short = (short[band].min(axis=2) < 100).sum()
    dark_long = (long[band].min(axis=2) < 100).sum()
    assert (blank[band].min(axis=2) < 100).sum() == 0              # the margin is white without a title
    assert 0 < dark_short < dark_long                              # ink grows with the text
    cols = np.flatnonzero((long[band].min(axis=2) < 100).any(axis=0))
    assert abs((cols[0] + cols[-1]) / 2 - blank.shape[1] / 2) < 10  # centred
    np.testing.assert_array_equal(pixels("run-a"), short)          # deterministic


def test_comparison_mcap_has_the_model_comparison_for_foxglove(tmp_path):
    """Read back by the mcap library: 7 JSON-schema channels, one message per sample, residual = measured - model."""
    from mcap.reader import make_reader

    kin = synthetic_kinematics(current_noise_a=0.02, duration=5.0)
    paths = synthetic_run(tmp_path, kin=kin)
    validate_run(paths, rrd=False, png=False)
    with open(paths.comparison_mcap, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert set(topics) == {"/measured/kinematics", "/measured/current", "/measured/command", "/model/closed_loop",
                               "/model/replay", "/residuals/closed_loop", "/residuals/replay"}
        for schema in topics.values():
            assert schema.encoding == "jsonschema" and json.loads(schema.data)["type"] == "object"
        assert set(json.loads(topics["/residuals/replay"].data)["properties"]) == {
            "theta_residual_replay_rad", "omega_residual_replay_rad_s", "current_residual_replay_a"}
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert "wall-clock start is not known" in meta["time"]["log_time"]
        messages: dict[str, list] = {}
        for _schema, channel, message in reader.iter_messages():
            messages.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
    assert all(len(m) == len(kin) for m in messages.values())
    times = [lt for lt, _ in messages["/measured/kinematics"]]
    assert times[0] == 0 and times[-1] == round((kin["t_s"].iloc[-1] - kin["t_s"].iloc[0]) * 1e9)
    table = pd.read_parquet(paths.comparison)
    for k in (0, 37, len(kin) - 1):
        meas = messages["/measured/kinematics"][k][1]
        model = messages["/model/replay"][k][1]
        res = messages["/residuals/replay"][k][1]
        assert meas["theta_rad"] == kin["theta_rad"].iloc[k]
        assert res["theta_residual_replay_rad"] == pytest.approx(meas["theta_rad"] - model["theta_replay_rad"], abs=1e-15)
        cur = messages["/measured/current"][k][1]["current_a"]
        assert res["current_residual_replay_a"] == pytest.approx(cur - model["current_replay_a"], abs=1e-15)
        assert model["dir_replay"] == kin["dir"].iloc[k]
        assert table["omega_residual_closed_loop_rad_s"].iloc[k] == pytest.approx(
            kin["omega_rad_s"].iloc[k] - messages["/model/closed_loop"][k][1]["omega_closed_loop_rad_s"], abs=1e-15)


def test_oscillation_and_energy_errors_against_an_independent_computation(tmp_path):
    """A run whose driver lost 1.5 V, validated with the rig's model: period, amplitude and the paper's
    energy recomputed here from comparison.parquet; errors are simulated minus measured, in % of measured."""
    truth = default_config().plant_spec((make_effect("driver_voltage_drop", {"Vd": 1.5}),))
    paths = synthetic_run(tmp_path, kin=synthetic_kinematics(truth, current_noise_a=0.02))
    validate_run(paths, rrd=False, png=False)
    v = json.loads(paths.validation.read_text())
    table = pd.read_parquet(paths.comparison)
    t = table["t_s"].to_numpy()
    guard = default_config().plant_spec().guard_rad

    def oscillation(theta, d):
        k = np.flatnonzero((d[1:] != d[:-1]) & (d[1:] != 0) & (d[:-1] != 0)) + 1
        peaks = [theta[a:b + 1].max() if d[a] < 0 else -theta[a:b + 1].min() for a, b in zip(k[:-1], k[1:])]
        return 2 * np.mean(np.diff(t[k])), np.mean(peaks)

    def paper(i):
        return 6.0 * 0.05 * np.sum(np.abs(i[:-1] + i[1:])) / 2

    period_m, amp_m = oscillation(table["theta_rad"].to_numpy(), table["dir"].to_numpy())
    e_m = paper(table["current_a"].to_numpy())
    for way in ("closed_loop", "replay"):
        period_s, amp_s = oscillation(table[f"theta_{way}_rad"].to_numpy(), table[f"dir_{way}"].to_numpy())
        err = v[way]["oscillation_error"]
        assert err["period_s"] == pytest.approx(period_s - period_m, abs=1e-12)
        assert err["amplitude_rad"] == pytest.approx(amp_s - amp_m, abs=1e-12)
        assert err["overshoot_rad"] == pytest.approx((amp_s - guard) - (amp_m - guard), abs=1e-12)
        e_s = paper(table[f"current_{way}_a"].to_numpy())
        assert v[way]["energy_error"]["paper_j"] == pytest.approx(e_s - e_m, rel=1e-9)
        assert v[way]["energy_error"]["paper_pct"] == pytest.approx(100 * (e_s - e_m) / e_m, rel=1e-9)
    # the full-voltage model reaches the guards sooner (5.4 s measured, 3.7 s simulated) and, on the logged
    # switching, draws more current than the weaker drive did
    assert v["closed_loop"]["oscillation_error"]["period_s"] < -1.0
    assert v["replay"]["energy_error"]["paper_pct"] > 5.0


def test_overview_does_not_depend_on_the_runs_drawn_before():
    """A worker's figure is reused: a run drawn over a cached background gets that background's axis
    limits, not the limits of the run drawn just before (which once scaled its lines wrongly)."""
    from pipeline.model.simulate import simulate
    from pipeline.validate.plots import overview_png

    spec = default_config().plant_spec()
    sims = {"small": simulate(spec, duration=5.0), "large": simulate(spec, duration=12.0)}

    def png(which: str, current_scale: float) -> bytes:
        s = sims[which]
        kin = pd.DataFrame({"t_s": s.t, "theta_rad": s.theta, "omega_rad_s": s.omega,
                            "current_a": s.current_measured * current_scale})
        return overview_png("r", kin, {"closed_loop": s, "replay": s}, spec.guard_rad)

    first = png("small", 1.0)
    png("large", 3.0)               # other limits: another background, the axes changed
    assert png("small", 1.0) == first
