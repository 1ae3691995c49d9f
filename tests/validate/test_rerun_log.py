"""The .rrd read back with rerun's own reader (rerun.chunk.RrdReader), strict mode on."""

import os
from collections import Counter

import numpy as np
import pytest
from rerun.chunk import RrdReader

from pipeline.config import default_config
from pipeline.validate.compare import compare, simulate_both, switch_indices
from pipeline.validate.rerun_log import VIEW_NAMES, guard_crossings, verify_rrd, verify_rrds, write_rrd
from tests.validate.synthetic import synthetic_kinematics

SPEC = default_config().plant_spec()


@pytest.fixture(scope="module")
def rrd(tmp_path_factory):
    assert os.environ.get("RERUN_STRICT") == "1"
    kin = synthetic_kinematics(SPEC, current_noise_a=0.02)
    sims = simulate_both(SPEC, kin)
    path = tmp_path_factory.mktemp("rrd") / "synth.rrd"
    write_rrd(path, "synth", kin, sims, compare(kin, SPEC, sims), SPEC.guard_rad)
    return path, kin, sims


def _scalars(chunks, entity):
    """The entity's scalars, one row per sample, one column per instance (series)."""
    values = []
    for ch in chunks:
        if ch.entity_path == entity and not ch.is_static:
            values += ch.to_record_batch().column("Scalars:scalars").to_pylist()
    return np.array(values)


def _series_names(chunks, entity):
    for ch in chunks:
        if ch.entity_path == entity and ch.is_static:
            batch = ch.to_record_batch()
            if "SeriesLines:names" in batch.schema.names:
                return batch.column("SeriesLines:names").to_pylist()[0]
    return None


def test_expected_entities_and_row_counts(rrd):
    path, kin, sims = rrd
    reader = RrdReader(path)
    assert [r.recording_id for r in reader.recordings()] == ["synth"]
    chunks = reader.stream().to_chunks()
    rows = Counter()
    for ch in chunks:
        if not ch.is_static:
            rows[ch.entity_path] += ch.num_rows
    n = len(kin)
    for sig in ("theta", "omega", "current"):
        assert rows[f"/signals/{sig}"] == n
        assert rows[f"/residuals/{sig}"] == n
        assert _scalars(chunks, f"/signals/{sig}").shape == (n, 3)          # one instance per series
        assert _series_names(chunks, f"/signals/{sig}") == ["measured", "closed loop", "replay"]
        assert _series_names(chunks, f"/residuals/{sig}") == ["measured - closed loop", "measured - replay"]
    assert rows["/signals/theta/guard_upper"] == 2           # a straight line: its two ends
    d = kin["dir"].to_numpy()
    n_switch = len(switch_indices(d))
    assert rows["/signals/theta/switches_logged"] == n_switch
    assert rows["/mode/logged"] == n_switch + 1
    n_cross = len(guard_crossings(kin["theta_rad"].to_numpy(), SPEC.guard_rad))
    assert rows["/events"] == n_switch + len(switch_indices(sims["closed_loop"].dir)) + n_cross
    static = {ch.entity_path for ch in chunks if ch.is_static}
    assert {"/trajectory", "/trajectory/measured", "/trajectory/closed_loop", "/trajectory/guard_planes",
            "/trajectory/axes", "/stats"} <= static


def test_values_round_trip(rrd):
    path, kin, sims = rrd
    chunks = RrdReader(path).stream().to_chunks()
    np.testing.assert_allclose(_scalars(chunks, "/signals/theta")[:, 0], kin["theta_rad"].to_numpy())
    np.testing.assert_allclose(_scalars(chunks, "/signals/theta")[:, 1], sims["closed_loop"].theta)
    np.testing.assert_allclose(_scalars(chunks, "/signals/current")[:, 2], sims["replay"].current_measured)
    np.testing.assert_allclose(_scalars(chunks, "/residuals/omega")[:, 0],
                               kin["omega_rad_s"].to_numpy() - sims["closed_loop"].omega)
    guard = _scalars(chunks, "/signals/theta/guard_lower")
    assert list(guard[:, 0]) == [-SPEC.guard_rad] * 2


def test_trajectory_is_scaled_to_fill_the_view_and_stats_are_text(rrd):
    path, kin, _ = rrd
    chunks = RrdReader(path).stream().to_chunks()
    by_path = {ch.entity_path: ch.to_record_batch() for ch in chunks if ch.is_static}
    scale = by_path["/trajectory"].column("Transform3D:scale").to_pylist()[0][0]
    extent = 1.0 / np.array(scale)
    assert extent[2] >= np.abs(kin["theta_rad"]).max()           # theta axis spans the data
    assert extent[1] < 10 * np.abs(kin["omega_rad_s"]).max()      # and is not dwarfed by another axis
    labels = by_path["/trajectory/axes"].column("Arrows3D:labels").to_pylist()[0]
    assert any("[A]" in s for s in labels) and any("[rad/s]" in s for s in labels)
    text = by_path["/stats"].column("TextDocument:text").to_pylist()[0][0]
    assert "overshoot" in text and "| theta [rad] | replay |" in text


def test_blueprint_is_saved_with_every_view(rrd):
    path, _, _ = rrd
    reader = RrdReader(path)
    blueprints = reader.blueprints()
    assert len(blueprints) == 1
    names = set()
    for ch in reader.stream(store=blueprints[0]).to_chunks():
        rb = ch.to_record_batch()
        if "ViewBlueprint:display_name" in rb.schema.names:
            names.update(v[0] for v in rb.column("ViewBlueprint:display_name").to_pylist() if v)
    assert names == set(VIEW_NAMES)


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
