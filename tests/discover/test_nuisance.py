"""Discovery on virtual-rig recordings whose start and noise it was not tuned on (issue 15, items 1-2).

Each recording goes through the rig's own plant and sensor chain, a CSV + TOML, ingest and
derive.  The start is a nuisance: logging opened while the rig was running, a first current
reading three sigmas off under three times the sensor noise, a reversed command still on its
way to the motor under a 100 ms loop delay.  The noise floor comes from the recording, so the
verdicts hold on a noisier sensor and on the 100 mV/A and 66 mV/A parts.
"""

import pytest

from pipeline.discover.stage import discover
from pipeline.model.effects import make_effect
from tests.validate.rig_cases import SHIPPED_NOISE_V, rig_case, sensor_config

# each test re-runs a whole discovery on a pinned case for one path of the search: make test-all
pytestmark = [pytest.mark.slow, pytest.mark.long]

VISCOUS = make_effect("viscous_friction", {"b": 7.7e-4})


def _found(d) -> dict[str, float]:
    return {e.name: next(iter(e.parameters.values())) for e in d.effects}


def test_logging_opened_while_the_rig_ran_is_clean(tmp_path):
    kin, cfg, truth = rig_case(open_s=6.3, work=tmp_path)
    assert abs(truth["omega_rad_s"].iloc[0]) > 0.5                  # mid-motion at the first sample
    d = discover(kin, cfg, "late")
    assert d.verdict == "none", _found(d)


def test_logging_opened_while_the_rig_ran_names_only_the_hidden_effect(tmp_path):
    kin, cfg, _ = rig_case((VISCOUS,), open_s=7.2, work=tmp_path)
    d = discover(kin, cfg, "late-viscous")
    assert d.verdict == "explained" and list(_found(d)) == ["viscous_friction"]
    assert _found(d)["viscous_friction"] == pytest.approx(7.7e-4, rel=0.02)


def test_a_noisy_first_current_sample_is_not_an_effect(tmp_path):
    kin, cfg, truth = rig_case((VISCOUS,), pre_roll_s=0.0, noise_v=3 * SHIPPED_NOISE_V, first_adc_shift=15,
                               work=tmp_path)
    assert truth["current_a"].iloc[0] == 0.0 and kin["current_a"].iloc[0] > 0.2   # ~3 sigma of 3x the noise
    d = discover(kin, cfg, "noisy-first")
    assert d.verdict == "explained" and list(_found(d)) == ["viscous_friction"]
    assert _found(d)["viscous_friction"] == pytest.approx(7.7e-4, rel=0.02)


def test_a_command_in_flight_under_a_loop_delay_leaves_no_start_transient(tmp_path):
    kin, cfg, _ = rig_case((make_effect("loop_delay", {"Td": 0.1}),), after_switch=1, seed=2, work=tmp_path)
    d = discover(kin, cfg, "in-flight")
    assert d.verdict == "explained" and list(_found(d)) == ["loop_delay"]
    assert _found(d)["loop_delay"] == pytest.approx(0.1, rel=0.02)
    start = d.meas.x0(d.meas.spec(d.effects), d.selection.command_after)
    assert len(start.commands) == 2                                  # in force at t0, and one in flight


@pytest.mark.parametrize("effect, sensitivity", [(None, 0.066), (VISCOUS, 0.100)])
def test_verdicts_hold_on_four_times_the_noise_and_coarser_current_sensors(tmp_path, effect, sensitivity):
    effects = () if effect is None else (effect,)
    kin, cfg, _ = rig_case(effects, config=sensor_config(sensitivity), seed=5, noise_v=4 * SHIPPED_NOISE_V,
                           work=tmp_path)
    d = discover(kin, cfg, "noisy")
    assert list(_found(d)) == [e.name for e in effects]
    assert d.verdict == ("explained" if effects else "none")


@pytest.mark.parametrize("effects", [(), (VISCOUS,)], ids=["clean", "viscous"])
def test_after_a_board_reset_the_counters_zero_is_a_nuisance_not_a_torque(tmp_path, effects):
    """After a board reset the counter restarts wherever the pinion then is (here 2 s after the
    motor went off, still swinging); the springs' rest in that count is unknown, and a constant
    torque, which only moves it, is not named for it.  The segment's runs say they follow a reset."""
    from pipeline.derive.stage import derive_run
    from pipeline.discover.stage import after_board_reset, discover_run
    from pipeline.runs import ingest_segment
    from pipeline.ingest.stage import ingest_recording
    from pipeline.rig.recording import RigSetup, make_recording, write_recording
    from pipeline.rig.serial import Artefacts

    setup = RigSetup(effects=effects, duration_s=40.0, artefacts=Artefacts(reset_after_s=12.0, reset_gap_s=2.0))
    rec = make_recording(setup, seed=3)
    assert abs(rec.truth_meta["segments"][1]["theta_ref_rad"]) > 0.02          # the count restarted off the rest
    write_recording(rec, tmp_path / "raw", "reset")
    first, after = ingest_recording(tmp_path / "raw" / "reset.csv", tmp_path / "processed").runs
    assert not after_board_reset(ingest_segment(first)) and after_board_reset(ingest_segment(after))
    derive_run(after)
    d, doc = discover_run(after)
    assert doc["verdict"] == ("explained" if effects else "none"), doc["effects"]
    assert [e["name"] for e in doc["effects"]] == [e.name for e in effects]
    assert "constant_load_torque" not in {c["name"] for c in doc["candidates"]}   # it only moves the springs' rest


def test_a_hot_winding_is_not_named_as_a_slightly_stiffer_spring(tmp_path):
    """A hot armature (Ra x1.4-1.8, outside the catalogue) shifts the oscillation's period; springs
    1-2 % stiffer absorb most of that, a small fraction of a clearly visible stiffness change, so
    nothing is named and the structure is left unexplained.  Draw 44 of the randomised rig (seed 15,
    10 s) was called explained by springs 2 % stiffer."""
    import numpy as np

    from pipeline.derive.stage import derive_run
    from pipeline.discover.stage import discover_run, segment_to_discover
    from pipeline.ingest.stage import ingest_recording
    from pipeline.rig.randomised import randomised_setup
    from pipeline.rig.recording import make_recording, write_recording

    draw = randomised_setup(np.random.default_rng([15, 44]))
    assert draw.outside == "armature_resistance" and not draw.effects
    write_recording(make_recording(draw.setup), tmp_path / "raw", "hot")
    runs = ingest_recording(tmp_path / "raw" / "hot.csv", tmp_path / "processed").runs
    for paths in runs:
        derive_run(paths)
    _, doc = discover_run(segment_to_discover(runs))
    assert doc["verdict"] == "unexplained" and doc["effects"] == []
    spring = next(c for c in doc["candidates"] if c["name"] == "spring_stiffness")
    assert abs(spring["parameters"]["k_scale"] - 1.0) < 0.03 and not spring["checks"]["size"]


def _randomised(index: int, tmp_path, after_reset: bool = False, discovery: bool = False) -> tuple:
    """Randomised draw ``index`` (seed 15) through CSV, ingest, derive and discovery of the segment
    ``pdr discover`` takes (``after_reset``: of the last, which follows a board reset); (draw, JSON),
    and the ``Discovery`` too when ``discovery``."""
    import numpy as np

    from pipeline.derive.stage import derive_run
    from pipeline.discover.stage import after_board_reset, discover_run, segment_to_discover
    from pipeline.runs import ingest_segment
    from pipeline.ingest.stage import ingest_recording
    from pipeline.rig.randomised import randomised_setup
    from pipeline.rig.recording import make_recording, write_recording

    draw = randomised_setup(np.random.default_rng([15, index]))
    write_recording(make_recording(draw.setup), tmp_path / "raw", "r")
    runs = ingest_recording(tmp_path / "raw" / "r.csv", tmp_path / "processed").runs
    for paths in runs:
        derive_run(paths)
    if after_reset:
        assert len(runs) > 1 and after_board_reset(ingest_segment(runs[-1]))
    d, doc = discover_run(runs[-1] if after_reset else segment_to_discover(runs))
    return (draw, doc, d) if discovery else (draw, doc)


def _named_right(draw, doc) -> None:
    truth = {e.name: next(iter(e.parameters.values())) for e in draw.effects}
    found = {e["name"]: next(iter(e["parameters"].values())) for e in doc["effects"]}
    assert doc["verdict"] == "explained" and set(found) == set(truth), (doc["verdict"], found)
    for name, value in truth.items():
        assert found[name] == pytest.approx(value, rel=0.1), name


def test_a_sensor_offset_under_half_a_noise_sigma_is_named_over_a_long_recording(tmp_path):
    """Randomised draw 173 (seed 15): a -85 mA sensor offset under 0.27 A of noise (the 30 A part, 3.6x
    the noise), 1,193 samples: a tenth of a noise variance per sample, ~100 in chi-square over the
    recording.  A quarter noise variance per sample was asked of the current, and it was called
    ``none``.  A row lost at the first reversal also bent the start (a transient over 40 s)."""
    _named_right(*_randomised(173, tmp_path))


def test_switches_read_off_the_angle_are_settled_again_under_the_effects_found(tmp_path):
    """Randomised draw 4 (seed 15): a constant load torque, no ``dir`` column.  Four reversals were read
    off the angle within half a count of the guard; the base model, lacking the torque, settled three
    of them a sample late, and with the torque found one sample of the wrong command left a transient
    of 2e4 noise variances (``unexplained``)."""
    _named_right(*_randomised(4, tmp_path))


def test_a_row_lost_at_a_reversal_is_decided_by_the_measured_angle(tmp_path):
    """Randomised draw 8 (seed 15): a voltage drop beside a load torque, no ``dir``, 112 rows lost.  A
    lost row's command decided on the model's angle made the replay jump as a parameter moved the
    angle across the guard there (3,800 in log-likelihood between two torques 1 % apart), and the joint
    fit stopped at a torque 8 % off (``unexplained``)."""
    _named_right(*_randomised(8, tmp_path))


def test_an_effect_the_later_ones_made_redundant_frees_a_round(tmp_path):
    """Randomised draw 196 (seed 15): a sensor offset beside a rack inertia and a voltage drop.  Round two
    took Coulomb friction, round three the voltage drop, which made the friction redundant (pruned); the
    three rounds were spent and the offset, which passes every rule, never had its own."""
    _named_right(*_randomised(196, tmp_path))


def test_a_twin_picked_first_gives_way_to_the_pair_that_is_there(tmp_path):
    """Randomised draw 275 (seed 15): viscous friction beside softer springs (k 0.87).  Coulomb friction
    fits best alone; the rounds from round one's other candidates find the pair that is there."""
    _named_right(*_randomised(275, tmp_path))


def test_an_adopted_effect_is_tried_against_candidates_an_earlier_round_passed(tmp_path):
    """Randomised draw 37 (seed 15): a voltage drop beside stiffer springs.  Round one took the springs,
    round two a small viscous friction; the voltage drop, which passed round one, was not among the
    three round two assessed, so it was never tried in the friction's place."""
    _named_right(*_randomised(37, tmp_path))


def test_a_sensor_offset_is_not_asked_to_remove_the_floors_own_error(tmp_path):
    """Randomised draw 242 (seed 15): backlash and a 0.11 A offset on a 322-sample segment after a board
    reset.  The current's floor is itself estimated, to ~sqrt(3/n) (10 % here): the true model left 0.18
    noise variances of "structure", and the offset, removing 0.21 of 0.43, missed the held-out half."""
    _named_right(*_randomised(242, tmp_path))


def test_an_effect_that_moves_the_angle_too_is_asked_for_all_the_currents_structure(tmp_path):
    """Randomised draw 179 (seed 15): a hot winding (outside the catalogue).  A voltage drop removes the
    current's little structure and a fifth of the angle's; excusing it the floor's error, as a sensor
    offset is, named it."""
    draw, doc = _randomised(179, tmp_path)
    assert draw.outside and doc["verdict"] == "unexplained" and doc["effects"] == []


def test_a_segment_opening_at_rest_after_a_reset_without_dir(tmp_path):
    """Without a dir column, a segment after a board reset opens with the motor off while the pinion
    still creeps on its springs (here 0.02 rad/s, 0.17 rad from their rest after a 10 s gap): the motor's
    start is the drive's, not the creep's first count, and the counter's offset is pinned by the whole
    segment, not by the first seconds (where it reads like where the springs hold the pinion).  Both
    wrong, this clean segment left 33,000 noise variances of angle structure."""
    from pipeline.derive.stage import derive_run
    from pipeline.discover.stage import discover_run
    from pipeline.ingest.stage import ingest_recording
    from pipeline.rig.recording import RigSetup, make_recording, write_recording
    from pipeline.rig.serial import Artefacts

    setup = RigSetup(duration_s=30.0, artefacts=Artefacts(dir_column=False, reset_after_s=8.0, reset_gap_s=10.0))
    rec = make_recording(setup, seed=3)
    assert abs(rec.truth_meta["segments"][1]["theta_ref_rad"]) > 0.1
    write_recording(rec, tmp_path / "raw", "creep")
    _, after = ingest_recording(tmp_path / "raw" / "creep.csv", tmp_path / "processed").runs
    derive_run(after)
    _, doc = discover_run(after)
    assert doc["verdict"] == "none" and not doc["effects"], (doc["effects"], doc["structure_after"])
    assert abs(doc["motor_start_shift_samples"]["base"]) <= 2       # the onset found is the drive's


@pytest.mark.parametrize("index, expected", [(226, {}), (31, {"spring_stiffness": 1.2829}),
                                             (121, {"spring_stiffness": 1.2231})])
def test_after_a_reset_the_command_is_decided_in_the_counters_frame_and_on_the_whole_run(tmp_path, index, expected):
    """Randomised draws (seed 15), the segment after their board reset.  226 (clean, dir logged, 5
    rows lost) and 31 (stiffer springs, no dir): a row lost at a reversal was decided by the model's
    guard, in the springs' frame, 0.09 and 0.03 rad off the counter's the sketch decided in, which
    drove a reversed pulse.  121 (stiffer springs, no dir): the motor's onset, chosen on the first
    phase where the start absorbs a sample's error, came out one sample early; on the whole run it is
    not.  Each left hundreds of noise variances in the angle."""
    draw, doc = _randomised(index, tmp_path, after_reset=True)
    assert doc["verdict"] == ("explained" if expected else "none"), (doc["effects"], doc["structure_after"])
    found = {e["name"]: next(iter(e["parameters"].values())) for e in doc["effects"]}
    assert found.keys() == expected.keys()
    for name, value in expected.items():
        assert found[name] == pytest.approx(value, rel=0.01)


def test_a_start_re_estimated_for_another_onset_keeps_the_sensor_offset(tmp_path):
    """Without dir the motor's onset is a nuisance: a model is replayed under shifted onsets, each from
    a start estimated for it, under the model's own sensor offset (not none: the start's current
    would take some of the offset up)."""
    import numpy as np
    from dataclasses import replace

    from pipeline.discover.measurement import measurement_from_kinematics
    from pipeline.rig.serial import Artefacts
    from tests.discover.synthetic import rig_kinematics

    offset = make_effect("current_sensor_offset", {"I0": 0.15})
    kin, cfg, _ = rig_kinematics((offset,), seed=2, work=tmp_path, duration_s=8.0,
                                 artefacts=Artefacts(dir_column=False))
    meas = measurement_from_kinematics(kin, cfg, "r")
    assert meas.onset is not None                                   # a motor-off lead-in, the onset inferred
    spec = meas.spec((offset,))
    plant = replace(spec, I0=0.0)
    earlier = meas.with_onset(meas.onset - 2)
    replayed = meas.replay(plant, meas.x0(spec), earlier)           # as the Evaluator replays a shifted onset
    own = meas.x0(spec, earlier)
    assert own.current_offset == 0.15
    assert np.array_equal(replayed.current, meas.run(own, plant, earlier).current)


def test_an_automatic_current_zero_off_by_its_own_error_is_not_named_an_offset(tmp_path):
    """Randomised draw 247 (seed 15): a clean rig whose current zero ingest reads off 11 rest readings
    (zero_v = "auto").  Their noise averages 47 mA off the part's true zero, 2 of that mean's standard
    errors (the recording's noise floor over 11), which every later current then carries: an offset
    really in the data, but one the zero's own error explains, so it is not named."""
    draw, doc = _randomised(247, tmp_path)
    assert not draw.effects and draw.setup.zero_v == "auto"
    assert doc["verdict"] == "none" and doc["effects"] == []
    offset = next(c for c in doc["candidates"] if c["name"] == "current_sensor_offset")
    assert abs(offset["parameters"]["I0"]) > 0.03 and not offset.get("accepted")


def test_a_sensor_offset_is_not_named_beside_an_angle_the_model_cannot_explain(tmp_path):
    """Randomised draw 78 (seed 15), the segment after its board reset: a hot winding (outside the
    catalogue), 7 s.  The smaller current, over unequal times in each direction, has a mean that a
    sensor offset of 41 mA removes, while the angle keeps 10,000 noise variances of structure: the
    offset was named."""
    draw, doc = _randomised(78, tmp_path, after_reset=True)
    assert draw.outside and doc["verdict"] == "unexplained" and doc["effects"] == []
    assert "current_sensor_offset" in doc["pruned"]["effects"]             # passed its round, then dropped


def test_a_load_torque_is_found_on_the_segment_whose_counter_started_at_the_springs_rest(tmp_path):
    """Randomised draw 264 (seed 15): a constant load torque, a board reset after 92 samples, 140 after
    it.  After the reset the counter restarts wherever the pinion is, and a torque only moves where the
    springs rest in that count (the segment tells Tl - k * offset, not Tl): discovered on the longer,
    later segment it was not named.  The first segment is taken unless a later one is twice as long."""
    _named_right(*_randomised(264, tmp_path))


def test_a_pair_restarts_the_rounds_when_round_one_adopts_nothing(tmp_path):
    """Randomised draw 271 (seed 15): a 0.035 rad backlash and a 20 ms loop delay, no ``dir``.  Alone, the
    loop delay (fitted to 9 %) removes 72 % of the structure but its switch pattern grows beside the
    backlash, and nothing else passes; a pair of round one's candidates was tried only after an effect
    was adopted, so the recording was ``unexplained`` with nothing named."""
    _named_right(*_randomised(271, tmp_path))


@pytest.mark.parametrize("report", ['[]', '{"segments": [{"run": "r", "index": "2", "current_zero": []}]}',
                                    '{"segments": [{"run": "r", "current_zero": {"method": "dir == 0"}}]}', 'not json'])
def test_a_hand_edited_ingest_report_reads_as_no_reset_and_no_automatic_zero(tmp_path, report):
    """What discovery reads from a run's ingest report is context: an unreadable or mangled entry is
    taken as "first segment, configured zero", never a traceback."""
    from pipeline.discover.stage import after_board_reset, zero_samples
    from pipeline.runs import RunPaths, ingest_segment

    paths = RunPaths(tmp_path / "r")
    paths.root.mkdir()
    paths.ingest_report.write_text(report, encoding="utf-8")
    segment = ingest_segment(paths)
    assert not after_board_reset(segment) and zero_samples(segment) == {}


def test_an_interval_holds_the_start_where_the_estimate_does(tmp_path):
    """Randomised draw 277 (seed 15): a backlash beside a heavier rack, on a ridge where a rack 0.2 %
    lighter takes a gap 27 % wider.  The final model's start is refined on the whole run; moving the gap
    with the start estimated afresh from the first seconds compared two estimates of the start 1e-3
    apart in the gap and reported [0.0562, 0.0564] with the truth at 0.044.  Held, with the start's
    states as nuisances, the interval holds the truth and stays within the ridge."""
    draw, doc = _randomised(277, tmp_path)
    truth = {e.name: next(iter(e.parameters.values())) for e in draw.effects}
    for e in doc["effects"]:
        (lo, hi), = e["interval"].values()
        value, = e["parameters"].values()
        assert lo <= truth[e["name"]] <= hi, (e["name"], lo, hi, truth[e["name"]])
        assert hi - lo < 0.8 * value, e["name"]


def test_after_a_reset_the_counter_offset_is_estimated_again_under_the_model_found(tmp_path):
    """Randomised draw 28 (seed 15): viscous friction, backlash and a sensor offset, discovered on the segment
    after a board reset.  The counter's offset, held from the base model's fit through the rounds, left
    146 noise variances of angle structure under the full model; judged at it, backlash and the offset
    were eliminated again and the verdict was ``unexplained``.  Estimated again under the model the
    rounds found, the three are kept and the angle is within its floor."""
    _named_right(*_randomised(28, tmp_path, after_reset=True))
