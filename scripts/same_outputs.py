"""Check that two ``processed/`` folders hold the same outputs, byte for byte.

For changes that must not change any result (speed work): run ``pdr run`` on
the same ``raw/`` with the old code and with the new one, into two folders,
then ``python scripts/same_outputs.py OLD NEW``.  Every file must be present
in both with the same bytes, except the stamps (which hold the code version)
and the lock file (a symbolic link must name the same target); the ``.rrd`` recordings hold Rerun's write time and ids,
so they are compared by ``rerun rrd compare`` (same chunks, same data).
Exit status 1 and one line per difference otherwise.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from pipeline.validate.rerun_io import rerun_executable

SKIPPED_NAMES = {"stamp.json", ".pdr.lock"}
SKIPPED_SUFFIXES = {".rrd"}


def compared_files(root: Path, suffixes: set[str] | None = None) -> set[str]:
    """Files under ``root`` (relative names) but the skipped ones; with ``suffixes``, only those."""
    return {p.relative_to(root).as_posix() for p in root.rglob("*")
            if p.is_file() and p.name not in SKIPPED_NAMES
            and (p.suffix in suffixes if suffixes else p.suffix not in SKIPPED_SUFFIXES)}


def _link_target(path: Path) -> str | None:
    return str(path.readlink()) if path.is_symlink() else None


def rrd_differs(a: Path, b: Path) -> bool:
    return subprocess.run([rerun_executable(), "rrd", "compare", str(a), str(b)], capture_output=True).returncode != 0


def differences(old: Path, new: Path) -> list[str]:
    """One line per file that is missing on one side or differs."""
    a, b = compared_files(old), compared_files(new)
    out = [f"only in {old}: {name}" for name in sorted(a - b)] + [f"only in {new}: {name}" for name in sorted(b - a)]
    out += [f"differs: {name}" for name in sorted(a & b) if (old / name).read_bytes() != (new / name).read_bytes()]
    out += [f"links elsewhere: {name}" for name in sorted(a & b) if _link_target(old / name) != _link_target(new / name)]
    ra, rb = compared_files(old, SKIPPED_SUFFIXES), compared_files(new, SKIPPED_SUFFIXES)
    out += [f"only in {old}: {name}" for name in sorted(ra - rb)] + [f"only in {new}: {name}" for name in sorted(rb - ra)]
    out += [f"differs (rerun rrd compare): {name}" for name in sorted(ra & rb) if rrd_differs(old / name, new / name)]
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python scripts/same_outputs.py OLD_PROCESSED NEW_PROCESSED", file=sys.stderr)
        return 2
    old, new = Path(argv[0]), Path(argv[1])
    diff = differences(old, new)
    for line in diff:
        print(line)
    n, n_rrd = len(compared_files(old)), len(compared_files(old, SKIPPED_SUFFIXES))
    print(f"{n} files compared byte for byte, {n_rrd} .rrd by rerun: {'same' if not diff else f'{len(diff)} differences'}")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
