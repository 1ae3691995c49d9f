"""numba's kernels compiled once per machine: a second checkout of the same kernels loads them from the user's
cache directory, a checkout whose kernels differ (a sibling a kernel calls included) compiles its own."""

from __future__ import annotations

import pytest
import json
import os
import subprocess
import sys
from pathlib import Path

from pipeline.jit_cache import LOCATORS, user_cache_dir

KERNEL = '''
from numba import njit

from helper import twice


@njit(cache=True)
def kernel(x):
    return twice(x) + 1
'''
HELPER = "from numba import njit\n\n\n@njit(cache=True)\ndef twice(x):\n    return {factor} * x\n"
RUN = ("import json, kernel; r = kernel.kernel(3); "
       "s = kernel.kernel.stats; print(json.dumps([r, sum(s.cache_hits.values()), sum(s.cache_misses.values())]))")


def _checkout(root: Path, factor: int = 2) -> Path:
    """A package directory of two kernel modules, the one calling the other (as loop.py and linear.py)."""
    folder = root / "kernels"
    folder.mkdir(parents=True)
    (folder / "kernel.py").write_text(KERNEL)
    (folder / "helper.py").write_text(HELPER.format(factor=factor))
    return folder


def _run(folder: Path, cache: Path) -> tuple[int, bool]:
    """The kernel's result and whether it was loaded from the cache, in a fresh process of that checkout."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(XDG_CACHE_HOME=str(cache), PYTHONPATH=f"{folder}{os.pathsep}{Path(__file__).resolve().parents[1]}")
    code = "import pipeline; " + RUN                      # importing pipeline sets numba up, as pdr does
    out = subprocess.run([sys.executable, "-c", code], cwd=folder, env=env, capture_output=True, text=True,
                         timeout=120, check=True).stdout
    result, hits, misses = json.loads(out)
    return result, hits > 0 and misses == 0


def test_the_cache_is_under_the_users_cache_directory():
    assert user_cache_dir({"XDG_CACHE_HOME": "/c"}) == Path("/c/pdr/numba")
    assert user_cache_dir({"HOME": "/h"}).parts[-3:] == (".cache", "pdr", "numba")
    assert user_cache_dir({"NUMBA_CACHE_DIR": "/n", "XDG_CACHE_HOME": "/c"}) == Path("/n")
    assert os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] == LOCATORS          # set by importing pipeline


@pytest.mark.long
def test_a_second_checkout_loads_the_first_ones_kernels_and_a_changed_one_compiles_its_own(tmp_path):
    cache = tmp_path / "cache"
    assert _run(_checkout(tmp_path / "a"), cache) == (7, False)              # compiled
    assert _run(_checkout(tmp_path / "b"), cache) == (7, True)               # another path, same kernels
    assert any((cache / "pdr" / "numba").glob("kernels-*/kernel.kernel-*.nbi"))
    assert _run(_checkout(tmp_path / "c", factor=3), cache) == (10, False)   # a changed sibling: not the old one
    assert _run(_checkout(tmp_path / "d"), cache) == (7, True)               # and the first is still there
