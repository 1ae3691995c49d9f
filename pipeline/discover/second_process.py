"""A second process beside the decision: it ingests the raw CSV while this one sets up the
model's kernels, then imports what drawing needs while this one decides, then draws.

Deciding needs numba's one-time set-up (~0.15 s at the first kernel loaded) and none of
matplotlib or rerun; drawing needs those (~0.45 s of imports) and then ~0.45 s for the four
PNGs and the .rrd; ingesting and deriving a raw CSV (~0.1 s) needs neither.  Each goes where
the other core is idle: the user waits for the longer of two paths, not their sum.

Where processes can be forked (Linux), the second process is a fork taken after the
discovery's own modules are imported: it repeats no import and costs no CPU that working
here would not, so it is used whenever there are two cores.  Handed the discovery, it forks
once more and the two draw half the figures each (two PNGs there; two PNGs and the .rrd
here, the process that imported rerun).  Elsewhere the second process is spawned and repeats
numpy, pandas and the discovery modules (~0.5 s of CPU), which a busy machine would pay in
waiting, so it is used only when the load average leaves a core idle, and only to draw.
Either way the files are the same bytes (``report.write_figures`` draws them, and
``ingest_and_derive`` ingests).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
from dataclasses import replace
from pathlib import Path

# what the forked second process hands to its own fork (the rest, and the .rrd, it draws itself)
FORKED_HALF = ("localisation_png", "candidates_png")


def can_fork() -> bool:
    """Whether the second process can be a fork: Linux (macOS' system libraries are not fork-safe)."""
    return sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()


def use_second_process() -> bool:
    """Whether to have a second process.  A fork (``can_fork``) whenever there are two cores;
    a spawned one only when the 1-minute load average is at least one below the cores (where there
    is no load average, whether there are two cores).  ``PDR_DISCOVER_DRAW=process`` or ``=here``
    decides instead (benchmarks compare the two)."""
    forced = os.environ.get("PDR_DISCOVER_DRAW", "")
    if forced in ("process", "here"):
        return forced == "process"
    cores = os.cpu_count() or 1
    if can_fork():
        return cores >= 2
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):
        return cores >= 2
    return cores - load >= 1.0


def ingest_and_derive(csv: Path, processed: Path) -> list:
    """The raw CSV ingested into ``processed`` and each of its runs derived; the runs' paths."""
    from pipeline.derive.stage import derive_run
    from pipeline.ingest.stage import ingest_recording

    runs = ingest_recording(csv, processed).runs
    for paths in runs:
        derive_run(paths)
    return runs


def _warm() -> None:
    """What drawing imports, done while the first process decides."""
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401
    import rerun  # noqa: F401

    import pipeline.discover.report  # noqa: F401



def _draw(paths: dict[str, Path], d, report_md: str, rrd: bool) -> None:
    from pipeline.discover.report import write_figures

    write_figures(paths, d, report_md, rrd=rrd)


def _draw_in_halves(paths: dict[str, Path], d, report_md: str, rrd: bool) -> bool:
    """Draw ``FORKED_HALF`` in a fork of this process and the rest here; whether both halves were drawn.
    The fork draws no .rrd: rerun's threads, started by its import here, are not in a fork."""
    from pipeline.discover.report import FIGURES, write_figures

    pid = os.fork()
    if pid == 0:                                     # the fork: draw, then leave without any clean-up
        code = 1
        try:
            write_figures(paths, d, report_md, rrd=False, figures=FORKED_HALF)
            code = 0
        finally:
            os._exit(code)
    try:
        write_figures(paths, d, report_md, rrd=rrd, figures=tuple(k for k in FIGURES if k not in FORKED_HALF))
    finally:
        _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status) == 0


def _serve(conn, forked_from) -> None:
    """The second process: perhaps ingest (a fork is sent the CSV first, or None), import, then draw
    the one discovery it is sent (None: nothing to draw).  It answers whether it ingested and whether
    it drew; on failure the first process does it again itself, so an error is reported there as it
    would have been without a second process.  Ctrl-C is the first process's to handle (it stops this
    one), so it prints no second traceback.  ``forked_from``: the first process's end of the pipe when
    this is its fork (closed here, so its death ends the wait), else None."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        if forked_from is not None:
            forked_from.close()
            job = conn.recv()
            if job is not None:
                try:
                    conn.send(ingest_and_derive(*job))
                except Exception:   # noqa: BLE001 -- redone (and reported) by the first process
                    conn.send(None)
        _warm()
        job = conn.recv()
    except EOFError:
        return
    if job is None:
        return
    try:
        if forked_from is not None:
            drawn = _draw_in_halves(*job)
        else:
            _draw(*job)
            drawn = True
    except Exception:           # noqa: BLE001 -- redone (and reported) by the first process
        drawn = False
    conn.send(drawn)


def lean(d):
    """The discovery without the measurement's caches of start estimators (what drawing never reads
    and would only make the hand-over slower)."""
    from pipeline.discover.measurement import StartCache

    meas = replace(d.meas, cache=StartCache(offsets=d.meas.cache.offsets))
    return replace(d, meas=meas, selection=replace(d.selection, meas=meas))


class SecondProcess:
    """The second process (started at construction: a fork where ``can_fork``, else spawned) or, when
    ``background`` is false, none: everything is then done here."""

    def __init__(self, background: bool) -> None:
        self._proc = self._conn = None
        self._forked = False
        self._asked = False             # whether the fork has been sent its first job (the CSV, or None)
        if background:
            self._forked = can_fork()
            ctx = multiprocessing.get_context("fork" if self._forked else "spawn")
            self._conn, child = ctx.Pipe()
            self._proc = ctx.Process(target=_serve, args=(child, self._conn if self._forked else None),
                                     daemon=True, name="pdr-discover-second")
            self._proc.start()
            child.close()

    def ingest(self, csv: Path, processed: Path) -> list:
        """``ingest_and_derive``: in the fork, while this process sets up the model's kernels, or here."""
        from pipeline.model.compile import set_up_kernels

        if not self._forked or self._asked:
            return ingest_and_derive(csv, processed)
        self._asked = True
        try:
            self._conn.send((csv, processed))
        except OSError:
            return ingest_and_derive(csv, processed)
        set_up_kernels()
        try:
            runs = self._conn.recv()
        except (EOFError, OSError):     # the second process died (killed, out of memory)
            runs = None
        return runs if runs is not None else ingest_and_derive(csv, processed)

    def draw(self, paths: dict[str, Path], d, report_md: str, rrd: bool) -> None:
        if self._proc is not None:
            try:
                if self._forked and not self._asked:
                    self._asked = True
                    self._conn.send(None)           # nothing to ingest
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

    def __enter__(self) -> "SecondProcess":
        return self

    def __exit__(self, *_exc) -> None:
        self.close()
