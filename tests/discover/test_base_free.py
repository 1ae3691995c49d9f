"""On a rig whose [model] is not declared, effects that only stand in for the base model are dropped."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.calibrate.load import load_measurements
from pipeline.discover.base_free import check_with_base_free
from pipeline.model.effects import CATALOGUE
from pipeline.rig.other_rigs import OffRig, rigs, write_rig

PDR = str(Path(sys.executable).with_name("pdr"))
RIG = rigs(seed=20261128, count=3)[2]         # off Table I; its hidden effect is a backlash


@pytest.fixture(scope="module")
def hidden_csv(tmp_path_factory):
    rig = OffRig(index=RIG.index, model=RIG.model, hidden=CATALOGUE["backlash"](gap=0.06))
    return write_rig(rig, tmp_path_factory.mktemp("lab") / "raw", seed=3, roles=("hidden",), duration_s=15.0)["hidden"]


@pytest.fixture(scope="module")
def hidden(hidden_csv):
    work = hidden_csv.parent.parent
    measurements, _, declared = load_measurements([str(hidden_csv)], work / "processed", work / "work")
    assert not declared
    return measurements[0]


def test_stand_ins_are_dropped_and_the_real_effect_kept(hidden):
    stand_ins = (CATALOGUE["spring_stiffness"](k_scale=0.93), CATALOGUE["loop_delay"](Td=0.018))
    check = check_with_base_free(hidden, (CATALOGUE["backlash"](gap=0.05), *stand_ins))
    assert [e.name for e in check.kept] == ["backlash"]
    assert set(check.dropped) == {"spring_stiffness", "loop_delay"}
    lo, hi = check.intervals["backlash"]
    assert lo <= 0.06 <= hi and check.kept[0].gap == pytest.approx(0.06, rel=0.2)
    assert check.base_off and "pdr calibrate" in check.hint


def test_where_the_base_is_off_the_effect_the_search_missed_is_named_in_place_of_its_stand_in(hidden):
    """The search, on Table I's base, may read a backlash beside the rig's own springs as a Coulomb
    friction; with the base free the catalogue is offered again, and the backlash is what holds."""
    check = check_with_base_free(hidden, (CATALOGUE["coulomb_friction"](Tc=0.002),))
    assert [e.name for e in check.kept] == ["backlash"]
    assert check.added == ("backlash",) and check.dropped == ("coulomb_friction",)
    lo, hi = check.intervals["backlash"]
    assert lo <= 0.06 <= hi and check.kept[0].gap == pytest.approx(0.06, rel=0.2)
    assert "pdr calibrate" in check.hint


def test_past_the_decision_budget_the_check_only_drops(hidden):
    """The work budget bounds the check's forward steps, not its elimination: past it, the stand-in the
    search chose is still dropped, nothing is offered in its place, and the answer says the budget ended
    it and asks for a calibration."""
    from dataclasses import replace as _replace

    from pipeline.discover.base_free import base_free_text
    from pipeline.discover.policy import DEFAULT_POLICY

    policy = _replace(DEFAULT_POLICY, decision_work_budget=1_000_000)
    check = check_with_base_free(hidden, (CATALOGUE["coulomb_friction"](Tc=0.002),), policy=policy,
                                 spent=policy.decision_work_budget)
    assert check.kept == () and check.added == () and check.dropped == ("coulomb_friction",)
    assert check.stopped_for_time and check.work > policy.decision_work_budget
    assert "pdr calibrate" in check.hint and "work budget" in base_free_text(check.to_json())


def test_stand_ins_the_search_calls_an_explanation_are_not_named(tmp_path):
    """A clean recording of an undeclared rig off Table I (stiffer springs, more friction, another motor)
    that forward selection explains with springs, viscous friction and a driver drop: each stands in for
    the rig's own base parameters, so the answer names none of them, says ``unexplained`` and asks for
    a calibration."""
    from pipeline.derive.stage import ingest_and_derive
    from pipeline.discover.stage import discover_run

    rig = rigs(seed=14, count=6)[4]
    paths = write_rig(rig, tmp_path / "raw", seed=14, roles=("clean",), duration_s=15.0)
    d, doc = discover_run(ingest_and_derive(paths["clean"], tmp_path / "processed")[0])
    assert d.selection.effects                       # the search did find stand-ins ...
    assert doc["effects"] == []                      # ... and the answer names none of them
    assert doc["verdict"] == "unexplained" and "pdr calibrate" in doc["hint"]
    # ... and says so where a user reads it: the terminal's summary and report.md
    from pipeline.discover.cli import _summary
    from pipeline.discover.report import markdown

    for text in (_summary({**doc, "seconds": 1.0}), markdown(d, doc)):
        assert "pdr calibrate" in text and "stood in for the base" in text, text


@pytest.mark.long       # a whole discovery with the base-free check, in a subprocess (~18 s)
def test_what_was_found_beside_an_off_base_is_not_adopted(hidden_csv, tmp_path):
    """``--adopt`` would write effects valued beside a free base into a TOML whose base is Table I's: it
    answers, draws its report, writes nothing into the TOML and exits 2 saying to calibrate first."""
    sidecar = hidden_csv.with_suffix(".toml")
    before = sidecar.read_bytes()
    res = subprocess.run([PDR, "discover", str(hidden_csv), "--adopt", "--json", "--no-rrd", "--out", str(tmp_path)],
                         capture_output=True, text=True, cwd=hidden_csv.parent.parent)
    assert res.returncode == 2, res.stderr
    doc = json.loads(res.stdout)
    assert [e["name"] for e in doc["effects"]] == ["backlash"] and doc["adopted"] is None
    assert res.stderr.startswith("pdr: error: ") and "not adopted" in res.stderr and "pdr calibrate" in res.stderr
    assert sidecar.read_bytes() == before
    assert (tmp_path / "signals.png").is_file()           # the report was still drawn
    # without --json, the line after the verdict says so (the command prints ``_where`` of the same answer)
    from pipeline.discover.cli import _where

    told = _where(doc, {"markdown": tmp_path / "report.md", "toml": tmp_path / "effects.toml"})
    assert "--adopt writes nothing until the rig is calibrated" in told, told
