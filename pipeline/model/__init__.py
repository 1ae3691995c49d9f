"""The hybrid model.  On import: drop numba's on-disk caches of the compiled kernels when their sources changed.

numba (``cache=True``) invalidates a cached function only when its own file
changes, not when a function it calls from another file does: after an edit
to ``loop.py`` the cached ``linear.run_zoh`` would go on running the old
controller loop it was compiled with.  The kernels span five files, so a
digest of all five is kept beside the caches, and any change removes
every cache of those files (the next call recompiles, ~30 s).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

KERNEL_SOURCES = ("loop.py", "linear.py", "modal.py", "nonsmooth.py", "event_step.py")


def drop_stale_jit_cache(here: Path = Path(__file__).resolve().parent) -> bool:
    """Remove numba's cache files of the kernel sources if the sources differ from the last stamp; True if removed.

    Only numba's in-tree cache (``__pycache__`` beside the sources, its fallback where the user's cache
    directory is not writable) is looked after here; ``pipeline.jit_locator`` keys the shared cache on
    every kernel source already.
    """
    digest = hashlib.sha256(b"".join((here / name).read_bytes() for name in KERNEL_SOURCES)).hexdigest()
    cache = here / "__pycache__"
    stamp = cache / "numba-kernel-sources.sha256"
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for name in KERNEL_SOURCES:
            for path in cache.glob(f"{Path(name).stem}.*.nb[ic]"):
                path.unlink(missing_ok=True)
        tmp = stamp.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(digest)
        tmp.replace(stamp)                    # atomic: a concurrent process reads the old or the new stamp
    except OSError:
        return False                          # read-only install: numba falls back to its own cache directory
    return True


drop_stale_jit_cache()
