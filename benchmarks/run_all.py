"""``make bench``: every ``benchmarks/bench_*.py`` in name order, each ``main()`` under a header.

A benchmark that fails is reported and the others still run; the exit status
is non-zero if any failed.
"""

from __future__ import annotations

import importlib
import sys
import time
import traceback
from pathlib import Path


def benchmark_modules(folder: Path = Path(__file__).parent) -> list[str]:
    return [f"benchmarks.{p.stem}" for p in sorted(folder.glob("bench_*.py"))]


def main() -> int:
    failed = []
    for name in benchmark_modules():
        print(f"\n=== {name} ===", flush=True)
        t0 = time.perf_counter()
        try:
            importlib.import_module(name).main()
        except Exception:                                  # report, keep going
            traceback.print_exc()
            failed.append(name)
        print(f"--- {name}: {time.perf_counter() - t0:.1f} s", flush=True)
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
