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


def test_every_complete_cycle_and_only_those():
    """Upper turn -> lower turn -> upper turn, on a hand-made overshoot table: the last complete cycle is
    kept, and a turn that was cut off (not turned) ends no cycle."""
    import pandas as pd

    from pipeline.derive.cycles import cycle_table

    turns = [(1.0, 1, 1.05, True), (2.9, -1, -1.03, True), (4.8, 1, 1.04, True), (6.7, -1, -1.02, True),
             (8.6, 1, 1.06, True), (10.0, -1, -0.5, False)]
    over = pd.DataFrame({"turn_t_s": [t for t, *_ in turns], "direction": [d for _, d, *_ in turns],
                         "turn_theta_rad": [th for *_, th, _ in turns], "turned": [ok for *_, ok in turns]})
    cycles = cycle_table(over)
    assert cycles["start_s"].tolist() == [1.0, 4.8] and cycles["end_s"].tolist() == [4.8, 8.6]
    assert cycles["period_s"].tolist() == pytest.approx([3.8, 3.8])
    assert cycles["theta_min_rad"].tolist() == [-1.03, -1.02]
    assert cycles["center_rad"].tolist() == pytest.approx([(1.05 - 1.03) / 2, (1.04 - 1.02) / 2])
    cut = over.assign(turned=[True, True, True, False, True, True])   # the lower turn of cycle 2 not seen
    assert cycle_table(cut)["start_s"].tolist() == [1.0]


def test_steady_figures_leave_out_the_swing_from_rest():
    import pandas as pd

    from pipeline.derive.cycles import cycle_summary

    cycles = pd.DataFrame({"period_s": [4.6, 3.7, 3.8], "amplitude_rad": [1.25, 1.05, 1.05],
                           "center_rad": [0.1, 0.0, 0.0]})
    s = cycle_summary(cycles)
    assert s["period_s"]["n"] == 3 and s["steady_period_s"]["n"] == 2
    assert s["steady_period_s"]["mean"] == pytest.approx(3.75) and s["frequency_hz"] == pytest.approx(1 / 3.75)
    assert s["steady_amplitude_rad"]["max"] == pytest.approx(1.05)
    assert s["log_decrement"] == pytest.approx(np.log(1.25 / 1.05) / 2)
    two = cycle_summary(cycles.iloc[:2])
    assert two["steady_period_s"]["n"] == 1 and two["steady_period_s"]["mean"] == pytest.approx(3.7)
    one = cycle_summary(cycles.iloc[:1])
    assert one["steady_period_s"]["n"] == 1 and one["log_decrement"] is None
