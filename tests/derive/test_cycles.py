"""Cycle period, amplitude and centre against the virtual rig's true turning points (computed here)."""

import math

import numpy as np
import pytest

from pipeline.derive.stage import derive_tables
from pipeline.model.effects import make_effect
from pipeline.rig.recording import RigSetup
from tests.derive.rigdata import rig_run
from tests.derive.test_overshoot import true_turns

COUNT = 2 * math.pi / 6533.12


@pytest.mark.parametrize("effects", [(), (make_effect("backlash", {"gap": 0.1}),)], ids=["base", "backlash"])
def test_cycles_against_the_true_turning_points(effects):
    sig, cfg, rec = rig_run(RigSetup(effects=effects), seed=3)
    cycles = derive_tables(sig, cfg).cycles
    turns = true_turns(rec)
    up = turns[turns["theta_rad"] > 0]
    down = turns[turns["theta_rad"] < 0]
    assert len(cycles) >= 4
    for row in cycles.itertuples():
        a = up.iloc[int(np.argmin(np.abs(up["t_s"].to_numpy() - row.start_s)))]
        b = up.iloc[int(np.argmin(np.abs(up["t_s"].to_numpy() - row.end_s)))]
        low = down[(down["t_s"] > a["t_s"]) & (down["t_s"] < b["t_s"])]
        assert len(low) == 1
        hi, lo = a["theta_rad"], low["theta_rad"].iloc[0]
        assert row.period_s == pytest.approx(b["t_s"] - a["t_s"], abs=0.05)
        assert row.theta_max_rad == pytest.approx(hi, abs=COUNT)
        assert row.theta_min_rad == pytest.approx(lo, abs=COUNT)
        assert row.amplitude_rad == pytest.approx((hi - lo) / 2, abs=COUNT)
        assert row.center_rad == pytest.approx((hi + lo) / 2, abs=COUNT)
    assert np.abs(cycles["center_rad"].iloc[1:]).max() < 0.05          # symmetric once past the swing from rest
