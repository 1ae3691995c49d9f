"""pipeline.api: the README example runs and prints what it says; runs load back as the stages wrote them."""

import contextlib
import io
import re
from pathlib import Path

import pandas as pd
import pytest

from pipeline import api
from pipeline.errors import PdrError
from pipeline.validate.stage import validate_run
from tests.validate.synthetic import synthetic_kinematics, synthetic_run

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_readme_example_prints_what_its_comments_say():
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Python API (notebooks)"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    expected = [line[2:] for line in code.splitlines() if line.startswith("# ")]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, str(README), "exec"), {})
    assert out.getvalue().splitlines() == expected


def test_runs_load_back_with_their_tables_and_documents(tmp_path):
    processed = tmp_path / "processed"
    for name, seed in (("a", 0), ("b", 1)):
        validate_run(synthetic_run(processed, name, kin=synthetic_kinematics(duration=3.0, seed=seed,
                                                                             current_noise_a=0.02)),
                     rrd=False, png=False)
    runs = api.load_runs(processed)
    assert list(runs) == ["a", "b"]
    a = runs["a"]
    assert a.validation["run"] == "a" and a.summary is None and a.signals is None     # derive was not run
    pd.testing.assert_frame_equal(a.kinematics, pd.read_parquet(processed / "a" / "kinematics.parquet"))
    assert a.config.controller.guard_rad == pytest.approx(0.9424777960769379)
    both = api.concat(runs, "comparison")
    assert both.columns[0] == "run" and len(both) == len(a.comparison) + len(runs["b"].comparison)
    assert both.loc[both["run"] == "b", "theta_rad"].tolist() == runs["b"].comparison["theta_rad"].tolist()
    assert api.load_run(processed / "b").name == "b"
    with pytest.raises(PdrError, match="no rig.json"):
        api.load_run("missing", processed)
    with pytest.raises(PdrError, match="unknown table"):
        api.concat(runs, "nope")


def test_simulate_rig_applies_effects_and_discover_frame_refuses_a_table_without_time():
    base = api.simulate_rig(duration=5.0)
    slow = api.simulate_rig({"driver_voltage_drop": {"Vd": 2.0}}, duration=5.0)
    assert list(base.columns) == ["t_s", "theta_rad", "omega_rad_s", "current_a", "dir"]
    assert len(base) == 101 and slow["omega_rad_s"].abs().max() < base["omega_rad_s"].abs().max()
    with pytest.raises(PdrError, match="expected column 't_s'"):
        api.discover_frame(base.drop(columns=["t_s"]))
