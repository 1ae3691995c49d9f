"""The real Rerun viewer, headless, opens a run's .rrd on its saved blueprint.

Needs a Vulkan driver: ``make test`` installs Debian's mesa-vulkan-drivers
(lavapipe, a software rasteriser) when it is missing.  The viewer is bound to
127.0.0.1 on a free port (the CLI's default bind is 0.0.0.0, so the spawned
executable is a two-line wrapper that adds ``--bind 127.0.0.1``).
"""

import os
import socket
import stat
import time

import numpy as np
import pytest
from PIL import Image

from pipeline.validate.rerun_log import VIEW_NAMES, rerun_executable
from pipeline.validate.stage import validate_run
from tests.validate.synthetic import synthetic_run

SCREENSHOT_DIR_ENV = "PDR_VIEWER_SCREENSHOT_DIR"   # keep the screenshot somewhere to look at


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _local_rerun(folder) -> str:
    wrapper = folder / "rerun"
    wrapper.write_text(f'#!/bin/sh\nexec "{rerun_executable()}" --bind 127.0.0.1 "$@"\n')
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IXUSR)
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


@pytest.mark.viewer
@pytest.mark.slow
def test_headless_viewer_shows_every_view_without_errors(tmp_path):
    from rerun.experimental import ViewerClient

    os.environ.setdefault("WGPU_BACKEND", "vulkan")
    paths = synthetic_run(tmp_path / "processed")
    validate_run(paths, png=False)
    port = _free_port()
    viewer = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True,
                                executable_path=_local_rerun(tmp_path))
    try:
        assert viewer.url == f"rerun+http://127.0.0.1:{port}/proxy"
        _wait(viewer.get_state, timeout=60)
        opened = viewer.open(str(paths.rrd))
        assert len(opened.store_ids) == 1
        def loaded():
            s = viewer.get_state()
            return s if not s.loading and s.views else None

        state = _wait(loaded)
        assert state is not None, "the viewer did not finish loading the recording"
        time.sleep(1.0)                                     # let every view draw once
        state = viewer.get_state()
        names = {v.name for v in state.views}
        assert names == set(VIEW_NAMES)
        for view in state.views:
            assert view.reports == [], f"view '{view.name}' reports {view.reports}"
        assert any(r.store_id == opened.store_ids[0] for r in state.recordings)
        shot_dir = os.environ.get(SCREENSHOT_DIR_ENV, str(tmp_path))
        shot = os.path.join(shot_dir, "viewer.png")
        viewer.save_screenshot(shot)
        errors = [e.message for e in viewer.get_logs() if e.level == "ERROR"]
        assert errors == []
    finally:
        viewer.quit()
    with Image.open(shot) as im:
        pixels = np.asarray(im.convert("L"), dtype=float)
    assert pixels.shape[0] >= 600 and pixels.shape[1] >= 800
    assert pixels.std() > 10          # plots drawn, not a blank window
