"""Generated raw folders: good recordings mixed with bad entries, links, FIFOs, repeated lines and glitches.
In every folder: no traceback, each good recording's outputs as when processed alone, raw/ unchanged."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.run import run_pipeline
from tests.hostile.folders import CODE, good_csv, no_traceback, snapshot, with_count_glitch, with_line_repeated


def _dir(raw, name):
    (raw / name).mkdir()


def _fifo(raw, name):
    os.mkfifo(raw / name)


BAD = {
    # maker(raw, name) -> what the entry is; each is refused or fails in one line
    "directory": _dir,
    "fifo": _fifo,
    "dangling": lambda raw, name: (raw / name).symlink_to(raw / "nowhere"),
    "loop": lambda raw, name: (raw / name).symlink_to(raw / name),
    "device": lambda raw, name: (raw / name).symlink_to("/dev/zero"),
    "empty": lambda raw, name: (raw / name).write_bytes(b""),
    "binary": lambda raw, name: (raw / name).write_bytes(bytes(range(256)) * 8),
    "text": lambda raw, name: (raw / name).write_text("hello\nworld\n"),
    "reserved": lambda raw, name: (raw / "discovery.csv").write_bytes(good_csv(0)),
    "segment name": lambda raw, name: (raw / "good1-seg2.csv").write_bytes(good_csv(1)),
    "case twin": lambda raw, name: (raw / "GOOD0.csv").write_bytes(good_csv(0)),
    "toml fifo": lambda raw, name: ((raw / name).write_bytes(good_csv(1)), os.mkfifo(raw / (name[:-4] + ".toml"))),
    "toml folder": lambda raw, name: ((raw / name).write_bytes(good_csv(0)), (raw / (name[:-4] + ".toml")).mkdir()),
}
# damaged but usable: processed, with the damage quarantined
DAMAGED = {"repeated line": lambda k: with_line_repeated(good_csv(1), k),
           "count glitch": lambda k: with_count_glitch(good_csv(0), k)}

folders = st.fixed_dictionaries({
    "goods": st.sets(st.sampled_from([0, 1]), min_size=1),
    "bad": st.lists(st.sampled_from(sorted(BAD)), max_size=4, unique=True),
    "damaged": st.lists(st.tuples(st.sampled_from(sorted(DAMAGED)), st.integers(5, 90)), max_size=2,
                        unique_by=lambda d: d[0]),
    "symlinked_good": st.booleans(),
})


@pytest.mark.slow
@settings(max_examples=4, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(folder=folders)
def test_generated_raw_folders(workspace, folder):
    for seed in folder["goods"]:
        workspace.alone(seed)
    raw = workspace.fresh_raw()
    for seed in folder["goods"]:
        (raw / f"good{seed}.csv").write_bytes(good_csv(seed))
    bad_names, damaged = [], []
    for k, kind in enumerate(folder["bad"]):
        name = {"reserved": "discovery.csv", "segment name": "good1-seg2.csv", "case twin": "GOOD0.csv"}.get(
            kind, f"bad{k}.csv")
        BAD[kind](raw, name)
        # a case twin is refused beside good0.csv; alone, it is a good recording of its own
        (damaged if kind == "case twin" and 0 not in folder["goods"] else bad_names).append(name)
    for kind, k in folder["damaged"]:
        name = f"damaged_{kind.replace(' ', '_')}.csv"
        (raw / name).write_bytes(DAMAGED[kind](k))
        damaged.append(name)
    if folder["symlinked_good"]:
        (raw / "linked.csv").symlink_to(raw / f"good{min(folder['goods'])}.csv")
        damaged.append("linked.csv")
    before = snapshot(raw)
    processed = workspace.processed()
    report = run_pipeline(raw, processed, jobs=1, code=CODE)
    status = {r["recording"]: r for r in report.ran}
    for r in report.ran:
        no_traceback(r["error"] or "")
        assert "\n" not in (r["error"] or "")
    for seed in folder["goods"]:
        assert status[f"good{seed}.csv"]["status"] == "ok", status
        workspace.assert_as_alone(processed, seed)
    for name in damaged:
        assert status[name]["status"] == "ok", status[name]
    for name in bad_names:
        assert status[name]["status"] == "failed", (name, status)
    assert snapshot(raw) == before
