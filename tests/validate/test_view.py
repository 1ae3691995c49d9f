"""`pdr view`: no display, side by side, and the web viewer served over HTTP (localhost only)."""

import re
import signal
import socket
import subprocess
import sys
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.validate.stage import validate_run
from pipeline.validate.view import NO_DISPLAY, display_available, side_by_side_rrd
from tests.validate.net import default_sigint, free_port_pair
from tests.validate.synthetic import synthetic_kinematics, synthetic_run

PDR = str(Path(sys.executable).with_name("pdr"))      # the console command, as a user runs it


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    """Two validated runs: a clean one and one whose rig has a loop delay the model lacks."""
    root = tmp_path_factory.mktemp("view") / "processed"
    delayed = default_config().plant_spec(extra_effects=(make_effect("loop_delay", {"Td": 0.05}),))
    for name, kin in (("clean", None), ("delayed", synthetic_kinematics(delayed, current_noise_a=0.02))):
        validate_run(synthetic_run(root, name, kin=kin), png=False)
    return root


def test_display_detection():
    assert not display_available({}, "linux")
    assert not display_available({"DISPLAY": ""}, "linux")
    assert display_available({"DISPLAY": ":0"}, "linux")
    assert display_available({"WAYLAND_DISPLAY": "wayland-0"}, "linux")
    assert display_available({}, "darwin") and display_available({}, "win32")


def test_without_a_display_one_line_says_to_use_web(processed, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    result = subprocess.run([PDR, "view", "clean", "--processed", str(processed)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode != 0
    assert result.stderr.strip().splitlines() == [f"pdr: error: {NO_DISPLAY}"]
    assert "pdr view --web" in NO_DISPLAY and "Traceback" not in result.stderr + result.stdout


def test_side_by_side_recording_holds_every_run_under_its_name(processed, tmp_path):
    runs = {name: processed / name / f"{name}.rrd" for name in ("clean", "delayed")}
    reader = RrdReader(side_by_side_rrd(runs, tmp_path / "both.rrd"))
    chunks = reader.stream().to_chunks()
    paths = {ch.entity_path for ch in chunks}
    for name, path in runs.items():
        own = {ch.entity_path for ch in RrdReader(path).stream().to_chunks()} - {"/__properties"}
        assert {f"/runs/{name}{p}" for p in own} <= paths
        theta = [v for ch in chunks if ch.entity_path == f"/runs/{name}/signals/theta" and not ch.is_static
                 for v in ch.to_record_batch().column("Scalars:scalars").to_pylist()]
        original = [v for ch in RrdReader(path).stream().to_chunks()
                    if ch.entity_path == "/signals/theta" and not ch.is_static
                    for v in ch.to_record_batch().column("Scalars:scalars").to_pylist()]
        np.testing.assert_array_equal(theta, original)
    views = set()
    for ch in reader.stream(store=reader.blueprints()[0]).to_chunks():
        rb = ch.to_record_batch()
        if "ViewBlueprint:display_name" in rb.schema.names:
            views.update(v[0] for v in rb.column("ViewBlueprint:display_name").to_pylist() if v)
    assert {"clean: theta [rad]", "delayed: theta [rad]", "clean: mode",
            "delayed: trajectory (I, w, theta)"} <= views


def _blueprint_views(reader) -> dict[str, dict]:
    """Display name -> the view's blueprint components (origin, its y range when it has one)."""
    by_id: dict[str, dict] = {}
    for ch in reader.stream(store=reader.blueprints()[0]).to_chunks():
        rb = ch.to_record_batch()
        view_id = ch.entity_path.split("/")[2] if ch.entity_path.startswith("/view/") else None
        if view_id is None:
            continue
        entry = by_id.setdefault(view_id, {})
        for column, key in (("ViewBlueprint:display_name", "name"), ("ViewBlueprint:space_origin", "origin"),
                            ("ScalarAxis:range", "range")):
            if column in rb.schema.names:
                entry[key] = rb.column(column).to_pylist()[0][0]
    return {v["name"]: v for v in by_id.values() if "name" in v}


def _series_names(reader, entity: str) -> list[str]:
    return [n for ch in reader.stream().to_chunks() if ch.entity_path == entity and ch.is_static
            for n in (ch.to_record_batch().column("SeriesLines:names").to_pylist()[0] or [])]


def test_side_by_side_gives_each_run_its_legend_residuals_and_statistics(processed, tmp_path):
    """Each column's legend shows its own run's series (the clean run's "closed loop = replay", the
    delayed run's closed loop and replay apart), each run has its residuals and statistics, and the
    angle's range is the data's, not a band for a legend."""
    runs = {name: processed / name / f"{name}.rrd" for name in ("clean", "delayed")}
    reader = RrdReader(side_by_side_rrd(runs, tmp_path / "both.rrd"))
    views = _blueprint_views(reader)
    for name in runs:
        assert views[f"{name}: legend"]["origin"] == f"/runs/{name}/signals/theta"
        for sig, unit in (("theta", "rad"), ("omega", "rad/s"), ("current", "A")):
            assert views[f"{name}: residual {sig} [{unit}]"]["origin"] == f"/runs/{name}/residuals/{sig}"
        assert views[f"{name}: statistics"]["origin"] == f"/runs/{name}/stats"
    assert "closed loop = replay" in _series_names(reader, "/runs/clean/signals/theta")
    assert {"closed loop", "replay"} <= set(_series_names(reader, "/runs/delayed/signals/theta"))
    peak = max(np.nanmax(np.abs(np.asarray(v, dtype=float))) for ch in reader.stream().to_chunks()
               if ch.entity_path.endswith("/signals/theta") and not ch.is_static
               for v in ch.to_record_batch().column("Scalars:scalars").to_pylist())
    lo, hi = views["clean: theta [rad]"]["range"]
    assert lo == -hi and peak < hi <= 1.03 * (peak + 0.1)


@pytest.mark.slow
def test_web_serves_the_viewer_page_and_the_side_by_side_recording(processed, tmp_path):
    port = free_port_pair()
    proc = subprocess.Popen([PDR, "view", "--web", "--port", str(port),
                             "--processed", str(processed), "clean", "delayed"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    try:
        line = proc.stdout.readline()
        match = re.search(r"(http://127\.0\.0\.1:(\d+)/\?url=\S+)", line)
        assert match and int(match.group(2)) == port, line
        page = urllib.request.urlopen(match.group(1), timeout=20)
        html = page.read().decode()
        assert page.status == 200 and "<html>" in html and "Rerun" in html
        recording_url = urllib.parse.parse_qs(urllib.parse.urlparse(match.group(1)).query)["url"][0]
        assert recording_url.startswith(f"http://127.0.0.1:{port + 1}/")
        response = urllib.request.urlopen(recording_url, timeout=20)
        assert response.headers["Access-Control-Allow-Origin"] == "*"       # the viewer page fetches it cross-origin
        fetched = tmp_path / "fetched.rrd"
        fetched.write_bytes(response.read())
        reader = RrdReader(fetched)
        assert [r.recording_id for r in reader.recordings()] == ["side-by-side:clean+delayed"]
        assert len(reader.blueprints()) == 1
        assert {"/runs/clean/signals/theta", "/runs/delayed/trajectory/scaled"} <= {
            ch.entity_path for ch in reader.stream().to_chunks()}
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
    assert proc.returncode == 0, proc.stderr.read()
    for p in (port, port + 1):                  # both servers stopped with the command
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", p)) != 0
