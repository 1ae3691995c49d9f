"""numba's compiled kernels cached once per machine, not once per checkout.

numba's own locators key a cache on where the source file is (``__pycache__`` beside it, or a hash of
its directory under ``NUMBA_CACHE_DIR``), so every clone compiles every kernel again (tens of seconds).
``jit_locator.SharedLocator`` keys it on what the kernels are made of instead: the kernels of one package directory
are cached under ``NUMBA_CACHE_DIR`` (default ``$XDG_CACHE_HOME/pdr/numba``, else ``~/.cache/pdr/numba``)
in a folder named after that directory and a digest of every module in it that imports numba.  Two clones
with the same kernels share one compilation; a clone whose kernels differ gets a folder of its own
(no clone overwrites another's); and a kernel is never loaded against a changed sibling it calls (numba
alone checks only the function's own file).  ``use_shared_cache`` must run before numba is imported:
``pipeline/__init__.py`` calls it, so ``pdr``, its workers, ``make`` and the tests all use it.  This module
imports no numba (every ``import pipeline`` runs it); ``jit_locator`` does, and numba imports it.
"""

from __future__ import annotations

import os
from pathlib import Path

LOCATOR_ENV = "NUMBA_CACHE_LOCATOR_CLASSES"
# ours first; numba's own (by their names in numba.core.caching) where the user cache is not writable
LOCATORS = "pipeline.jit_locator.SharedLocator,InTreeCacheLocator,UserWideCacheLocator"


def user_cache_dir(environ: dict[str, str] = os.environ) -> Path:
    """Where pdr's numba cache lives: ``NUMBA_CACHE_DIR`` if set, else the user's cache directory."""
    if environ.get("NUMBA_CACHE_DIR"):
        return Path(environ["NUMBA_CACHE_DIR"])
    base = environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "pdr" / "numba"


def use_shared_cache() -> None:
    """Point numba at ``SharedLocator`` and the user's cache directory (a caller's own settings win)."""
    os.environ.setdefault("NUMBA_CACHE_DIR", str(user_cache_dir()))
    os.environ.setdefault(LOCATOR_ENV, LOCATORS)
