"""The .rrd read back with rerun's own reader (rerun.chunk.RrdReader), strict mode on."""

import os
import subprocess
from collections import Counter

import numpy as np
import pytest
from rerun.chunk import RrdReader

from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.validate.compare import compare, simulate_both, switch_indices
from pipeline.validate.rerun_log import (COINCIDENCE_TOL, VIEW_NAMES, coincidence, event_rows, guard_crossings,
                                         rerun_executable, verify_rrd, verify_rrds, write_rrd)
from tests.validate.synthetic import synthetic_kinematics

SPEC = default_config().plant_spec()
# A rig with a loop delay the model lacks: the closed loop switches one sample late, so it departs from the replay.
DELAYED = default_config().plant_spec(extra_effects=(make_effect("loop_delay", {"Td": 0.05}),))


def _write(folder, name, kin, spec=SPEC):
    sims = simulate_both(spec, kin)
    path = folder / f"{name}.rrd"
    write_rrd(path, name, kin, sims, compare(kin, spec, sims), spec.guard_rad, period=spec.period_s)
    return path, kin, sims


@pytest.fixture(scope="module")
def rrd(tmp_path_factory):
    assert os.environ.get("RERUN_STRICT") == "1"
    kin = synthetic_kinematics(SPEC, current_noise_a=0.02)
    kin["current_smooth_a"] = np.convolve(kin["current_a"], np.ones(5) / 5, mode="same")
    return _write(tmp_path_factory.mktemp("rrd"), "synth", kin)


@pytest.fixture(scope="module")
def departing(tmp_path_factory):
    kin = synthetic_kinematics(DELAYED, current_noise_a=0.02)
    return _write(tmp_path_factory.mktemp("rrd"), "delayed", kin)


def _chunks(path):
    return RrdReader(path).stream().to_chunks()


def _rows(chunks):
    rows = Counter()
    for ch in chunks:
        if not ch.is_static:
            rows[ch.entity_path] += ch.num_rows
    return rows


def _scalars(chunks, entity):
    """The entity's scalars, one row per sample, one column per instance (series)."""
    values = []
    for ch in chunks:
        if ch.entity_path == entity and not ch.is_static:
            values += ch.to_record_batch().column("Scalars:scalars").to_pylist()
    return np.array(values)


def _static(chunks, entity, column):
    for ch in chunks:
        if ch.entity_path == entity and ch.is_static:
            batch = ch.to_record_batch()
            if column in batch.schema.names:
                return batch.column(column).to_pylist()[0]
    return None


def test_coinciding_ways_are_one_series_with_the_measurement_on_top(rrd):
    path, kin, sims = rrd
    assert coincidence(sims["closed_loop"], sims["replay"]) <= COINCIDENCE_TOL
    reader = RrdReader(path)
    assert [r.recording_id for r in reader.recordings()] == ["synth"]
    chunks = reader.stream().to_chunks()
    rows = _rows(chunks)
    n = len(kin)
    for sig in ("theta", "omega", "current"):
        assert rows[f"/signals/{sig}"] == n and rows[f"/residuals/{sig}"] == n
        assert _scalars(chunks, f"/signals/{sig}").shape == (n, 2)
        assert _static(chunks, f"/signals/{sig}", "SeriesLines:names") == ["closed loop = replay", "measured"]
        assert _static(chunks, f"/residuals/{sig}", "SeriesLines:names") == ["measured - model"]
    assert rows["/signals/theta/guards"] == 2           # a straight line: its two ends
    assert _static(chunks, "/signals/theta/guards", "SeriesLines:names") == ["guards +/-0.942 rad"] * 2
    d = kin["dir"].to_numpy()
    n_switch = len(switch_indices(d))
    assert rows["/signals/theta/switches_logged"] == n_switch
    assert rows["/mode/logged"] == n_switch + 1
    assert "/mode/closed_loop" not in rows and "/signals/theta/switches_closed_loop" not in rows
    n_cross = len(guard_crossings(kin["theta_rad"].to_numpy(), SPEC.guard_rad))
    assert rows["/events"] == n_switch + n_cross
    levels = [v for ch in chunks if ch.entity_path == "/events"
              for v in ch.to_record_batch().column("TextLog:level").to_pylist()]
    assert sorted({x[0] for x in levels}) == ["INFO"]                # a clean run warns of nothing
    text = _static(chunks, "/stats", "TextDocument:text")[0]
    assert "Closed loop = replay" in text and "| theta [rad] | replay |" in text


def test_departing_ways_keep_both_series_lanes_and_residuals(departing):
    path, kin, sims = departing
    assert coincidence(sims["closed_loop"], sims["replay"]) is None
    chunks = _chunks(path)
    rows = _rows(chunks)
    assert _static(chunks, "/signals/theta", "SeriesLines:names") == ["closed loop", "replay", "measured"]
    assert _static(chunks, "/residuals/theta", "SeriesLines:names") == ["measured - closed loop", "measured - replay"]
    assert rows["/mode/closed_loop"] == len(switch_indices(sims["closed_loop"].dir)) + 1
    assert rows["/signals/theta/switches_closed_loop"] == len(switch_indices(sims["closed_loop"].dir))
    np.testing.assert_allclose(_scalars(chunks, "/residuals/omega")[:, 1],
                               kin["omega_rad_s"].to_numpy() - sims["replay"].omega)
    assert "Closed loop = replay" not in _static(chunks, "/stats", "TextDocument:text")[0]
    # no smoothed current in this table: the portrait's measured curve is the raw one, and says so
    assert _static(chunks, "/trajectory/legend", "Points3D:labels") == ["closed loop", "replay", "measured"]


def test_values_round_trip(rrd):
    path, kin, sims = rrd
    chunks = _chunks(path)
    np.testing.assert_allclose(_scalars(chunks, "/signals/theta")[:, 1], kin["theta_rad"].to_numpy())
    np.testing.assert_allclose(_scalars(chunks, "/signals/theta")[:, 0], sims["closed_loop"].theta)
    np.testing.assert_allclose(_scalars(chunks, "/signals/current")[:, 0], sims["replay"].current_measured)
    np.testing.assert_allclose(_scalars(chunks, "/residuals/omega")[:, 0],
                               kin["omega_rad_s"].to_numpy() - sims["closed_loop"].omega)
    assert list(_scalars(chunks, "/signals/theta/guards")[0]) == [SPEC.guard_rad, -SPEC.guard_rad]


def test_coincidence_tolerance_and_commands():
    kin = synthetic_kinematics(SPEC)
    sims = simulate_both(SPEC, kin)
    cl, rp = sims["closed_loop"], sims["replay"]
    assert coincidence(cl, cl) == 0.0
    from dataclasses import replace

    nudged = replace(rp, theta=rp.theta * (1 + 1e-7))
    assert coincidence(cl, nudged) > COINCIDENCE_TOL                # visible at a zoom: drawn apart
    flipped = replace(rp, dir=np.where(np.arange(len(rp.dir)) == 100, -rp.dir, rp.dir))
    assert coincidence(cl, flipped) is None


def test_warnings_only_where_the_controller_rule_breaks():
    kin = synthetic_kinematics(SPEC)
    sims = simulate_both(SPEC, kin)
    t, theta, d = kin["t_s"].to_numpy(), kin["theta_rad"].to_numpy(), kin["dir"].to_numpy().copy()
    clean = event_rows(t, theta, d, sims, SPEC.guard_rad, SPEC.period_s)
    assert {level for _t, _s, level in clean} == {"INFO"}
    assert all(text.startswith(f"t = {tk:7.3f} s") for tk, text, _ in clean)
    sw = switch_indices(d)
    late = d.copy()
    late[sw[3]:sw[3] + 2] = late[sw[3] - 1]           # the logged command reverses two samples late
    warned = [text for _t, text, level in event_rows(t, theta, late, sims, SPEC.guard_rad, SPEC.period_s)
              if level == "WARN"]
    assert len(warned) == 1 and "the logged command did not reverse" in warned[0]
    early = d.copy()
    m = (sw[5] + sw[6]) // 2
    early[m:sw[6] + 1] = -d[m]                         # a reversal mid-swing, held to the next guard
    warned = [text for _t, text, level in event_rows(t, theta, early, sims, SPEC.guard_rad, SPEC.period_s)
              if level == "WARN"]
    assert any("inside the guards" in w for w in warned)


def test_phase_portrait_scale_is_below_the_views_origin_and_uses_the_smoothed_current(rrd):
    path, kin, _ = rrd
    chunks = _chunks(path)
    assert _static(chunks, "/trajectory", "Transform3D:scale") is None     # the origin's own transform is ignored
    extent = 1.0 / np.array(_static(chunks, "/trajectory/scaled", "Transform3D:scale")[0])
    assert extent[2] >= np.abs(kin["theta_rad"]).max()           # theta axis spans the data
    assert extent[1] < 10 * np.abs(kin["omega_rad_s"]).max()      # and is not dwarfed by another axis
    strip = np.array(_static(chunks, "/trajectory/scaled/measured_smoothed_current", "LineStrips3D:strips")[0])
    np.testing.assert_allclose(strip[:, 0], kin["current_smooth_a"], rtol=1e-6, atol=1e-7)
    half = np.array(_static(chunks, "/trajectory/scaled/guard_planes", "Boxes3D:half_sizes"))
    np.testing.assert_allclose(half[:, :2] / extent[:2], 1.0, rtol=1e-6)   # squares 2 x 2 once scaled
    assert _static(chunks, "/trajectory/guard_labels", "Points3D:colors")[0] & 0xFF == 0xFF   # opaque labels
    assert _static(chunks, "/trajectory/legend", "Points3D:labels") == ["closed loop = replay",
                                                                      "measured (smoothed current)"]
    labels = _static(chunks, "/trajectory/axis_labels", "Points3D:labels")
    assert any("[A]" in s for s in labels) and any("[rad/s]" in s for s in labels)


def test_blueprint_is_saved_with_every_view_and_opens_at_the_end(rrd):
    path, _, _ = rrd
    from pipeline.validate.rerun_blueprint import run_blueprint, tick_range, view_ids

    names, play, ranges = set(), [], {}
    reader = RrdReader(path)
    assert len(reader.blueprints()) == 1
    for ch in reader.stream(store=reader.blueprints()[0]).to_chunks():
        rb = ch.to_record_batch()
        if "ViewBlueprint:display_name" in rb.schema.names:
            names.update(v[0] for v in rb.column("ViewBlueprint:display_name").to_pylist() if v)
        if "TimePanelBlueprint:play_state" in rb.schema.names:
            play += rb.column("TimePanelBlueprint:play_state").to_pylist()
        if "ScalarAxis:range" in rb.schema.names:
            ranges[ch.entity_path.split("/")[2]] = rb.column("ScalarAxis:range").to_pylist()[0][0]
    assert names == set(VIEW_NAMES)
    assert play == [[3]]           # PlayState.Following: the cursor at the recording's end (viewer test)
    by_name = {name: ranges.get(view_id) for name, view_id in view_ids(run_blueprint).items()}
    _, kin, sims = rrd
    residual = np.abs(kin["current_a"].to_numpy() - sims["replay"].current_measured).max()
    assert by_name["residual current [A]"] == list(tick_range(residual))
    lo, hi = by_name["theta [rad]"]
    peak = max(np.abs(kin["theta_rad"]).max(), *(np.abs(s.theta).max() for s in sims.values()))
    assert lo == -hi and peak < hi <= 1.03 * (peak + 0.1)          # the data, no band kept for a legend
    legend_low, _ = by_name["legend"]
    assert legend_low > 10 * peak                                   # the legend's view shows no data
    assert by_name["omega [rad/s]"] is None


def test_two_renders_of_a_run_compare_equal_and_another_run_does_not(rrd, departing, tmp_path):
    path, kin, _ = rrd
    again, _, _ = _write(tmp_path, "synth", kin)
    compare_ = [rerun_executable(), "rrd", "compare"]
    assert subprocess.run([*compare_, str(path), str(again)], capture_output=True).returncode == 0
    other = subprocess.run([*compare_, str(path), str(departing[0])], capture_output=True)
    assert other.returncode != 0


def test_written_file_verifies_and_no_temporary_is_left(rrd):
    path, _, _ = rrd
    verify_rrd(path)
    assert [p.name for p in path.parent.iterdir()] == [path.name]


def test_a_torn_file_fails_verification(tmp_path):
    from pipeline.errors import PdrError

    bad = tmp_path / "torn.rrd"
    bad.write_bytes(b"RRF2" + bytes(100))
    with pytest.raises(PdrError, match="rerun rrd verify failed"):
        verify_rrd(bad)


def test_batch_verification_names_only_the_torn_files(rrd, tmp_path):
    good, _, _ = rrd
    torn = tmp_path / "torn.rrd"
    torn.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    assert verify_rrds([good, good]) == {}
    failed = verify_rrds([good, torn, good])
    assert list(failed) == [torn] and "rerun rrd verify failed" in failed[torn]


def test_residual_ranges_hold_the_data_and_a_labelled_gridline():
    from pipeline.validate.rerun_blueprint import tick_range

    for peak in np.geomspace(1e-4, 50.0, 301):
        lo, hi = tick_range(peak)
        assert lo == -hi and hi >= peak
        step = 10.0 ** np.floor(np.log10(hi))              # the largest power of ten inside
        assert 2 * hi / step <= 9.0 + 1e-9, peak          # few enough gridlines for the viewer to label
        assert peak / hi >= 0.39                           # and the data fill much of the plot
    assert tick_range(3.5) == (-3.85, 3.85) and tick_range(0.04) == (-0.044, 0.044)      # not +/-10, +/-0.115
    assert tick_range(0.0) is None and tick_range(float("nan")) is None
