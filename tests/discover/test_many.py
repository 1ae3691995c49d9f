"""``pdr discover`` on several recordings: a row per run in summary.csv, the pooled estimate per rig and
effect in pooled.csv, the parameter plot, each run's own outputs, and a bad recording reported without
stopping the others."""

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest
from PIL import Image

from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.rig.recording import RigSetup, make_recording, write_recording

PDR = str(Path(sys.executable).with_name("pdr"))
B_TRUE = 7.7e-4
DAY = 86400.0
T0 = 1.7e9


def make_b_rig(raw: Path, count: int, first_seed: int = 300) -> list[Path]:
    """Recordings of one rig whose TOML says b = 0 while the rig has b = 7.7e-4 (the paper's story),
    one a day (file modification times), each with its own noise."""
    base = default_config()
    base = replace(base, model=base.model.with_(b=0.0))
    out = []
    for i in range(count):
        rec = make_recording(RigSetup(effects=(make_effect("viscous_friction", {"b": B_TRUE}),), config=base,
                                      duration_s=10.0), seed=first_seed + i)
        name = f"day{i:02d}"
        paths = write_recording(rec, raw, name)
        os.utime(paths["csv"], (T0 + i * DAY, T0 + i * DAY))
        out.append(paths["csv"])
    return out


@pytest.mark.long
@pytest.mark.slow
def test_discover_many_pools_one_rig_and_reports_a_bad_recording(tmp_path):
    raw = tmp_path / "raw"
    csvs = make_b_rig(raw, 2)
    (raw / "garbage.csv").write_text("not a capture\n")
    out = tmp_path / "disc"
    proc = subprocess.run([PDR, "discover", *map(str, csvs), str(raw / "garbage.csv"), "--out", str(out),
                           "--no-rrd", "--json", "-j", "1"], capture_output=True, text=True)
    assert proc.returncode == 1, proc.stderr           # one recording failed
    doc = json.loads(proc.stdout)
    summary = pd.read_csv(out / "summary.csv")
    assert list(summary["run"]) == [f"day{i:02d}" for i in range(2)] + ["garbage"]     # recording order
    assert list(summary["verdict"]) == ["explained"] * 2 + ["failed"]
    assert "garbage.csv" in summary["error"].iloc[-1]
    assert summary["recorded"].iloc[1] == "2023-11-15T22:13:20Z"
    assert len(doc["runs"]) == 3
    for i in range(2):
        run_doc = json.loads((out / f"day{i:02d}" / "discovery.json").read_text())
        b = run_doc["effects"][0]
        assert b["name"] == "viscous_friction"
        assert summary["viscous_friction.b"].iloc[i] == pytest.approx(b["parameters"]["b"], rel=1e-7)

    pooled = pd.read_csv(out / "pooled.csv")
    assert len(pooled) == 1
    row = pooled.iloc[0]
    assert (row["effect"], row["parameter"], row["runs_found"]) == ("viscous_friction", "b", 2)
    assert row["lo"] <= B_TRUE <= row["hi"]
    assert row["hi"] - row["lo"] < min(summary["viscous_friction.b_hi"] - summary["viscous_friction.b_lo"])
    assert not row["trend_flagged"]
    with Image.open(out / "parameters.png") as im:
        assert im.size[0] > 300 and im.size[1] > 150


def test_recordings_that_would_share_a_run_name_or_are_not_raw_files_are_refused(tmp_path):
    from pipeline.discover.many import _jobs

    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "day.csv").write_text("t_ms,counts\n0,0\n")
    jobs, failed = _jobs([tmp_path / "a" / "day.csv", tmp_path / "b" / "day.csv", tmp_path / "missing.csv"])
    assert [job.source for job, _mtime in jobs] == [str(tmp_path / "a" / "day.csv")]
    assert failed[0]["error"].startswith(f"{tmp_path / 'b' / 'day.csv'}: has the name of {tmp_path / 'a' / 'day.csv'}")
    assert failed[1]["error"] == f"{tmp_path / 'missing.csv'}: expected a raw .csv recording (several recordings: raw files only)"
