"""The real Rerun viewer, headless, opens a run's .rrd and discovery.rrd on their saved layouts.

Needs a Vulkan driver: Mesa's software one (lavapipe, Debian's mesa-vulkan-drivers), which CI installs
(``.ci/run``); on a machine without it this module is skipped with that reason in the summary, and
``make test`` never installs anything.  The viewer is bound to
127.0.0.1 on a free port (the CLI's default bind is 0.0.0.0, so the spawned
executable is a two-line wrapper that adds ``--bind 127.0.0.1``).

Colours are checked in both of the viewer's schemes: ``pdr view --web`` is
opened in headless Chromium (``tests.validate.browser``) with the page's
``prefers-color-scheme`` emulated light and dark, at 1600 x 1000, and the
measured line's contrast against the plots' background is read from the
screenshots.

The 3-D phase portrait is checked on its pixels: the guard planes (their red
is found by colour) must lie inside the view from the saved camera, and seen
from straight above they must be squares -- which they are only when the
view applies the scale that maps each axis's extent to +/-1.  The same check
on a copy of the file with the scale moved onto the view's origin (the viewer
then ignores it) must fail, so the check is known to be able to.
"""

import copy
import glob
import os
import time

import numpy as np
import pytest
import rerun as rr
from PIL import Image
from rerun.chunk import RrdReader
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.model.effects import make_effect
from pipeline.runs import RunPaths
from pipeline.validate.rerun_blueprint import DISCOVERY_VIEW_NAMES
from pipeline.validate.rerun_io import rerun_executable, save_with_blueprint
from pipeline.validate.palette import RGB, contrast_ratio, relative_luminance
from pipeline.validate.rerun_log import VIEW_NAMES
from pipeline.validate.view import serve_web
from tests.validate.browser import Browser, wait_for
from pipeline.validate.stage import validate_run
from tests.discover.synthetic import rig_kinematics
from tests.validate.net import free_port, free_port_pair

SCREENSHOT_DIR_ENV = "PDR_VIEWER_SCREENSHOT_DIR"   # keep the screenshots somewhere to look at
TOP_DOWN = {"kind": "Orbital", "position": [0.0, 0.0, 6.0], "look_target": [0.0, 0.0, 0.0], "eye_up": [0.0, 1.0, 0.0]}

LAVAPIPE = glob.glob("/usr/share/vulkan/icd.d/lvp_icd.*.json")
pytestmark = [pytest.mark.viewer, pytest.mark.slow, pytest.mark.long,
              pytest.mark.skipif(not LAVAPIPE, reason="no software Vulkan driver (lavapipe) for the headless "
                                 "viewer: apt-get install mesa-vulkan-drivers (.ci/run does)")]


def _local_rerun(folder) -> str:
    wrapper = folder / "rerun"
    wrapper.write_text(f'#!/bin/sh\nexec "{rerun_executable()}" --bind 127.0.0.1 "$@"\n')
    wrapper.chmod(wrapper.stat().st_mode | 0o100)
    return str(wrapper)


def _wait(predicate, timeout: float = 30.0, step: float = 0.2):
    end = time.monotonic() + timeout
    while True:
        try:
            value = predicate()
            if value:
                return value
        except Exception:                       # the viewer is still starting up
            if time.monotonic() > end:
                raise
        if time.monotonic() > end:
            return None
        time.sleep(step)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """A virtual-rig recording with a loop delay the rig's model lacks, through the real stages:
    its run's .rrd (validate) and its discovery.rrd (discover), plus the run's .rrd with the scale bug."""
    work = tmp_path_factory.mktemp("viewer")
    _, _, csv = rig_kinematics((make_effect("loop_delay", {"Td": 0.05}),), seed=3, work=work)
    paths = RunPaths(work / "processed" / "rec")
    validate_run(paths, png=False)
    result = CliRunner().invoke(app, ["discover", str(csv), "--out", str(work / "discovery")])
    assert result.exit_code == 0, result.output
    return {"run": paths.rrd, "discovery": work / "discovery" / "discovery.rrd",
            "unscaled": _scale_on_the_origin(paths.rrd, work / "unscaled.rrd"),
            "another_run": _another_run(paths.rrd, work / "another.rrd")}


def _another_run(src, target):
    """The run's file as another run would be written: application id "pdr", a recording id of its
    own, the run's layout (a run the viewer has not opened yet)."""
    reader = RrdReader(src)
    layout = reader.store(store=reader.blueprints()[0]).stream().collect()
    chunks = [ch for ch in reader.stream().to_chunks() if ch.entity_path != "/__properties"]
    rec = rr.RecordingStream("pdr", recording_id="another")
    save_with_blueprint(rec, target, layout)
    rr.send_chunks(chunks, recording=rec)
    rec.flush()
    rec.disconnect()
    return target


def _scale_on_the_origin(src, target):
    """The run's file with the portrait's scale logged on the 3-D view's origin itself, under an
    application id of its own (the viewer keeps one active layout per application, and the tests
    change the run's camera)."""
    reader = RrdReader(src)
    layout = reader.store(store=reader.blueprints()[0]).stream().collect()
    chunks = [ch.with_entity_path("/trajectory") if ch.entity_path == "/trajectory/scaled" else ch
              for ch in reader.stream().to_chunks() if ch.entity_path not in ("/trajectory", "/__properties")]
    rec = rr.RecordingStream("pdr-unscaled", recording_id="unscaled")
    save_with_blueprint(rec, target, layout, application_id="pdr-unscaled")
    rr.send_chunks(chunks, recording=rec)
    rec.flush()
    rec.disconnect()
    return target


@pytest.fixture(scope="module")
def viewer(tmp_path_factory):
    from rerun.experimental import ViewerClient

    os.environ.setdefault("WGPU_BACKEND", "vulkan")
    port = free_port()
    client = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True,
                                executable_path=_local_rerun(tmp_path_factory.mktemp("bin")))
    try:
        assert client.url == f"rerun+http://127.0.0.1:{port}/proxy"
        _wait(client.get_state, timeout=60)
        yield client
        errors = [e.message for e in client.get_logs() if e.level == "ERROR"]
        assert errors == []
    finally:
        client.quit()


def _open(viewer, path):
    """Open a file, wait until every view is there and has drawn; returns (state, its recording)."""
    opened = viewer.open(str(path))
    assert len(opened.store_ids) == 1

    def loaded():
        s = viewer.get_state()
        return s if not s.loading and s.views and s.active_recording == opened.store_ids[0] else None

    assert _wait(loaded) is not None, f"the viewer did not finish loading {path}"
    time.sleep(1.0)                                     # let every view draw once
    state = viewer.get_state()
    recording = next(r for r in state.recordings if r.store_id == opened.store_ids[0])
    return state, recording


def _guard_planes(png: bytes, name: str) -> np.ndarray:
    """Mask of the guard planes' red (neutral green and blue, unlike the orange model line)."""
    import io

    folder = os.environ.get(SCREENSHOT_DIR_ENV)
    if folder:
        with open(os.path.join(folder, name), "wb") as fh:
            fh.write(png)
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (r > 80) & (g < 0.45 * r) & (np.abs(g - b) < 12)


def _aspect(mask: np.ndarray) -> float:
    ys, xs = np.nonzero(mask)
    assert len(xs) > 500, "no guard plane in the 3-D view"
    return (np.ptp(xs) + 1) / (np.ptp(ys) + 1)


def _inside(mask: np.ndarray) -> bool:
    ys, xs = np.nonzero(mask)
    return len(xs) > 500 and xs.min() > 0 and ys.min() > 0 and xs.max() < mask.shape[1] - 1 \
        and ys.max() < mask.shape[0] - 1


def _top_down(viewer, recording, view, name: str) -> float:
    """The guard planes' projected aspect (width / height) seen from straight above the unit cube."""
    blueprint = copy.deepcopy(viewer.get_blueprint(store_id=recording.store_id).blueprint)
    key = f"/view/{view.view_id}/EyeControls3D"
    blueprint[key] = {"EyeControls3D": TOP_DOWN}
    viewer.set_blueprint(blueprint, store_id=recording.store_id)
    time.sleep(1.0)
    return _aspect(_guard_planes(viewer.take_screenshot(view.view_id), name))


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> str:
    return os.environ.get(SCREENSHOT_DIR_ENV) or str(tmp_path_factory.mktemp("shots"))


def _screenshot(viewer, folder: str, name: str) -> np.ndarray:
    """The whole window, saved by the viewer (which writes on its own machine: here, this one)."""
    shot = os.path.join(folder, name)
    viewer.save_screenshot(shot)
    with Image.open(shot) as im:
        return np.asarray(im.convert("L"), dtype=float)


def _check_layout(state, recording, names) -> None:
    assert {v.name for v in state.views} == set(names)
    for view in state.views:
        assert view.reports == [], f"view '{view.name}' reports {view.reports}"
    (timeline,) = [tl for tl in recording.timelines if tl.name == "time"]
    assert recording.current_timeline == "time" and recording.current_time == timeline.end   # opens at the end


def _run_recording(viewer, path, shots) -> None:
    state, recording = _open(viewer, path)
    _check_layout(state, recording, VIEW_NAMES)
    pixels = _screenshot(viewer, shots, "run.png")
    assert pixels.shape[0] >= 600 and pixels.shape[1] >= 800 and pixels.std() > 10
    (portrait,) = [v for v in state.views if v.view_class == "3D"]
    assert _inside(_guard_planes(viewer.take_screenshot(portrait.view_id), "run-3d.png"))   # the saved camera
    assert 0.85 < _top_down(viewer, recording, portrait, "run-top-down.png") < 1.18         # squares


def _discovery_recording(viewer, path, shots) -> None:
    state, recording = _open(viewer, path)
    _check_layout(state, recording, DISCOVERY_VIEW_NAMES)
    assert _screenshot(viewer, shots, "discovery.png").std() > 10
    portraits = [v for v in state.views if v.view_class == "3D"]
    assert len(portraits) == 2
    for view in portraits:
        assert _inside(_guard_planes(viewer.take_screenshot(view.view_id), f"discovery-{view.origin[1:]}.png"))
    assert 0.85 < _top_down(viewer, recording, portraits[0], "discovery-top-down.png") < 1.18


def _unscaled_recording(viewer, path) -> None:
    """The negative control: the same checks fail when the scale sits on the view's origin."""
    state, recording = _open(viewer, path)
    (portrait,) = [v for v in state.views if v.view_class == "3D"]
    assert not _inside(_guard_planes(viewer.take_screenshot(portrait.view_id), "unscaled-3d.png"))
    assert _top_down(viewer, recording, portrait, "unscaled-top-down.png") < 0.5   # 0.65 A by 5 rad/s: thin strips


def _side_by_side_over_http(viewer, run, folder, shots) -> None:
    """What ``pdr view --web A B`` serves, loaded by the viewer from its HTTP address: every view
    of both columns there and healthy."""
    from pipeline.validate.view import serve_web, side_by_side_rrd

    both = side_by_side_rrd({"a": run, "b": run}, folder / "a+b.rrd")
    server = serve_web(both, port=free_port_pair())
    try:
        state, recording = _open(viewer, server.recording_url)
    finally:
        server.stop()
    names = {v.name for v in state.views}
    assert {"a: theta [rad]", "b: theta [rad]", "a: mode", "b: trajectory (I, w, theta)"} <= names
    assert all(v.reports == [] for v in state.views)
    assert recording.current_time == next(tl.end for tl in recording.timelines if tl.name == "time")
    assert _screenshot(viewer, shots, "side-by-side.png").std() > 10


def _run_after_side_by_side(viewer, run) -> None:
    """A run the viewer has not shown yet, opened after a side-by-side file: its own layout, every
    view healthy (the side-by-side files have an application id of their own, ``SIDE_BY_SIDE_APP``)."""
    state, recording = _open(viewer, run)
    _check_layout(state, recording, VIEW_NAMES)


def test_recordings_open_on_their_layouts_with_the_portraits_scaled(viewer, recordings, shots, tmp_path):
    """One test, so that one pytest-xdist worker starts one viewer and makes the recordings once."""
    _run_recording(viewer, recordings["run"], shots)
    _discovery_recording(viewer, recordings["discovery"], shots)
    _unscaled_recording(viewer, recordings["unscaled"])
    _side_by_side_over_http(viewer, recordings["run"], tmp_path, shots)
    _run_after_side_by_side(viewer, recordings["another_run"])


# The signal plots of a run's layout in a 1600 x 1000 window, as shares of its width and height:
# the left column's left part (3/5 of 3/5), between the top bar and the mode lane.
SIGNAL_PLOTS = (slice(0.07, 0.80), slice(0.03, 0.35))
LINE_TOLERANCE = 10            # per channel: the line's core pixels, not its anti-aliased edge


def _plots(rgb: np.ndarray) -> np.ndarray:
    h, w, _ = rgb.shape
    rows, cols = SIGNAL_PLOTS
    return rgb[int(rows.start * h):int(rows.stop * h), int(cols.start * w):int(cols.stop * w)].reshape(-1, 3)


def line_contrast(png: bytes) -> tuple[float, tuple[int, ...], int]:
    """(contrast ratio, background, pixel count) of the measured line in the signal plots: the
    background is their most frequent colour, the line the median of the pixels of its colour."""
    import io

    pixels = _plots(np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int))
    colours, counts = np.unique(pixels, axis=0, return_counts=True)
    background = tuple(int(c) for c in colours[counts.argmax()])
    line = pixels[np.abs(pixels - np.array(RGB["measured"])).max(axis=1) <= LINE_TOLERANCE]
    if not len(line):
        return 0.0, background, 0
    return contrast_ratio(tuple(np.median(line, axis=0)), background), background, len(line)


def _settled_screenshot(browser: Browser) -> bytes | None:
    """A screenshot once the recording is drawn: the measured line is there and two shots agree."""
    previous: list[bytes] = []

    def drawn():
        try:
            png = browser.screenshot()
        except RuntimeError:            # the page is between documents while it navigates
            return None
        done = line_contrast(png)[2] > 2000 and previous and previous[-1] == png
        previous.append(png)
        return png if done else None

    return wait_for(drawn, timeout=180, step=2.0)


def test_the_measured_line_reads_in_the_light_and_the_dark_scheme(recordings, shots):
    """``pdr view --web`` in Chromium, light then dark: the measured line stands out from the plots'
    background by >= 3:1 in both (WCAG's figure for graphics), where white, the earlier colour,
    gives ~1.3:1 on the light scheme."""
    from tests.validate.net import free_port_pair

    server = serve_web(recordings["run"], port=free_port_pair())
    try:
        with Browser(1600, 1000) as browser:
            for scheme in ("light", "dark"):
                browser.color_scheme(scheme)
                browser.open(server.url)
                png = _settled_screenshot(browser)
                assert png is not None, f"the web viewer did not draw the recording in the {scheme} scheme"
                with open(os.path.join(shots, f"web-{scheme}.png"), "wb") as fh:
                    fh.write(png)
                assert Image.open(io_bytes(png)).size == (1600, 1000)
                ratio, background, _n = line_contrast(png)
                assert (relative_luminance(background) > 0.8) == (scheme == "light"), (scheme, background)
                assert ratio >= 3.0, f"measured line at {ratio:.2f}:1 on the {scheme} scheme's {background}"
                if scheme == "light":
                    assert contrast_ratio((230, 230, 230), background) < 3.0      # the check can fail
    finally:
        server.stop()


def io_bytes(data: bytes):
    import io

    return io.BytesIO(data)
