"""Draining a work queue in batches: what a consumer thread behind a producer does each time it wakes."""

from __future__ import annotations

import queue


def next_batch(q: queue.Queue) -> list:
    """Block for one item, then take every item already waiting (a consumer that falls behind catches up
    in one pass instead of one wake-up per item)."""
    batch = [q.get()]
    while True:
        try:
            batch.append(q.get_nowait())
        except queue.Empty:
            return batch
