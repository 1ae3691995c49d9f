"""Saving ``.rrd`` files with a saved layout, and checking them with the ``rerun`` CLI.

Shared by the run recording (``rerun_log``), discovery's (``discover.rerun_report``) and the
side-by-side one (``view``).  Every stream pdr saves is ended when its file is written
(``write_recording``): rerun's Python SDK never drops a stream by itself.
"""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import tempfile
import uuid
from pathlib import Path
from typing import Callable

from pipeline.errors import PdrError

# Blueprint element ids derive from their place in the layout, not from uuid4: two renders of
# the same run give the same file (``rerun rrd compare``), and a viewer that has been told to
# remember a layout finds the same views again.
_ID_NAMESPACE = uuid.UUID("6f0b7f3e-2d4c-4a0e-9a55-0c1f5b1d9e20")


def stable_ids(blueprint, key: str):
    """Give every container and view of ``blueprint`` an id derived from ``key`` and its position."""

    def walk(item, where: str) -> None:
        item.id = uuid.uuid5(_ID_NAMESPACE, f"{key}/{where}")
        for i, child in enumerate(getattr(item, "contents", None) or ()):
            if hasattr(child, "blueprint_path"):
                walk(child, f"{where}/{i}")

    walk(blueprint.root_container, "root")
    return blueprint


@functools.lru_cache(maxsize=16)
def blueprint_chunks(build: Callable, *args):
    """The chunks of ``build(*args)`` (a ``rrb.Blueprint``), built once per process and argument set.

    ``RecordingStream.save(path, default_blueprint=...)`` rebuilds the
    blueprint on every call: a few dozen archetypes through rerun's Python
    converters, ~10 ms per ``.rrd``.  The few layouts recur in every run, so
    each is logged once into a file of its own and its chunks are read back;
    each ``.rrd`` then gets a copy of them (~4 ms).  Logged by a layout stream
    of pdr's own, ended after: ``save(default_blueprint=...)`` would leave
    rerun's in-memory one running.  Not in the forkserver: saving starts
    rerun's threads, and a process must not fork after that.
    """
    from rerun.chunk import RrdReader

    def log_layout(stream) -> None:
        stream.save(path)
        stream.set_time("blueprint", sequence=0)
        build(*args).to_blueprint()._log_to_stream(stream)

    with tempfile.TemporaryDirectory(prefix="pdr-blueprint-") as folder:
        path = Path(folder) / "blueprint.rrd"
        _with_stream(_layout_stream("pdr"), log_layout)
        reader = RrdReader(path)
        return reader.store(store=reader.blueprints()[0]).stream().collect()


def write_recording(path: Path, recording_id: str, chunks, log: Callable, application_id: str = "pdr",
                    y_ranges: dict[str, tuple[float, float]] | None = None) -> None:
    """Save a new stream to ``path`` with the layout ``chunks`` (``save_with_blueprint``), ``log(stream)``
    into it, and end the stream: the file is complete, and the stream's threads are gone.

    The stream never leaves this call (``log`` must not keep it), so nothing holds it once it is
    closed; ``end_streams`` then drops it.
    """
    import rerun as rr

    def save_and_log(rec) -> None:
        save_with_blueprint(rec, path, chunks, application_id, y_ranges)
        log(rec)

    _with_stream(rr.RecordingStream(application_id, recording_id=recording_id), save_and_log)


def _with_stream(rec, use: Callable) -> None:
    """``use(rec)``, then flush and close ``rec`` and drop it (``end_streams``), whatever happens
    (after a failure the traceback may still hold it: the next ``end_streams`` drops it)."""
    try:
        use(rec)
        rec.flush()
    finally:
        rec.disconnect()
        del rec
        end_streams()


def end_streams() -> None:
    """End every Rerun stream of this process that nothing references any more.

    rerun-sdk's Python streams are owned by its Rust side (rerun-io/rerun#2116):
    a stream Python lets go of is only disconnected, and keeps its
    ``RecordingStream`` and ``ChunkBatcher`` threads and buffers for the life of
    the process -- two threads per stream, four per ``.rrd`` with its layout
    stream, thousands in a ``pdr run`` worker.  The binding ``rr.init`` calls to
    destroy orphaned streams is the only one that ends them; it also flushes
    the live ones and clears the global recording, which pdr never sets (it
    logs to explicit streams only).  A live stream that cannot flush (``pdr
    record``'s view of a viewer that cannot be reached) makes it raise before
    it ends any: the file at hand was flushed and closed already, so that is
    no failure of it, and the orphans are ended by the next call that succeeds.
    """
    import rerun_bindings as bindings

    try:
        bindings.flush_and_cleanup_orphaned_recordings()
    except RuntimeError:
        pass


def save_with_blueprint(rec, path: Path, chunks, application_id: str = "pdr",
                        y_ranges: dict[str, tuple[float, float]] | None = None) -> None:
    """``rec.save(path, default_blueprint=...)`` from cached blueprint chunks, plus this file's
    ``y_ranges`` (view id -> y axis range) logged as the views' ``ScalarAxis``.

    What ``rerun.sinks.save`` does, with the blueprint stream filled by
    ``send_chunks`` instead of by logging the blueprint again (rerun-sdk is
    pinned: ``rerun_bindings.new_blueprint`` and ``save`` are its internals).
    The tests read the blueprint back from the file and open it in the viewer.
    """
    import rerun as rr
    import rerun_bindings as bindings

    _require_space(path)

    def save(stream) -> None:
        rr.send_chunks(chunks, recording=stream)
        if y_ranges:
            import rerun.blueprint as rrb

            stream.set_time("blueprint", sequence=0)
            for view_id, y_range in y_ranges.items():
                stream.log(f"view/{view_id}/ScalarAxis", rrb.archetypes.ScalarAxis(range=y_range))
        bindings.save(path=str(path), default_blueprint=stream.memory_recording().storage,
                      recording=rec.to_native(), write_footer=True)

    # the layout stream's memory sink and the stream hold each other: only closing it frees both
    _with_stream(_layout_stream(application_id), save)


def _layout_stream(application_id: str):
    """A blueprint (layout) stream, neither global nor the thread's."""
    import rerun_bindings as bindings
    from rerun.recording_stream import RecordingStream

    return RecordingStream._from_native(bindings.new_blueprint(
        application_id=application_id, make_default=False, make_thread_default=False, default_enabled=True))


# Free space a recording needs to start: Rerun's file sink blocks for good, instead of failing, when
# the disk is already full as it opens the file (seen with 0.41 on a full tmpfs).
MIN_FREE_BYTES = 4 << 20


def _require_space(path: Path) -> None:
    import errno
    import os
    import shutil

    if shutil.disk_usage(Path(path).parent).free < MIN_FREE_BYTES:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


# The rerun binary (verify, the viewer, the web viewer) sends usage events to tel.rerun.io, and flushes any
# a viewer session left pending, unless the user's analytics config says no or CI is set (re_analytics,
# native/pipeline.rs, 0.41: "Analytics disabled on CI"; there is no other switch).  pdr sets the latter for
# the rerun processes it starts: a lab pipeline connects nowhere its user did not ask, and it does not
# rewrite the user's own config (`rerun analytics disable` would, for every program).
# FORCE_RERUN_ANALYTICS=1 in the environment still turns them on.
ANALYTICS_OFF = ("CI", "1")


def rerun_env(environ: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a ``rerun`` process pdr starts: ``environ`` (default: this process's) with
    Rerun's analytics off (``ANALYTICS_OFF``; a ``CI`` already set is kept, it has the same effect)."""
    env = dict(os.environ if environ is None else environ)
    env.setdefault(*ANALYTICS_OFF)
    return env


def rerun_executable() -> str:
    """The native ``rerun`` binary shipped in the rerun-sdk wheel.

    Called directly rather than through ``.venv/bin/rerun`` (a Python wrapper
    that starts an interpreter first): 30 ms instead of 120 ms per verify.
    """
    import importlib.util

    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        native = Path(spec.origin).with_name("rerun")
        if native.exists():
            return str(native)
    found = shutil.which("rerun")
    if found is None:
        raise PdrError("the rerun CLI (package rerun-sdk, module rerun_cli) is not installed")
    return found


def _verify(paths: list[Path]) -> str | None:
    """Run ``rerun rrd verify`` on the files; None when all pass, else the tool's last line."""
    proc = subprocess.run([rerun_executable(), "rrd", "verify", *map(str, paths)], capture_output=True, text=True,
                          env=rerun_env())
    if proc.returncode == 0:
        return None
    msg = (proc.stderr or proc.stdout).strip().splitlines()
    return f"rerun rrd verify failed: {msg[-1] if msg else 'exit ' + str(proc.returncode)}"


def verify_rrd(path: Path) -> None:
    """``rerun rrd verify``: the file loads and every chunk is interpretable."""
    error = _verify([path])
    if error is not None:
        raise PdrError(error, path=path)


def verify_rrds(paths: list[Path]) -> dict[Path, str]:
    """``verify_rrd`` on many files with one start of the tool (~40 ms each saved); returns the failures.

    When the batch fails, each file is verified on its own so only the culprits are named.
    """
    if not paths or _verify(paths) is None:
        return {}
    failed = {}
    for path in paths:
        error = _verify([path])
        if error is not None:
            failed[path] = error
    return failed
