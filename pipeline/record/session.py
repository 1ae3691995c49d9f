"""``pdr record``'s imperative shell: port, file, live view, stop, then the pipeline on the recording.

Ctrl-C (SIGINT) and SIGTERM only set a flag that the capture loop polls, so
a stop never lands between a read and its write.  The run afterwards is
``pdr run``'s own per-recording code (``pipeline.run.process_recording``
under the ``processed/`` lock, then the summary), on this recording only.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator

from pipeline.errors import PdrError
from pipeline.record.capture import READ_TIMEOUT_S, STOP_INTERRUPT, CaptureResult, capture, check_new_recording, \
    create_recording
from pipeline.record.live import LiveView, ViewSink


STOP_TERMINATED = "terminated (SIGTERM)"


@dataclass(frozen=True)
class RecordOptions:
    port: str
    name: str
    raw: Path = Path("raw")
    processed: Path = Path("processed")
    baud: int = 115200
    duration_s: float | None = None
    view: ViewSink | None = ViewSink("spawn")
    run: bool = True


def open_port(port: str, baud: int):
    """The serial port via pyserial, or a one-line error naming it."""
    import serial

    try:
        return serial.Serial(port, baudrate=baud, timeout=READ_TIMEOUT_S)
    except (serial.SerialException, ValueError) as err:
        raise PdrError(f"cannot open the serial port ({err}); pdr record --list shows the ports",
                       path=port) from None


@contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[list[int]]:
    """SIGINT and SIGTERM set ``stop`` instead of raising, for the duration of the capture; yields the
    signals received."""
    received: list[int] = []

    def handler(signum, _frame) -> None:
        received.append(signum)
        stop.set()

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield received
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def start_view(opts: RecordOptions, cfg) -> LiveView | None:
    if opts.view is None:
        return None
    import rerun as rr

    from pipeline.record.live import live_blueprint
    from pipeline.validate import rerun_log  # noqa: F401  (imported now, not in the view's first frame)

    rec = rr.RecordingStream("pdr-record", recording_id=f"{opts.name}-{time.time_ns()}")
    opts.view.open(rec, live_blueprint())
    return LiveView(cfg, rec).start()


def capture_to(csv: Path, opts: RecordOptions, on_chunk, say) -> CaptureResult:
    """Open the port, create the file, copy until a stop; both closed whatever happens."""
    port = open_port(opts.port, opts.baud)
    try:
        fd = create_recording(csv)
        try:
            say(f"recording {opts.port} -> {csv}"
                + (f" for {opts.duration_s:g} s" if opts.duration_s else "") + "; Ctrl-C stops")
            stop = threading.Event()
            with stop_on_signals(stop) as received:
                result = capture(port, fd, stop=stop, duration_s=opts.duration_s, on_chunk=on_chunk)
            if result.reason == STOP_INTERRUPT and received[:1] == [signal.SIGTERM]:
                result = replace(result, reason=STOP_TERMINATED)
            return result
        finally:
            os.close(fd)
    finally:
        port.close()


def record(opts: RecordOptions, say=print) -> tuple[CaptureResult, int]:
    """Capture, then (unless ``opts.run`` is off) process; returns the capture and the exit status."""
    from pipeline.config import config_for_recording
    from pipeline.runs import check_name

    check_name(opts.name)
    csv = Path(opts.raw) / f"{opts.name}.csv"
    cfg = config_for_recording(csv)           # the layers the run will use: the live view decodes with them
    check_new_recording(csv)                  # again, race-free, when the file is created
    view = start_view(opts, cfg)              # before the port opens: a board prints from then on
    try:
        result = capture_to(csv, opts, view.offer if view is not None else None, say)
    finally:
        if view is not None:
            view.close()
    say(f"stopped: {result.reason}; {result.n_bytes} bytes in {result.seconds:.1f} s -> {csv}")
    if view is not None:
        tally = view.decoder.tally
        say(f"live view: {tally.samples} samples, {tally.switches} switches, {tally.unparsed} lines did not "
            f"parse, {view.dropped_chunks} chunks dropped by the view"
            + (f"; view stopped early: {view.error}" if view.error else ""))
    if result.n_bytes == 0:
        csv.unlink()                          # the empty file this command created: not a recording
        raise PdrError(f"nothing was received ({result.reason}); is the board printing, and at --baud "
                       f"{opts.baud}? no file kept", path=opts.port)
    if not opts.run:
        say(f"not processed (--no-run); later: pdr run --raw {opts.raw}")
        return result, 0
    return result, run_recorded(csv, Path(opts.processed), say)


def run_recorded(csv: Path, processed: Path, say=print) -> int:
    """``pdr run``'s stages on this one recording, its summary, and how to look at it; the exit status."""
    from pipeline.run import RunReport, code_version, print_report, process_recording, processed_lock, stamp_for
    from pipeline.validate.summary import write_summary

    report = RunReport(started=time.perf_counter())
    with processed_lock(processed):
        report.ran = [process_recording(csv, processed, stamp_for(csv, code_version()))]
        write_summary(processed)
    report.wall_s = time.perf_counter() - report.started
    print_report(report, processed)
    if report.failed:
        return 1
    for run in report.ran[0]["runs"]:
        say(f"pdr view {run}" + (f" --processed {processed}" if processed != Path("processed") else ""))
    return 0
