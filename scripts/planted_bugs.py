"""The planted bugs of issue 17 (and two boundary ones): apply each to the source, run the tests that
should catch it, restore the file.  Prints "caught" or "SURVIVED" per bug; exit 1 if any survived.

Run from the repository root: .venv/bin/python scripts/planted_bugs.py [NAME-SUBSTRING ...]
(rewrites files under pipeline/ while it runs: not while other work is going on in the tree).
"""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BUGS = [
    ("friction b|w|", "pipeline/derive/energy.py", "p.b * omega ** 2", "p.b * np.abs(omega)", "tests/derive"),
    ("kinetic doubled", "pipeline/derive/energy.py", "kinetic = _change(0.5 * p.J", "kinetic = _change(1.0 * p.J", "tests/derive"),
    ("spring sign", "pipeline/derive/energy.py", "spring = _change(", "spring = -_change(", "tests/derive"),
    ("gate skips closed loop", "pipeline/validate/gate.py", "    for way in WAYS:\n        for sig in SIGNALS:\n            e = validation",
     "    for way in WAYS[:1]:\n        for sig in SIGNALS:\n            e = validation", "tests/validate/test_gate.py"),
    ("oscillation_error sign", "pipeline/validate/compare.py", "_difference(osc, meas_osc, osc_keys)", "_difference(meas_osc, osc, osc_keys)", "tests/validate"),
    ("paper_pct vs simulated", "pipeline/validate/compare.py", "(e_sim - e_meas) / e_meas", "(e_sim - e_meas) / e_sim", "tests/validate"),
    ("centre (hi-lo)/2", "pipeline/derive/cycles.py", '"center_rad": (hi + lo) / 2.0', '"center_rad": (hi - lo) / 2.0', "tests/derive"),
    ("guard >= as > (phases)", "pipeline/derive/phases.py", 'd * theta[nxt] >= guard_rad', 'd * theta[nxt] > guard_rad', "tests/derive/test_phases.py"),
    ("guard >= as > (the sketch's rule)", "pipeline/model/loop.py", "if current_dir >= 0 and theta >= guard:",
     "if current_dir >= 0 and theta > guard:", "tests/derive/test_phases.py"),
    ("gate <= as <", "pipeline/validate/gate.py", "self.mse <= self.threshold", "self.mse < self.threshold", "tests/validate/test_gate.py"),
]
only = sys.argv[1:]
survived = 0
for name, rel, old, new, tests in BUGS:
    if only and not any(o in name for o in only):
        continue
    path = ROOT / rel
    src = path.read_text()
    assert src.count(old) == 1, (name, src.count(old))
    path.write_text(src.replace(old, new))
    try:
        r = subprocess.run([str(ROOT / ".venv/bin/python"), "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", tests],
                           cwd=ROOT, capture_output=True, text=True)
    finally:
        path.write_text(src)
    last = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else r.stderr[-200:]
    survived += r.returncode == 0
    print(f"{'caught  ' if r.returncode else 'SURVIVED'} {name}: {last}", flush=True)
sys.exit(1 if survived else 0)
