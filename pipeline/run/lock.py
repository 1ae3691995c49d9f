"""The exclusive lock on ``processed/`` that every writing command holds (``pdr run``, ``ingest``, ``validate``).

``filelock`` takes an OS lock on ``processed/.pdr.lock`` (``flock`` on POSIX,
``msvcrt.locking`` on Windows): the OS releases it when the holder dies, even
by ``kill -9``, so a killed run never leaves a stale lock behind.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from filelock import FileLock, Timeout

from pipeline.errors import PdrError
from pipeline.runs import LOCK_NAME


def ensure_output_folder(processed: Path) -> Path:
    """``processed/`` as a folder this process can write, or a one-line refusal naming it."""
    processed = Path(processed)
    try:
        processed.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise PdrError("expected an output folder, found a file", path=processed) from None
    except OSError as err:
        raise PdrError(f"cannot create the output folder: {err.strerror}", path=processed) from None
    return processed


@contextmanager
def processed_lock(processed: Path, wait_message: bool = True) -> Iterator[None]:
    """Exclusive lock on ``processed/`` for the duration of a command; a second one waits, saying so."""
    processed = ensure_output_folder(processed)
    # an OS lock or none: a soft (file-exists) lock would outlive a killed holder and make every later run wait
    lock = FileLock(processed / LOCK_NAME, thread_local=False, preserve_lock_file=True, fallback_to_soft=False)
    try:
        try:
            lock.acquire(timeout=0)
        except Timeout:
            if wait_message:
                print(f"pdr: waiting for another pdr process using {processed}/ ...", file=sys.stderr)
            lock.acquire()
    except OSError as err:
        raise PdrError(f"cannot lock the output folder ({LOCK_NAME}): {err.strerror}", path=processed) from None
    try:
        yield
    finally:
        lock.release()


@contextmanager
def reading_lock(processed: Path) -> Iterator[None]:
    """The same lock for a command that only reads ``processed/`` (``pdr gate``): it waits for a run that
    is writing instead of reading half its outputs.  Nothing is created: a folder that is missing, or that
    cannot be locked because it cannot be written (a read-only copy), has no writer to wait for."""
    lock = FileLock(Path(processed) / LOCK_NAME, thread_local=False, preserve_lock_file=True,
                    fallback_to_soft=False)
    try:
        if Path(processed).is_dir():
            try:
                lock.acquire(timeout=0)
            except Timeout:
                print(f"pdr: waiting for another pdr process using {processed}/ ...", file=sys.stderr)
                lock.acquire()
    except OSError:
        pass
    try:
        yield
    finally:
        if lock.is_locked:
            lock.release()
