"""A ``pdr run`` worker's threads, memory and open files stay flat over hundreds of recordings.

Every recording opens Rerun streams (each with a batcher thread) and files and draws a figure; if any
of them outlived its recording, a worker on a raw folder of a few thousand recordings would run out of
threads or memory (issue 30).  One worker of ``pdr run``'s own pool does a few hundred short
virtual-rig recordings, chunk by chunk as ``pdr run`` hands them out, and reports what it holds
after each chunk.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.rig.recording import RigSetup, make_recording
from pipeline.run.pool import CHUNK_MAX, make_pool
from pipeline.run.stages import process_chunk
from pipeline.run.stamp import stamp_for
from tests.cluster.helpers import CODE

RECORDINGS = 160
DURATION_S = 3.0            # 60 control periods, two reversals at the guards: every stage has work, briefly
WARM_UP = 8                 # recordings after which the worker's caches (layouts, figure backgrounds) are filled
# What the worker may gain after its warm-up.  Flat, it stays within a few MB of memory and holds the
# same threads and files; one stream left per recording would cost four threads (a stream and its
# layout's, each with its batcher) and ~2 MB per recording: ~610 threads and ~300 MB here.
MAX_EXTRA_THREADS = 2
MAX_EXTRA_RSS_MB = 25
MAX_EXTRA_FILES = 2


def _held() -> tuple[int, float, int]:
    """This process's threads, resident memory (MB) and open files (descriptors, or handles on Windows)."""
    import psutil

    me = psutil.Process()
    files = me.num_fds() if hasattr(me, "num_fds") else me.num_handles()
    return me.num_threads(), me.memory_info().rss / 2**20, files


def _process_in_chunks(csvs: list[Path], processed: Path) -> tuple[list[str], list[tuple[int, int, float, int]]]:
    """What a worker does: ``process_chunk`` on consecutive chunks; the statuses, and after each chunk
    (recordings done, threads, RSS, open files)."""
    statuses, held = [], []
    for i in range(0, len(csvs), CHUNK_MAX):
        chunk = [(csv, stamp_for(csv, CODE)) for csv in csvs[i:i + CHUNK_MAX]]
        statuses += [r["error"] or r["status"] for r in process_chunk(chunk, processed, dataset=True)]
        held.append((i + len(chunk), *_held()))
    return statuses, held


@pytest.mark.long
@pytest.mark.slow
def test_a_worker_holds_as_much_after_hundreds_of_recordings_as_after_its_first(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    capture = make_recording(RigSetup(duration_s=DURATION_S), seed=3)
    csvs = [raw / f"r{i:04d}.csv" for i in range(RECORDINGS)]
    for csv in csvs:
        csv.write_bytes(capture.csv_bytes)
        csv.with_suffix(".toml").write_text(capture.toml_text)

    with make_pool(1) as pool:
        statuses, held = pool.submit(_process_in_chunks, csvs, tmp_path / "processed").result()

    assert statuses == ["ok"] * RECORDINGS
    assert len(list((tmp_path / "processed").glob("r*/r*.rrd"))) == RECORDINGS
    after_warm_up = [h for h in held if h[0] >= WARM_UP]
    _done, threads0, rss0, files0 = after_warm_up[0]
    peak_threads, peak_rss, peak_files = (max(h[k] for h in after_warm_up) for k in (1, 2, 3))
    assert peak_threads - threads0 <= MAX_EXTRA_THREADS, held
    assert peak_rss - rss0 <= MAX_EXTRA_RSS_MB, held
    assert peak_files - files0 <= MAX_EXTRA_FILES, held
