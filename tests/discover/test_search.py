"""The search's criterion on virtual-rig recordings (``discover.search``): what it decides, not its path."""

import numpy as np
import pytest

from pipeline.discover.candidates import Evaluator
from pipeline.discover.measurement import measurement_from_kinematics
from pipeline.discover.policy import DEFAULT_POLICY, DiscoveryPolicy
from pipeline.discover.residuals import noise_floor
from pipeline.discover.criterion import charge, room
from pipeline.discover.search import select
from pipeline.model.effects import CATALOGUE, make_effect
from tests.discover.synthetic import rig_kinematics


def _evaluator(effects, tmp_path, seed=3):
    kin, cfg, _ = rig_kinematics(effects, seed=seed, work=tmp_path, duration_s=12.0)
    meas = measurement_from_kinematics(kin, cfg, "r")
    return Evaluator(meas, noise_floor(meas))


def test_every_parameter_of_an_effect_is_charged():
    for name, effect in CATALOGUE.items():
        assert charge(name, DEFAULT_POLICY) == DEFAULT_POLICY.evidence_per_parameter * len(effect.PARAMS)


def test_the_room_left_for_evidence_is_what_the_residual_holds_above_the_noise(tmp_path):
    """``room``: the evidence left in the residual, which stops the rounds.  The true model leaves about
    a charge's worth (the floor is estimated); the base model of the same recording, with its viscous
    friction missing, leaves many times more."""
    hidden = (make_effect("viscous_friction", {"b": 3e-4}),)
    ev = _evaluator(hidden, tmp_path)
    assert room(ev, hidden) < 2 * DEFAULT_POLICY.evidence_per_parameter
    assert room(ev, ()) > max(5 * room(ev, hidden), 10 * DEFAULT_POLICY.evidence_per_parameter)


@pytest.mark.parametrize("per_parameter, named", [(5.0, True), (1e6, False)])
def test_the_charge_decides_what_is_named(tmp_path, per_parameter, named):
    """The same recording, two policies: the default charge names the hidden friction; a charge no
    evidence can clear names nothing and leaves the structure to the verdict."""
    hidden = (make_effect("viscous_friction", {"b": 3e-4}),)
    ev = _evaluator(hidden, tmp_path)
    sel = select(ev.meas, policy=DiscoveryPolicy(evidence_per_parameter=per_parameter))
    assert [e.name for e in sel.effects] == (["viscous_friction"] if named else [])
    assert sel.verdict == ("explained" if named else "unexplained")
    if named:
        assert sel.effects[0].parameters["b"] == pytest.approx(3e-4, rel=0.1)
        lo, hi = sel.intervals[0]
        assert lo <= 3e-4 <= hi
    assert all(np.isfinite(c.evidence) for rnd in sel.rounds for c in rnd if hasattr(c, "evidence"))


def test_a_scan_scores_its_best_point_and_neighbours_from_their_own_starts(tmp_path):
    """The coarse scan may replay a point from the model's start (a spring changes neither the inputs nor
    where the pinion rests), but where the fit will bracket -- the best point and its neighbours -- each
    point's score is its own model's, start estimated for it, and the best point is the hidden value's."""
    from pipeline.discover.candidates import _nll_of, make, scan
    from pipeline.discover.residuals import residuals

    ev = _evaluator((make_effect("spring_stiffness", {"k_scale": 0.8}),), tmp_path)
    sc = scan(ev, (), "spring_stiffness")
    best = int(np.argmin(sc.nll))
    assert sc.grid[best - 1] < 0.8 < sc.grid[best + 1]
    for k in (best - 1, best, best + 1):
        own = _nll_of(ev, residuals(ev.meas, ev.sim((make("spring_stiffness", float(sc.grid[k])),))))
        assert sc.nll[k] == pytest.approx(own, rel=1e-12)
