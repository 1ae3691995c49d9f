"""``SharedLocator``: numba's cache of a package directory's kernels in the user's cache directory, keyed on
those kernels' sources (``pipeline.jit_cache`` says why; numba imports this module by the name
``jit_cache.LOCATORS`` gives it).  It builds on numba's own locator classes, which are private:
pyproject pins numba below 0.70, whose ``numba.core.caching`` has them as used here."""

from __future__ import annotations

import functools
import hashlib
import re
from pathlib import Path

from numba.core.caching import _CacheLocator, _SourceFileBackedLocatorMixin

from pipeline.jit_cache import user_cache_dir

_IMPORTS_NUMBA = re.compile(rb"^\s*(from numba\b|import numba\b)", re.MULTILINE)


@functools.lru_cache(maxsize=None)
def kernel_digest(directory: str, stamps: tuple) -> str:
    """SHA-256 over the modules of ``directory`` that import numba (``stamps``: their mtimes and sizes,
    so an edit while a process runs is seen)."""
    h = hashlib.sha256()
    for path in sorted(Path(directory).glob("*.py")):
        data = path.read_bytes()
        if _IMPORTS_NUMBA.search(data):
            h.update(path.name.encode() + b"\0" + data)
    return h.hexdigest()


def _stamps(directory: Path) -> tuple:
    return tuple((p.name, p.stat().st_mtime_ns, p.stat().st_size) for p in sorted(directory.glob("*.py")))


class SharedLocator(_SourceFileBackedLocatorMixin, _CacheLocator):
    """A numba cache locator: ``<cache dir>/<package dir name>-<kernel digest>/`` (see the module doc)."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        directory = Path(py_file).resolve().parent
        self._digest = kernel_digest(str(directory), _stamps(directory))
        self._cache_path = str(user_cache_dir() / f"{directory.name}-{self._digest[:16]}")

    def get_cache_path(self) -> str:
        return self._cache_path

    def get_source_stamp(self) -> str:
        return self._digest
