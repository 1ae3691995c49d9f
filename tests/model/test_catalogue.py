"""Conformance of every catalogued effect, run for each entry (a new effect with a missing part fails here
by name): its declaration is complete; the fast simulator equals the independent reference plant with it
on; and a virtual-rig recording hiding it is named by discovery with its parameter recovered."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pipeline.config import default_config
from pipeline.discover.stage import discover, discovery_json
from pipeline.model.effects import CATALOGUE, SIGNATURES, build_spec, make_effect
from pipeline.model.simulate import simulate
from pipeline.rig.plant import simulate_reference
from tests.discover.synthetic import rig_kinematics
from tests.model.test_nonsmooth import TOL

NAMES = list(CATALOGUE)
MODEL_MD = Path(__file__).resolve().parents[2] / "docs" / "MODEL.md"
EFFECTS_DIR = Path(__file__).resolve().parents[2] / "pipeline" / "model" / "effects"


def _spec(*effects):
    cfg = default_config()
    return build_spec(cfg.model, cfg.controller, cfg.drive, effects)


def _flat(spec) -> dict[str, float]:
    d = dataclasses.asdict(spec)
    return {**d.pop("params"), **{k: v for k, v in d.items() if v is not None}}


@pytest.mark.parametrize("name", NAMES)
def test_declaration_is_complete(name):
    cls = CATALOGUE[name]
    assert (EFFECTS_DIR / f"{name}.py").is_file(), "one module per effect, named after it"
    assert cls.WHAT and cls.PARAMS and cls.SIGNATURE in SIGNATURES
    assert [f.name for f in dataclasses.fields(cls)] == [p.name for p in cls.PARAMS]
    for p in cls.PARAMS:
        lo, hi = p.bounds
        assert p.unit and lo < hi, p.name
        assert lo <= p.absent <= hi and lo <= p.typical <= hi and p.typical != p.absent, p.name
        assert all(lo <= v <= hi for v in p.scan) and p.absent in p.scan, p.name
    typical = cls.typical()
    assert make_effect(name, typical.parameters) == typical             # the config path accepts it
    absent = cls(**{p.name: p.absent for p in cls.PARAMS})
    assert _spec(absent) == _spec()                                     # absent changes nothing
    assert _spec(typical) != _spec()                                    # typical changes something
    assert typical.combine(absent) == typical
    stacked, combined = _flat(_spec(typical, typical)), _flat(_spec(typical.combine(typical)))
    assert stacked == pytest.approx(combined, rel=1e-12)               # stacking is what combining says



@pytest.mark.parametrize("name", NAMES)
def test_the_scan_reaches_down_to_the_smallest_nameable_size(name):
    """Discovery scans only so many points, each a replay and a start estimate; a scan starting far above the
    smallest size it may name (``DiscoveryPolicy.min_size_share`` of the typical) would bracket such an effect
    between "absent" and a point many times its size.  On each side of "absent" the bounds allow, the
    nearest point is within 2.5 times that size."""
    from pipeline.discover.policy import DEFAULT_POLICY

    p = CATALOGUE[name].PARAMS[0]
    smallest = DEFAULT_POLICY.min_size_share * abs(p.typical - p.absent)
    offsets = np.array(p.scan) - p.absent
    for side, room in ((1.0, p.bounds[1] - p.absent), (-1.0, p.absent - p.bounds[0])):
        if room > 0:
            nearest = np.min(side * offsets[side * offsets > 0])
            assert nearest <= 2.5 * smallest, (side, nearest, smallest)

def _catalogue_rows() -> list[str]:
    """The catalogue table of docs/MODEL.md as the effects package declares it."""
    rows = []
    for name, cls in CATALOGUE.items():
        p = cls.PARAMS[0]
        assert len(cls.PARAMS) == 1, "MODEL.md's table has one parameter column"
        rows.append(f"| `{name}` | `{p.name}` [{p.unit}] | {p.bounds[0]:g} .. {p.bounds[1]:g} | {p.typical:g} "
                    f"| {cls.WHAT} |")
    return rows


def test_model_md_catalogue_is_the_effects_package():
    """docs/MODEL.md's table is the catalogue, row for row (names, order, parameters, units, ranges, typical
    sizes, what changes): a new or changed effect fails here until the document says the same."""
    text = MODEL_MD.read_text(encoding="utf-8").split("## The effect catalogue", 1)[1]
    table = [line for line in text.splitlines() if line.startswith("| `")]
    expected = _catalogue_rows()
    assert table == expected, "docs/MODEL.md's catalogue should read:\n" + "\n".join(expected)


@pytest.mark.parametrize("name", NAMES)
def test_fast_simulator_equals_the_reference_plant(name):
    spec = _spec(CATALOGUE[name].typical())
    t = np.cumsum(np.where(np.arange(300) % 3 == 0, 0.051, 0.050))
    fast, ref = simulate(spec, t), simulate_reference(spec, t)
    assert fast.switches >= 3 and np.array_equal(fast.dir, ref.dir)
    for f in ("theta", "omega", "current", "current_measured"):
        np.testing.assert_allclose(getattr(fast, f), getattr(ref, f), rtol=0, atol=TOL, err_msg=f)


@pytest.mark.slow
@pytest.mark.long        # tests/discover/test_discovery.py names one effect per residual signature in make test
@pytest.mark.parametrize("name", NAMES)
def test_virtual_rig_recording_is_named_and_its_parameter_recovered(name, tmp_path):
    hidden = CATALOGUE[name].typical()
    kin, rig, _ = rig_kinematics((hidden,), seed=7, work=tmp_path)
    d = discover(kin, rig, name)
    assert [e.name for e in d.effects][:1] == [name], discovery_json(d, name)["candidates"][:3]
    for key, truth in hidden.parameters.items():
        assert abs(d.effects[0].parameters[key] - truth) <= 0.15 * abs(truth), key
