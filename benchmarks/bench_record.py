"""``pdr record`` through a real pty with the live view on: bytes lost, chunks the view dropped, CPU.

The virtual rig streams a 60 s recording (1,220 lines) at 20x (the issue's bar: 400 lines/s),
100x and 400x; the capture loop runs in this process's main thread as in ``pdr record``, the
live view in its thread, writing to an .rrd file (no viewer on a headless machine).
"""

from __future__ import annotations

import resource
import tempfile
import threading
import time
from pathlib import Path

import rerun as rr

from pipeline.config import config_for_recording
from pipeline.record.capture import capture, create_recording
from pipeline.record.live import LiveView, ViewSink, live_blueprint
from pipeline.record.session import open_port
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.rig.serve import PtyRig, line_schedule, serve

SPEEDS = (20.0, 100.0, 400.0)


def _cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def one(speed: float, rec, folder: Path) -> dict:
    rig = PtyRig()
    schedule = line_schedule(rec)

    def board() -> None:
        rig.wait_for_reader(30)
        serve(rig, schedule, speed, boot_s=0.3)
        rig.drain(10)
        rig.close()

    thread = threading.Thread(target=board, daemon=True)
    csv = folder / f"x{int(speed)}.csv"
    stream = rr.RecordingStream("pdr-record-bench", recording_id=csv.stem)
    ViewSink("save", str(folder / f"{csv.stem}.rrd")).open(stream, live_blueprint())
    view = LiveView(config_for_recording(csv), stream).start()
    thread.start()
    port = open_port(rig.path, 115200)
    fd = create_recording(csv)
    c0, t0 = _cpu(), time.perf_counter()
    result = capture(port, fd, stop=threading.Event(), on_chunk=view.offer)
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    port.close()
    view.close()
    thread.join(10)
    return {"speed": speed, "lines_per_s": len(schedule.lines) / (schedule.at_s[-1] / speed),
            "identical": csv.read_bytes() == rec.csv_bytes, "bytes": result.n_bytes,
            "dropped_chunks": view.dropped_chunks, "frames": view.frames, "samples_in_view": view.decoder.tally.samples,
            "wall_s": wall, "cpu_s": cpu}


def main() -> None:
    rec = make_recording(RigSetup(duration_s=60.0, seed=9))
    with tempfile.TemporaryDirectory(prefix="pdr-bench-record-") as tmp:
        for speed in SPEEDS:
            r = one(speed, rec, Path(tmp))
            print(f"{r['speed']:5.0f}x ({r['lines_per_s']:6.0f} lines/s): byte-identical {r['identical']}, "
                  f"{r['bytes']} bytes, view dropped {r['dropped_chunks']} chunks, {r['frames']} frames, "
                  f"{r['samples_in_view']} samples shown; capture {r['wall_s']:.2f} s wall, "
                  f"{r['cpu_s']:.2f} s CPU (process, view included)", flush=True)


if __name__ == "__main__":
    main()
