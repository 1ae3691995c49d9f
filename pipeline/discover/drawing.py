"""The discovery's figures and Rerun recording, drawn beside the decision when a core is free.

Drawing needs matplotlib and rerun (~0.5 s of imports) and then ~0.5 s for the four PNGs;
none of it is needed to decide.  A second process, started before the recording is even
ingested, does those imports while this one ingests, derives and fits, then draws what it
is handed; the user waits for the longer of the two, not their sum.  It repeats some imports
(numpy, pandas, the discovery modules its input is made of), ~0.5 s of CPU, which a busy
machine would pay in waiting, so it is used only when the load average leaves a core idle.
Either way the files are the same bytes (``report.write_figures`` draws them).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from dataclasses import replace
from pathlib import Path


def idle_core() -> bool:
    """Whether a core is free for a second process: the 1-minute load average at least one
    below the cores (where there is no load average, whether there are two cores).
    ``PDR_DISCOVER_DRAW=process`` or ``=here`` decides instead (benchmarks compare the two)."""
    forced = os.environ.get("PDR_DISCOVER_DRAW", "")
    if forced in ("process", "here"):
        return forced == "process"
    cores = os.cpu_count() or 1
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):
        return cores >= 2
    return cores - load >= 1.0


def _warm() -> None:
    """What drawing imports, done while the first process decides."""
    import matplotlib.figure  # noqa: F401
    import rerun  # noqa: F401

    import pipeline.discover.report  # noqa: F401


def _draw(paths: dict[str, Path], d, report_md: str, rrd: bool) -> None:
    from pipeline.discover.report import write_figures

    write_figures(paths, d, report_md, rrd=rrd)


def _serve(conn) -> None:
    """The second process: import, then draw the one discovery it is sent (None: nothing to draw).
    It answers whether it drew; on failure the first process draws again itself, so an error is
    reported there as it would have been without a second process.  Ctrl-C is the first process's
    to handle (it stops this one), so it prints no second traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _warm()
    try:
        job = conn.recv()
    except EOFError:
        return
    if job is None:
        return
    try:
        _draw(*job)
    except Exception:           # noqa: BLE001 -- redone (and reported) by the first process
        conn.send(False)
        return
    conn.send(True)


def lean(d):
    """The discovery without the measurement's caches of start estimators (what drawing never reads
    and would only make the hand-over slower)."""
    meas = replace(d.meas, _estimators={}, _starts={})
    return replace(d, meas=meas, selection=replace(d.selection, meas=meas))


class Drawer:
    """Draws in a second process (started at construction) or, when ``background`` is false, here."""

    def __init__(self, background: bool) -> None:
        self._proc = self._conn = None
        if background:
            ctx = multiprocessing.get_context("spawn")
            self._conn, child = ctx.Pipe()
            self._proc = ctx.Process(target=_serve, args=(child,), daemon=True, name="pdr-discover-drawing")
            self._proc.start()
            child.close()

    def draw(self, paths: dict[str, Path], d, report_md: str, rrd: bool) -> None:
        if self._proc is not None:
            try:
                self._conn.send((paths, lean(d), report_md, rrd))
                drawn = self._conn.recv()
            except (EOFError, OSError):         # the second process died (killed, out of memory)
                drawn = False
            self.close()
            if drawn:
                return
        _draw(paths, d, report_md, rrd)

    def close(self) -> None:
        """Stop the second process (at once when it has nothing left to draw)."""
        if self._proc is not None:
            self._conn.close()
            if self._proc.is_alive():
                self._proc.terminate()
            self._proc.join()
            self._proc = self._conn = None

    def __enter__(self) -> "Drawer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
