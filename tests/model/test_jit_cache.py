"""numba's on-disk caches of the kernels are dropped when any of the kernel sources changes."""

import shutil
from pathlib import Path

import pipeline.model as model
from pipeline.model import KERNEL_SOURCES, drop_stale_jit_cache


def _tree(tmp_path: Path) -> Path:
    here = Path(model.__file__).parent
    for name in KERNEL_SOURCES:
        shutil.copy(here / name, tmp_path / name)
    (tmp_path / "__pycache__").mkdir()
    return tmp_path


def _cache_files(tmp_path: Path) -> list[Path]:
    files = [tmp_path / "__pycache__" / f for f in ("loop.run-80.py311.nbi",
                                                     "loop.run-80.py311.1.nbc",
                                                     "linear.phi_gamma_into-38.py311.nbi")]
    for f in files:
        f.write_bytes(b"compiled")
    return files


def test_a_change_to_a_callee_file_drops_the_callers_cache(tmp_path):
    tree = _tree(tmp_path)
    other = tree / "__pycache__" / "effects.cpython-311.pyc"
    other.write_bytes(b"not numba")
    assert drop_stale_jit_cache(tree)                       # no stamp yet
    cached = _cache_files(tree)
    assert not drop_stale_jit_cache(tree)                   # sources unchanged: caches kept
    assert all(f.exists() for f in cached)
    with open(tree / "linear.py", "a") as fh:               # only the callee changes
        fh.write("\n# edited\n")
    assert drop_stale_jit_cache(tree)
    assert not any(f.exists() for f in cached)              # the loop.py caches go too
    assert other.exists()
    assert not drop_stale_jit_cache(tree)


def test_the_installed_tree_is_stamped_with_its_sources():
    assert not drop_stale_jit_cache()                       # the import already did it
