"""No dead code in pipeline/: vulture finds nothing at 80 % confidence (unused imports, variables, arguments
and unreachable code; at that confidence a finding is dead, not a name only reached by reflection)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pipeline

CONFIDENCE = 80


def test_vulture_finds_no_dead_code():
    root = Path(pipeline.__file__).parent
    done = subprocess.run([sys.executable, "-m", "vulture", str(root), "--min-confidence", str(CONFIDENCE)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout == "", done.stdout + done.stderr


def test_vulture_would_report_dead_code(tmp_path):
    """The check can fail: an unused import in a module is reported."""
    (tmp_path / "dead.py").write_text("import os\n\n\ndef f(x):\n    return x\n\n\nprint(f(2))\n")
    done = subprocess.run([sys.executable, "-m", "vulture", str(tmp_path), "--min-confidence", str(CONFIDENCE)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode != 0 and "unused import 'os'" in done.stdout
