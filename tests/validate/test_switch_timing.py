"""Switches the data leave open are settled by validation as discovery settles them: a motor started on a
row lost over serial, and a switch inferred from the guards on a guard.  The replay's MSE then measures
the model, not the sketch's rule's guess (``validation.json``'s ``switch_timing`` says what moved)."""

import json

import numpy as np
import pandas as pd

from pipeline.config import default_config
from pipeline.estimate.switch_timing import Timing, settle
from pipeline.model.simulate import simulate
from pipeline.validate.compare import initial_state, settled_timing, simulate_both
from pipeline.validate.stage import validate_run
from tests.validate.synthetic import AMPS_PER_STEP, COUNTS_PER_REV, synthetic_run

CFG = default_config()
COUNT = 2 * np.pi / COUNTS_PER_REV
HALF = COUNT / 2


def _started_after(off: int, n: int = 400, seed: int = 0) -> pd.DataFrame:
    """A run whose motor starts at sample ``off`` (a timer's start), through the encoder and the ADC."""
    spec = CFG.plant_spec()
    t = np.arange(n) * spec.period_s
    running = simulate(spec, t[: n - off])                    # the closed loop's commands from its start
    d = np.concatenate([np.zeros(off, dtype=np.int8), running.dir.astype(np.int8)])
    sim = simulate(spec, t, dir_log=d, closed_loop=False)
    rng = np.random.default_rng(seed)
    theta = np.round(sim.theta / COUNT) * COUNT
    current = np.round((sim.current_measured + AMPS_PER_STEP * rng.standard_normal(n)) / AMPS_PER_STEP) * AMPS_PER_STEP
    return pd.DataFrame({"t_s": t, "theta_rad": theta, "omega_rad_s": np.gradient(theta, t), "current_a": current,
                         "dir": d, "dir_inferred": False})


def test_a_motor_started_on_a_lost_row_is_replayed_from_the_lost_instant(tmp_path):
    kin = _started_after(10).drop(index=10).reset_index(drop=True)        # the start's row lost
    spec = CFG.plant_spec()
    rule = simulate_both(spec, kin)["replay"]
    timing, start = settled_timing(kin, spec, HALF)
    assert timing.shifted == (9,)
    settled = simulate_both(spec, kin, start, timing)["replay"]
    assert start == initial_state(kin, spec, timing)                # the start estimated under that timing
    mse = lambda sim: float(np.mean((sim.theta - kin["theta_rad"]) ** 2))   # noqa: E731
    assert mse(settled) < COUNT ** 2 < mse(rule)
    paths = synthetic_run(tmp_path / "processed", kin=kin, cfg=CFG)
    validate_run(paths, rrd=False, png=False)
    doc = json.loads(paths.validation.read_text())
    assert doc["switch_timing"] == {"inferred_moved_s": [], "lost_rows_moved_after_s": [kin["t_s"][9]]}
    assert doc["replay"]["signals"]["theta"]["mse"] == mse(settled)


def test_a_row_lost_where_the_command_held_moves_nothing():
    kin = _started_after(10).drop(index=200).reset_index(drop=True)
    assert kin["dir"][199] == kin["dir"][200] != 0
    assert settled_timing(kin, CFG.plant_spec(), HALF)[0] == Timing(kin["dir"].to_numpy())


def test_an_inferred_switch_on_a_guard_moves_only_where_the_replay_is_better():
    """``settle`` tries each open switch a sample moved and keeps it only for a lower misfit."""
    theta = np.array([0.0, 0.5, 1.0, 0.5, 0.0, -0.5, -1.0, -0.5])
    d = np.array([1, 1, -1, -1, -1, -1, 1, 1], dtype=np.int8)
    prefer_late = lambda tm: 0.0 if tm.dir[2] == 1 else 1.0               # noqa: E731
    moved = settle(Timing(d), t=np.arange(8.0), theta=theta, guard=1.0, half_count=0.01, inferred=True,
                   misfit=prefer_late)
    assert moved.dir.tolist() == [1, 1, 1, -1, -1, -1, 1, 1]
    kept = settle(Timing(d), t=np.arange(8.0), theta=theta, guard=1.0, half_count=0.01, inferred=True,
                  misfit=lambda tm: float(np.sum(tm.dir != d)))
    assert kept.dir.tolist() == d.tolist()


def test_an_earlier_switch_is_judged_again_once_a_later_one_has_moved():
    """Two switches on a guard, both a sample early.  Moving the first alone replays worse while the second
    is still off (its transient outweighs the gain); once the second has moved, the first is judged again."""
    theta = np.array([0.0, 0.5, 1.0, 0.5, 0.0, -0.5, -1.0, -0.5, 0.0])
    d = np.array([1, 1, -1, -1, -1, -1, 1, 1, 1], dtype=np.int8)
    truth = np.array([1, 1, 1, -1, -1, -1, -1, 1, 1], dtype=np.int8)

    def misfit(tm: Timing) -> float:
        first_right, second_right = tm.dir[2] == truth[2], tm.dir[6] == truth[6]
        return {(False, False): 2.0, (True, False): 3.0, (False, True): 1.0, (True, True): 0.0}[
            (bool(first_right), bool(second_right))]

    moved = settle(Timing(d), t=np.arange(9.0), theta=theta, guard=1.0, half_count=0.01, inferred=True,
                   misfit=misfit)
    assert moved.dir.tolist() == truth.tolist()
