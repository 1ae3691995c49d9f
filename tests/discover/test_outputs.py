"""What ``pdr discover`` hands back: the JSON contract, the TOML snippet validation accepts,
adoption only on request, the report, plots and Rerun recording read back by their libraries."""

import json
import os
import subprocess
import sys
import tomllib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.config import config_for_recording, resolve_config
from pipeline.discover.adopt import adopt, without_table
from pipeline.discover.candidates import parameter_of
from pipeline.discover.stage import merge_effects
from pipeline.model.effects import CATALOGUE, make_effect
from pipeline.validate.stage import resolve_model
from tests.discover.synthetic import rig_kinematics

runner = CliRunner()
KEYS = {"recording", "effects", "verdict", "mse_before", "mse_after", "candidates"}


def _effect(name, value):
    return make_effect(name, {parameter_of(name): value})


@pytest.fixture(scope="module")
def delay_run(tmp_path_factory):
    """A recording with a hidden loop delay, discovered once by the ``pdr`` command (JSON on stdout),
    read as a pipe reads it: the object is complete before the figures and the .rrd are drawn, so at
    that moment the files it names are already written, and nothing else follows it on stdout."""
    work = tmp_path_factory.mktemp("delay")
    _, _, csv = rig_kinematics((_effect("loop_delay", 0.05),), seed=8, work=work)
    out = work / "out"
    proc = subprocess.Popen([str(Path(sys.executable).with_name("pdr")), "discover", str(csv), "--json",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    text, doc = "", None
    while doc is None:
        line = proc.stdout.readline()
        assert line, proc.stderr.read()
        text += line
        if line.rstrip("\n") == "}":                        # the object's last line
            doc = json.loads(text)
            answered_with = {p.name for p in out.iterdir()}
    rest, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert rest == ""
    assert {"discovery.json", "effects.toml", "report.md"} <= answered_with
    return csv, out, doc


def test_json_contract(delay_run):
    csv, _, doc = delay_run
    assert KEYS <= set(doc)
    assert doc["recording"] == str(csv)
    assert doc["verdict"] == "explained"
    assert [e["name"] for e in doc["effects"]] == ["loop_delay"]
    assert doc["effects"][0]["units"] == {"Td": "s"} and set(doc["effects"][0]["parameters"]) == {"Td"}
    assert set(doc["mse_before"]) == {"theta", "omega", "current"}
    assert all(doc["mse_after"][s] < doc["mse_before"][s] for s in ("theta", "omega"))
    names = [c["name"] for c in doc["candidates"] if c["round"] == 1]
    assert sorted(names) == sorted(CATALOGUE)
    assert all(isinstance(c["score"], float) for c in doc["candidates"])
    accepted = [c for c in doc["candidates"] if c["accepted"]]
    assert accepted[0]["name"] == "loop_delay" and all(accepted[0]["checks"].values())


def test_every_candidate_key_is_documented_in_format_md(delay_run):
    """docs/FORMAT.md's table of a candidate's keys names every key the command writes."""
    _, _, doc = delay_run
    text = (Path(__file__).parents[2] / "docs" / "FORMAT.md").read_text(encoding="utf-8")
    written = {k for c in doc["candidates"] for k in c} | {k for c in doc["candidates"] for k in c.get("checks", {})}
    assert {k for k in written if f"`{k}`" not in text} == set()


def test_files_written_and_snippet_is_accepted_by_validation(delay_run):
    csv, out, doc = delay_run
    for name in ("discovery.json", "effects.toml", "report.md", "signals.png", "residuals.png",
                 "localisation.png", "candidates.png", "discovery.rrd"):
        assert (out / name).is_file(), name
    snippet = (out / "effects.toml").read_text()
    assert tomllib.loads(snippet)["effects"]["loop_delay"]["Td"] == pytest.approx(
        doc["effects"][0]["parameters"]["Td"], rel=1e-5)
    spec, _ = resolve_model(config_for_recording(csv), out / "effects.toml")   # what `pdr validate --model` does
    assert spec.Td == pytest.approx(doc["effects"][0]["parameters"]["Td"], rel=1e-5)
    md = (out / "report.md").read_text()
    assert "loop_delay" in md and "![residuals](residuals.png)" in md
    import matplotlib.image as mpimg
    img = mpimg.imread(out / "residuals.png")
    assert img.ndim == 3 and img.shape[0] > 300
    assert "[effects]" not in csv.with_suffix(".toml").read_text()        # nothing adopted without --adopt


def test_rrd_has_measurement_models_and_residuals(delay_run):
    _, out, _ = delay_run
    assert os.environ.get("RERUN_STRICT") == "1"
    reader = RrdReader(out / "discovery.rrd")
    rows = Counter()
    for ch in reader.stream().to_chunks():
        if not ch.is_static:
            rows[ch.entity_path] += ch.num_rows
    n = rows["/signals/theta"]
    assert n > 400
    chunks = reader.stream().to_chunks()
    for sig in ("theta", "omega", "current"):
        assert rows[f"/signals/{sig}"] == n and rows[f"/residuals/{sig}"] == n
        names = [ch.to_record_batch().column("SeriesLines:names").to_pylist()[0] for ch in chunks
                 if ch.is_static and ch.entity_path in (f"/signals/{sig}", f"/residuals/{sig}")]
        assert sorted(names) == [["base model", "augmented model", "measured"], ["before", "after"]]
        width = {len(v) for ch in chunks if ch.entity_path == f"/signals/{sig}" and not ch.is_static
                 for v in ch.to_record_batch().column("Scalars:scalars").to_pylist()}
        assert width == {3}                                   # measured, base and augmented at every sample
    assert len(reader.blueprints()) == 1
    static = {ch.entity_path for ch in chunks if ch.is_static}
    assert {"/signals/theta/guards", "/trajectory_before/scaled", "/trajectory_after/scaled/augmented_model",
            "/report"} <= static
    assert rows["/mode/logged"] > 10                          # the command lane, one row per change


@pytest.mark.slow
def test_rerun_gives_identical_files(delay_run, tmp_path, monkeypatch):
    csv, out, _ = delay_run
    res = runner.invoke(app, ["discover", str(csv), "--out", str(tmp_path), "--no-rrd"])
    assert res.exit_code == 0, res.output
    for name in ("discovery.json", "effects.toml", "report.md", "signals.png", "residuals.png",
                 "localisation.png", "candidates.png"):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes(), name


@pytest.mark.slow
def test_adopt_only_on_request_and_validation_reads_it_back(tmp_path):
    _, _, csv = rig_kinematics((_effect("current_sensor_offset", 0.1),), seed=9, work=tmp_path)
    sidecar = csv.with_suffix(".toml")
    sidecar.write_text("# my rig\n" + sidecar.read_text() + "\n[effects]\nloop_delay = { Td = 0.001 }\n")
    before = config_for_recording(csv).effects
    res = runner.invoke(app, ["discover", str(csv), "--adopt", "--out", str(tmp_path / "out"), "--no-rrd"])
    assert res.exit_code == 0, res.output
    text = sidecar.read_text()
    assert text.startswith("# my rig\n")                 # the user's file is kept, only [effects] replaced
    cfg = config_for_recording(csv)
    assert {e.name for e in cfg.effects} == {"loop_delay", "current_sensor_offset"}
    assert before[0] in cfg.effects                      # the rig's own effect survives
    assert cfg.plant_spec().I0 == pytest.approx(0.1, rel=0.15)


def test_without_table_keeps_everything_else():
    text = ("[drive]\nv_in = 6.0  # V\n\n[effects]\nbacklash = { gap = 0.01 }\n[effects.loop_delay]\nTd = 0.02\n"
            "\n[model]\nb = 0.0\n")
    kept = without_table(text)
    assert "effects" not in kept and "backlash" not in kept
    assert tomllib.loads(kept) == {"drive": {"v_in": 6.0}, "model": {"b": 0.0}}


def test_merge_effects_adds_parameters_and_multiplies_spring_scales():
    merged = merge_effects((_effect("viscous_friction", 1e-4), _effect("spring_stiffness", 1.2)),
                           (_effect("viscous_friction", 2e-4), _effect("spring_stiffness", 0.5),
                            _effect("loop_delay", 0.01)))
    values = {e.name: next(iter(e.parameters.values())) for e in merged}
    assert values == pytest.approx({"viscous_friction": 3e-4, "spring_stiffness": 0.6, "loop_delay": 0.01})


def test_adopt_refuses_a_file_that_would_not_load(tmp_path):
    csv = tmp_path / "r.csv"
    csv.write_text("t_ms,counts,adc,dir\n0,0,511,1\n")
    (tmp_path / "r.toml").write_text("[drive]\nv_in = -1\n")          # already invalid
    from pipeline.errors import PdrError
    with pytest.raises(PdrError, match="v_in"):
        adopt(csv, (_effect("loop_delay", 0.01),))
    assert (tmp_path / "r.toml").read_text() == "[drive]\nv_in = -1\n"   # untouched


def test_cli_refuses_what_it_cannot_read(tmp_path):
    res = subprocess.run([str(Path(sys.executable).with_name("pdr")), "discover", str(tmp_path / "nope")],
                         capture_output=True, text=True)
    assert res.returncode == 2
    assert res.stderr.startswith("pdr: error:") and len(res.stderr.strip().splitlines()) == 1


def test_a_missing_raw_file_is_refused_before_the_discovery_is_imported(tmp_path):
    """Said at once: nothing of the discovery, its figures or its recording is imported for it; and the
    objects alive at the end are frozen, out of the teardown's garbage collections."""
    probe = ("import gc, sys\nfrom pipeline.cli import main\nsys.argv = ['pdr', 'discover', sys.argv[1]]\n"
             "try:\n    main()\nexcept SystemExit as e:\n    code = e.code\n"
             "heavy = ['pipeline.discover.stage', 'matplotlib', 'rerun', 'scipy', 'pandas']\n"
             "print(code, gc.get_freeze_count() > 1000, [m for m in heavy if m in sys.modules])\n")
    res = subprocess.run([sys.executable, "-c", probe, str(tmp_path / "nope.csv")], capture_output=True, text=True)
    assert res.stdout.split() == ["2", "True", "[]"], res.stdout + res.stderr
    assert "nope.csv: no such raw recording" in res.stderr


def test_snippet_layers_over_the_rig_like_validation(tmp_path):
    snippet = tmp_path / "effects.toml"
    snippet.write_text("[effects]\nviscous_friction = { b = 0.0002 }\n")
    cfg = resolve_config([snippet])
    assert np.isclose(cfg.plant_spec().params.b, 7.7e-4 + 2e-4)


@pytest.mark.slow
def test_an_overstated_declared_effect_is_pointed_out_not_named(tmp_path):
    """The TOML declares a loop delay the rig does not have: nothing to add (effects only add),
    so the verdict is unexplained, and the report says which declared value fits at what."""
    _, _, csv = rig_kinematics((), seed=5, work=tmp_path)
    sidecar = csv.with_suffix(".toml")
    sidecar.write_text(sidecar.read_text() + "\n[effects]\nloop_delay = { Td = 0.03 }\n")
    res = runner.invoke(app, ["discover", str(csv), "--json", "--out", str(tmp_path / "out"), "--no-rrd"])
    doc = json.loads(res.stdout)
    assert doc["verdict"] == "unexplained" and doc["effects"] == []
    over = doc["declared_too_large"]
    assert [o["name"] for o in over] == ["loop_delay"] and over[0]["fitted"] < 0.003
    assert any("overstate loop_delay" in line for line in doc["unexplained"])


def test_the_command_collects_garbage_less_often_and_restores_the_collector():
    import gc

    from pipeline.discover.cli import fewer_collections

    before = gc.get_threshold()
    young = []
    with pytest.raises(RuntimeError), fewer_collections():
        assert gc.get_threshold()[0] >= 50 * before[0]
        young += [[k] for k in range(5000)]
        assert gc.get_count()[0] >= 5000                # not collected yet
        raise RuntimeError("the command failed")
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == 0
    assert any(o is young for o in gc.get_objects(generation=2))    # what was young joined the oldest generation
