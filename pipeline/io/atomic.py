"""Atomic output: write to a temporary file in the same folder, fsync, rename.

A killed run leaves either the previous file or the new one, never a torn one
(that needs only the rename).  The fsync makes the new file durable before it
replaces the old one, so a power cut cannot leave an empty file under the
output's name either; ``deferred_sync`` trades a dozen fsyncs per recording
for one ``os.sync()`` where a caller writes a marker (``pdr run``'s stamps)
only after it.
"""

from __future__ import annotations

import itertools
import json
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator


_deferred_depth = 0     # > 0 inside deferred_sync(): per-file fsyncs are skipped


@contextmanager
def deferred_sync() -> Iterator[None]:
    """Atomic writes inside skip their fsync; leaving it syncs everything once (``os.sync``).

    For ``pdr run``: a worker writes ~13 files per recording, and their fsyncs
    (~0.5 ms each on a quiet disk, several ms on a busy one) leave its core
    idle.  Inside, each file is still renamed into place complete (a killed
    process leaves old or new files); the one sync on exit makes them durable
    before the run's stamp is written, so a power cut can at worst cost a
    re-run, never a stamp over empty files.  Process-wide (helper threads
    write too); nested uses sync once, at the outermost exit.
    """
    global _deferred_depth
    if not hasattr(os, "sync"):         # Windows: no whole-system sync, so every file keeps its own fsync
        yield
        return
    _deferred_depth += 1
    try:
        yield
    finally:
        _deferred_depth -= 1
        if _deferred_depth == 0:
            os.sync()


def syncs_deferred() -> bool:
    """Inside ``deferred_sync``: a writer that syncs part of a file early (``write_signals``) skips it too."""
    return _deferred_depth > 0


def _sync(fd: int) -> None:
    if _deferred_depth == 0:
        os.fsync(fd)


_TEMP_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC | getattr(os, "O_NOFOLLOW", 0)
_serial = itertools.count()


def _create_temp(target: Path) -> tuple[int, Path]:
    """A new, empty temporary file beside ``target`` (same filesystem, so the rename is atomic).

    Named by process and a counter (``.<name>.<pid>.<n>.tmp``, the pattern
    ``remove_stale_temporaries`` clears), created exclusively with open()'s
    usual permissions.  Cheaper than ``tempfile.mkstemp``, whose random names
    and 0600 mode (then a chmod) cost a few syscalls per file, and a
    recording writes a dozen files.  A name left by a killed process with the
    same pid is simply skipped.
    """
    for _ in range(100):
        tmp = target.with_name(f".{target.name}.{os.getpid()}.{next(_serial)}.tmp")
        try:
            return os.open(tmp, _TEMP_FLAGS, 0o666), tmp
        except FileExistsError:
            continue
        except FileNotFoundError:
            target.parent.mkdir(parents=True, exist_ok=True)
    raise FileExistsError(f"no free temporary name beside {target}")


def remove_stale_temporaries(root: Path) -> None:
    """Temporary files a killed process left behind in ``root`` (never the outputs themselves); only for a
    caller that holds ``processed/``'s lock or owns ``root``, so no live writer's temporary is removed."""
    if root.is_dir():
        for tmp in root.glob(".*.tmp"):
            tmp.unlink(missing_ok=True)


def _fsync_path(path: Path) -> None:
    if _deferred_depth:
        return
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(target: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; on success it is synced and replaces ``target`` in one rename."""
    target = Path(target)
    fd, tmp_path = _create_temp(target)
    os.close(fd)
    try:
        yield tmp_path
        _fsync_path(tmp_path)
        os.replace(tmp_path, target)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_bytes(target: Path, data: bytes) -> None:
    """``data`` as ``target``, atomically: written, synced and renamed through one file descriptor."""
    target = Path(target)
    fd, tmp_path = _create_temp(target)
    try:
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            _sync(fd)
        finally:
            os.close(fd)
        os.replace(tmp_path, target)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def write_text(target: Path, text: str) -> None:
    write_bytes(target, text.encode("utf-8"))


def write_json(target: Path, obj: Any) -> None:
    """Deterministic JSON (sorted keys) so a re-run gives identical bytes."""
    write_text(target, json.dumps(obj, indent=2, sort_keys=True, allow_nan=False, default=_default) + "\n")


IN_MEMORY_PARQUET_BYTES = 32 << 20   # tables up to this size are encoded in memory, then written in one go


def write_parquet(target: Path, table: Any) -> None:
    """A pyarrow Table as Parquet; same table and pyarrow version give identical bytes.

    A run's small tables (a few hundred rows) are encoded into a buffer and
    written like any other bytes: ~1 ms, where handing pyarrow the path costs
    ~4 ms (it resolves a filesystem and opens its own stream for each file).
    Large tables stream to the file instead, so memory stays bounded.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq
    if table.nbytes <= IN_MEMORY_PARQUET_BYTES:
        sink = pa.BufferOutputStream()
        pq.write_table(table, sink)
        write_bytes(target, sink.getvalue())
        return
    with atomic_path(target) as tmp:
        pq.write_table(table, tmp)


def read_parquet(path: Path):
    """A Parquet file as a DataFrame, as ``pandas.read_parquet`` gives it for pdr's tables, at half the cost
    (no dataset discovery for a single file)."""
    import pyarrow.parquet as pq
    return pq.ParquetFile(path).read().to_pandas()


def _default(o: Any) -> Any:
    import numpy as np
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
