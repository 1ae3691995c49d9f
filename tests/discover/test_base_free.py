"""On a rig whose [model] is not declared, effects that only stand in for the base model are dropped."""

import pytest

from pipeline.calibrate.load import load_measurements
from pipeline.discover.base_free import check_with_base_free
from pipeline.model.effects import CATALOGUE
from pipeline.rig.other_rigs import OffRig, rigs, write_rig

RIG = rigs(seed=20261128, count=3)[2]         # off Table I; its hidden effect is a backlash


@pytest.fixture(scope="module")
def hidden(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("lab")
    rig = OffRig(index=RIG.index, model=RIG.model, hidden=CATALOGUE["backlash"](gap=0.06))
    paths = write_rig(rig, tmp / "raw", seed=3, roles=("hidden",), duration_s=15.0)
    measurements, _, declared = load_measurements([str(paths["hidden"])], tmp / "processed", tmp / "work")
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
