"""The live view while recording: Rerun, fed from a thread of its own.

The capture loop hands each chunk to ``LiveView.offer``, which never blocks:
when the queue is full (the viewer or this thread fell behind) the chunk is
dropped from the view, and only from the view (it is already on disk).  This
thread takes whatever has queued, decodes it with ingest's code
(``LineDecoder``), and logs it as one frame per ``frame_s``: theta with the
guards, current, the mode lane and a running count of lines, switches, lines
that did not parse and chunks the queue dropped.
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.config import RigConfig
from pipeline.errors import PdrError
from pipeline.io.queues import next_batch
from pipeline.record.decode import LineDecoder, Samples

TIMELINE = "time"
LIVE_VIEW_NAMES = ("theta [rad]", "current [A]", "mode", "counts")
_END = None


@dataclass(frozen=True)
class ViewSink:
    """Where the live view goes: a spawned viewer, a running one (``connect``: its gRPC URL) or a file."""

    kind: str                 # "spawn", "connect" or "save"
    target: str | None = None

    def open(self, rec, blueprint) -> None:
        """Attach the stream; a viewer that cannot start is a one-line error pointing at the other sinks."""
        import rerun as rr

        from pipeline.validate.rerun_io import ANALYTICS_OFF
        from pipeline.validate.rerun_log import rerun_executable

        if self.kind == "spawn" and not has_display():
            raise PdrError("no display for a viewer (DISPLAY and WAYLAND_DISPLAY are unset); use --save-view "
                           "FILE.rrd (open it later with rerun FILE.rrd), --connect URL or --no-view")
        try:
            if self.kind == "spawn":            # the wheel's own viewer binary: .venv/bin need not be on PATH
                os.environ.setdefault(*ANALYTICS_OFF)      # rr.spawn takes no environment (rerun_io says why)
                rr.spawn(executable_path=rerun_executable(), default_blueprint=blueprint, recording=rec)
            elif self.kind == "connect":
                rec.connect_grpc(self.target, default_blueprint=blueprint)
            else:
                rec.save(Path(self.target), default_blueprint=blueprint)
        except (RuntimeError, OSError, ValueError) as err:
            raise PdrError(f"cannot start the live view ({str(err).strip().splitlines()[0]}); "
                           f"use --no-view, --connect URL or --save-view FILE.rrd") from None


def has_display() -> bool:
    """A Linux viewer needs X11 or Wayland; without either it exits at once and the stream waits for it."""
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def live_blueprint():
    import rerun.blueprint as rrb

    theta, current, mode, counts = LIVE_VIEW_NAMES
    return rrb.Vertical(
        rrb.TimeSeriesView(origin="/signals/theta", name=theta),
        rrb.TimeSeriesView(origin="/signals/current", name=current),
        rrb.StateTimelineView(origin="/mode", name=mode),
        rrb.TextDocumentView(origin="/counts", name=counts),
        row_shares=[4, 4, 1, 1],
    )


class LiveView:
    """Decodes and logs the capture's chunks off the capture thread (see the module docstring)."""

    def __init__(self, cfg: RigConfig, rec, *, max_chunks: int = 4096, frame_s: float = 0.1) -> None:
        self.cfg = cfg
        self.rec = rec
        self.decoder = LineDecoder(cfg)
        self.frames = 0
        self.dropped_chunks = 0
        self._queue: queue.Queue = queue.Queue(maxsize=max_chunks)
        self._frame_s = frame_s
        self._last_dir: int | None = None
        self._thread = threading.Thread(target=self._run, name="pdr-live-view", daemon=True)
        self.error: str | None = None

    def start(self) -> "LiveView":
        self._thread.start()
        return self

    def offer(self, offset: int, data: bytes) -> None:
        """Called by the capture loop: hand the chunk over, or drop it if the view is behind. Never blocks."""
        try:
            self._queue.put_nowait((offset, data))
        except queue.Full:
            self.dropped_chunks += 1

    def close(self, timeout_s: float = 5.0) -> None:
        """Show what is queued, then end the thread and flush the stream."""
        if self._thread.is_alive():
            try:
                self._queue.put(_END, timeout=timeout_s)
            except queue.Full:
                pass
            self._thread.join(timeout_s)
        try:
            self.rec.flush(timeout_sec=timeout_s)
        except RuntimeError as err:           # e.g. the viewer never came up: the recording is unaffected
            self.error = self.error or str(err).strip().splitlines()[0]

    def _run(self) -> None:
        try:
            self._loop()
        except Exception as err:  # the view must never take the capture down: report it at the end
            self.error = f"{type(err).__name__}: {err}"

    def _loop(self) -> None:
        done = False
        while not done:
            started = time.monotonic()
            batch = next_batch(self._queue)
            done = _END in batch
            chunks = [c for c in batch if c is not _END]
            self._log(self.decoder.feed(chunks))
            if done:                            # the capture's last line, even without its line ending
                self._log(self.decoder.finish())
            rest = self._frame_s - (time.monotonic() - started)
            if rest > 0 and not done:
                time.sleep(rest)

    def _log(self, s: Samples) -> None:
        import rerun as rr

        from pipeline.validate.rerun_log import GUARD, MEASURED, MODE_NAMES, log_signal

        tally = self.decoder.tally
        self.frames += 1
        if len(s):
            time_column = rr.TimeColumn(TIMELINE, duration=s.t_s)
            g = np.full(len(s), self.cfg.controller.guard_rad)
            log_signal(self.rec, "signals/theta", time_column,
                       {"measured": (s.theta_rad, MEASURED, 1.5), "guard +": (g, GUARD, 1.0),
                        "guard -": (-g, GUARD, 1.0)})
            log_signal(self.rec, "signals/current", time_column, {"measured": (s.current_a, MEASURED, 1.5)})
            if s.has_dir:
                self._mode_lane(s, MODE_NAMES)
            self.rec.set_time(TIMELINE, duration=float(s.t_s[-1]))
        text = (f"lines {tally.lines}  samples {tally.samples}  segments {tally.segment}\n\n"
                f"switches {tally.switches}\n\nlines that did not parse {tally.unparsed}\n\n"
                f"chunks dropped by the view {self.dropped_chunks} (lines skipped {tally.skipped_lines})")
        self.rec.log("counts", rr.TextDocument(text))

    def _mode_lane(self, s: Samples, names: dict[int, str]) -> None:
        import rerun as rr

        d = s.dir.astype(np.int64)
        prev = np.r_[self._last_dir if self._last_dir is not None else d[0] + 1, d[:-1]]
        change = np.flatnonzero(d != prev)
        self._last_dir = int(d[-1])
        if len(change):
            self.rec.send_columns("mode", indexes=[rr.TimeColumn(TIMELINE, duration=s.t_s[change])],
                                  columns=rr.StateChange.columns(state=[names[int(v)] for v in d[change]]))
