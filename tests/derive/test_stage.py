"""The derive stage end to end: energies against the truth, files written, degenerate recordings, the command."""

import json
import math

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.config import default_config
from pipeline.derive.energy import ENERGY_KEYS
from pipeline.derive.stage import derive_run, derive_tables
from pipeline.errors import PdrError
from pipeline.model.simulate import simulate
from pipeline.rig.recording import RigSetup
from pipeline.runs import RunPaths
from pipeline.schemas import load_schema
from tests.derive.rigdata import rig_run

TABLES = ("kinematics", "phases", "overshoot", "cycles")


def true_energy(rec, cfg) -> dict[str, float]:
    """MODEL.md's power balance written out here, on the rig's true samples (not the code under test)."""
    tr = rec.truth[(rec.truth["status"] == "ok") & (rec.truth["segment"] == 1)]
    spec = cfg.plant_spec()
    p = spec.params
    t, i, w, th = (tr[c].to_numpy(float) for c in ("t_s", "current_a", "omega_rad_s", "theta_rad"))
    u = tr["dir"].to_numpy(float) * spec.v_drive
    ks = p.R ** 2 * (p.K1 + p.K2)
    on = int(np.flatnonzero(u != 0)[0])                      # the paper's window: the motor-on run
    return {"energy_paper_j": spec.v_rms * spec.period_s * np.sum(np.abs(i[on:-1] + i[on + 1:])) / 2,
            "input_energy_j": np.sum(u[:-1] * (i[:-1] + i[1:]) / 2 * np.diff(t)),
            "copper_loss_j": p.Ra * np.trapezoid(i ** 2, t),
            "friction_loss_j": p.b * np.trapezoid(w ** 2, t),
            "kinetic_energy_change_j": 0.5 * p.J * (w[-1] ** 2 - w[0] ** 2),
            "spring_energy_change_j": 0.5 * ks * (th[-1] ** 2 - th[0] ** 2),
            "magnetic_energy_change_j": 0.5 * p.La * (i[-1] ** 2 - i[0] ** 2)}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_energies_within_1_percent_of_the_truth_without_sensor_noise(seed):
    """ADC quantisation only: the stage's own error (timing, integration, smoothing) is what is left.
    Stored-energy changes within 2 % of their size plus what a count and a velocity error of
    0.03 rad/s at the last sample (where the velocity fit is one-sided) allow."""
    sig, cfg, rec = rig_run(RigSetup(noise_v=0.0), seed=seed)
    got = derive_tables(sig, cfg).summary["energy"]
    want = true_energy(rec, cfg)
    for key in ("energy_paper_j", "copper_loss_j", "friction_loss_j"):
        assert got[key] == pytest.approx(want[key], rel=0.01), key
    # signed input energy is a small difference of large terms (3.4 J out of 17 J moved): quantisation shows
    assert got["input_energy_j"] == pytest.approx(want["input_energy_j"], rel=0.03)
    p = cfg.plant_spec().params
    w_end = abs(rec.truth["omega_rad_s"].iloc[-1])
    assert got["kinetic_energy_change_j"] == pytest.approx(want["kinetic_energy_change_j"],
                                                           rel=0.02, abs=p.J * w_end * 0.03)
    assert got["spring_energy_change_j"] == pytest.approx(want["spring_energy_change_j"], rel=0.02, abs=1e-5)
    assert got["magnetic_energy_change_j"] == pytest.approx(want["magnetic_energy_change_j"], abs=0.02)
    assert abs(got["balance_residual_j"]) < 0.03 * got["input_energy_j"]      # the input error, nothing else


def test_paper_energy_with_sensor_noise():
    """One ADC step of white noise (27 mA) per sample puts ~1.1 % of random error on a 500-sample sum
    whatever the estimator (it survives any sum-preserving smoothing); over several runs the
    estimate is unbiased to within 1 %."""
    errors = []
    for seed in range(4):
        sig, cfg, rec = rig_run(seed=seed)
        got = derive_tables(sig, cfg).summary["energy"]
        want = true_energy(rec, cfg)
        errors.append(got["energy_paper_j"] / want["energy_paper_j"] - 1)
        # smoothing within phases removes the noise the raw samples add through |.|
        raw = got["energy_paper_logged_current_j"] / want["energy_paper_j"] - 1
        assert abs(errors[-1]) < 0.03 and errors[-1] <= raw + 0.002
    assert abs(np.mean(errors)) < 0.01


def test_papers_simulation_gives_16_496_j_through_this_stage():
    spec = default_config().plant_spec()                      # b = 7.7e-4, 500 samples at 50 ms
    r = simulate(spec)
    counts = np.round(r.theta * 6533.12 / (2 * math.pi))
    sig = pd.DataFrame({"t_s": r.t, "theta_rad": 2 * math.pi * counts / 6533.12, "current_a": r.current,
                        "dir": r.dir.astype(np.int8)})
    summary = derive_tables(sig, default_config()).summary
    assert summary["samples"] == 500
    assert summary["energy"]["energy_paper_j"] == pytest.approx(16.496, rel=0.03)
    assert summary["phases"]["switches"] == 13
    assert abs(summary["energy"]["balance_residual_j"]) < 0.01 * summary["energy"]["input_energy_j"]


def write_run(tmp_path, sig, cfg, name="run1") -> RunPaths:
    root = tmp_path / name
    root.mkdir(parents=True)
    load_schema("signals").check(sig)
    pq.write_table(load_schema("signals").to_arrow(sig), root / "signals.parquet")
    (root / "rig.json").write_text(json.dumps({"config": cfg.to_dict(), "sources": {}}))
    return RunPaths(root)


def test_derive_run_writes_schema_tables_and_summary_deterministically(tmp_path):
    sig, cfg, _ = rig_run(seed=4)
    paths = write_run(tmp_path, sig, cfg)
    summary = derive_run(paths)
    first = {n: getattr(paths, n).read_bytes() for n in (*TABLES, "summary")}
    for name in TABLES:
        table = pq.read_table(getattr(paths, name))
        schema = load_schema(name)
        assert set(table.column_names) <= {c.name for c in schema.columns}
        assert table.schema.field(table.column_names[0]).metadata[b"unit"]
        schema.check(table.to_pandas())
    kin = pd.read_parquet(paths.kinematics)
    assert len(kin) == len(sig) and not kin["dir_inferred"].any()
    assert summary["run"] == "run1" and summary["velocity"]["default"] == "savgol"
    assert summary["phases"]["mode_sequence"][:3] == [0, 1, 2]
    assert set(ENERGY_KEYS) <= set(summary["energy"])
    assert summary["cycles"]["n_cycles"] >= 5 and 3.0 < summary["cycles"]["period_s"]["mean"] < 4.5
    assert summary["not_computed"] == {}
    assert summary["counts"]["reversals"] == summary["phases"]["switches"] == summary["phases"]["count"] - 2
    assert json.loads(paths.summary.read_text()) == summary
    derive_run(paths)
    assert {n: getattr(paths, n).read_bytes() for n in (*TABLES, "summary")} == first


def test_no_current_and_no_dir_logged(tmp_path):
    sig, cfg, rec = rig_run(seed=5, log_dir=False, log_current=False)
    d = derive_tables(sig, cfg)
    assert d.summary["energy"] is None
    assert d.summary["not_computed"]["energy"] == "no current column: energy not computed"
    assert d.kinematics["dir_inferred"].all() and "current_a" not in d.kinematics
    assert d.summary["dir_source"] == "inferred from the guards"
    assert d.phases["peak_current_a"].isna().all() and d.overshoot["trigger_current_a"].isna().all()
    paths = write_run(tmp_path, sig, cfg)
    derive_run(paths)
    assert pd.read_parquet(paths.overshoot)["trigger_current_a"].isna().all()


def degenerate(kind: str) -> pd.DataFrame:
    n = {"two": 2, "one": 1}.get(kind, 200)
    t = np.arange(n) * 0.05
    theta = {"never": 0.6 * (1 - np.exp(-t)), "stalled": np.zeros(n), "single": 0.02 * t}.get(kind, 0.01 * t)
    counts = np.round(theta * 6533.12 / (2 * math.pi))
    return pd.DataFrame({"t_s": t, "t_raw": t * 1000, "line": np.arange(n) + 1, "segment": np.zeros(n, np.int32),
                         "counts": counts.astype(np.int64), "theta_rad": 2 * math.pi * counts / 6533.12,
                         "current_a": np.full(n, 0.3 if kind == "stalled" else 0.1)})


@pytest.mark.parametrize("kind", ["never", "stalled", "single", "two", "one"])
def test_degenerate_recordings_give_clear_answers(kind, tmp_path):
    cfg = default_config()
    d = derive_tables(degenerate(kind), cfg)
    s = d.summary
    assert len(d.kinematics) == s["samples"] and len(d.phases) == 1 and len(d.overshoot) == 0
    assert "never reached a guard" in s["not_computed"]["overshoot"]
    assert "cycles" in s["not_computed"] and s["cycles"]["n_cycles"] == 0
    assert s["overshoot"]["directions"]["upper"]["overshoot_rad"] == {"n": 0, "mean": None, "std": None,
                                                                      "min": None, "max": None}
    if kind == "stalled":
        assert any(n.startswith("stalled") for n in s["notes"])
    if kind == "one":
        assert s["energy"] is None and s["not_computed"]["energy"] == "fewer than 2 samples: no interval to integrate over"
    else:               # the same logged current at every sample: a stuck sensor, no energy (null, never 0)
        assert s["energy"] is None and s["energy_uncertainty_j"] is None
        assert "at every sample (a stuck or disconnected sensor)" in s["not_computed"]["energy"]
        assert s["current"]["constant"] and s["current"]["rms_a"] is None
        if kind != "two":
            assert any(n.startswith("current sensor stuck") for n in s["notes"])
    if kind in ("two", "one"):
        assert any("sample(s)" in n for n in s["notes"])
    paths = write_run(tmp_path, degenerate(kind), cfg)
    derive_run(paths)                                    # empty tables are written and read back
    assert len(pd.read_parquet(paths.overshoot)) == 0 and len(pd.read_parquet(paths.cycles)) == 0


def test_oscillation_without_reaching_the_guard_points_at_the_encoder_scale():
    sig, cfg, _ = rig_run(seed=1, log_dir=False)
    half = sig.assign(theta_rad=sig["theta_rad"] / 2)     # the scale of a sketch decoding x2 read as x4
    s = derive_tables(half, cfg).summary
    assert "overshoot" in s["not_computed"]
    assert any("counts_per_rev" in n for n in s["notes"])


def test_refusals_name_the_problem(tmp_path):
    with pytest.raises(PdrError, match="no samples"):
        derive_tables(pd.DataFrame({"t_s": [], "theta_rad": []}), default_config())
    bad = pd.DataFrame({"t_s": [0.0, 0.05, 0.05], "theta_rad": [0.0] * 3, "line": [2, 3, 4]})
    with pytest.raises(PdrError, match=r"line 4.*t_s.*increase"):
        derive_tables(bad, default_config())
    stuck = pd.DataFrame({"t_s": np.zeros(50), "theta_rad": 0.01 * np.arange(50)})
    s = derive_tables(stuck, default_config()).summary
    assert s["duration_s"] == pytest.approx(49 * 0.05) and any("timer stuck" in n for n in s["notes"])
    assert s["omega_rad_s"]["mean"] == pytest.approx(0.2)
    with pytest.raises(PdrError, match="pdr ingest"):
        derive_run(RunPaths(tmp_path / "missing"))


def test_command_accepts_a_raw_csv_a_run_name_and_a_folder(tmp_path):
    sig, cfg, _ = rig_run(seed=0)
    processed = tmp_path / "processed"
    write_run(processed, sig, cfg, name="rec-seg1")
    write_run(processed, sig.iloc[:40], cfg, name="rec-seg2")
    runner = CliRunner()
    res = runner.invoke(app, ["derive", str(tmp_path / "raw" / "rec.csv"), "--processed", str(processed)])
    assert res.exit_code == 0, res.output
    assert res.output.count("\n") == 2 and "rec-seg1:" in res.output and "rec-seg2:" in res.output
    res = runner.invoke(app, ["derive", "rec-seg1", "--processed", str(processed), "--json"])
    assert json.loads(res.output)["rec-seg1"]["samples"] == len(sig)
    res = runner.invoke(app, ["derive", str(processed / "rec-seg2"), "--processed", str(processed)])
    assert res.exit_code == 0 and (processed / "rec-seg2" / "summary.json").is_file()
    res = runner.invoke(app, ["derive", "nope", "rec-seg1", "--processed", str(processed)])
    # the bad name is one line, the good run after it still derived, the exit status non-zero
    assert res.exit_code == 2 and "pdr: error: nope: expected a processed run folder" in res.output
    assert "rec-seg1:" in res.output
