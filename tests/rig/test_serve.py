"""``pdr rig serve --pty``: the line schedule and the command's refusals (streaming itself: tests/record)."""

from __future__ import annotations

import os

import numpy as np
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.rig.serial import Artefacts
from pipeline.rig.serve import PtyRig, line_schedule

runner = CliRunner()


def test_schedule_sends_every_byte_at_the_sample_instants():
    rec = make_recording(RigSetup(duration_s=3.0, seed=6, artefacts=Artefacts(
        crlf=True, bom=True, partial_first_line=True, comments=2, garbled=3, dropped=2, reset_after_s=1.5,
        reset_gap_s=2.0)))
    sched = line_schedule(rec)
    assert b"".join(sched.lines) == rec.csv_bytes
    assert len(sched.lines) == rec.truth_meta["n_lines"]
    assert sched.at_s[0] == 0 and np.all(np.diff(sched.at_s) >= 0)
    t = rec.truth
    sent = t[t["line"] > 0].groupby("line")["t_s"].max()           # a merged line leaves with its second sample
    np.testing.assert_allclose(sched.at_s[sent.index.to_numpy() - 1], sent.to_numpy() - t["t_s"].iloc[0])
    gaps = np.diff(sched.at_s)
    assert gaps.max() >= 2.0                                          # the board sat unpowered during the reset


def test_serve_refuses_without_pty_or_with_a_bad_speed():
    res = runner.invoke(app, ["rig", "serve"])
    assert res.exit_code != 0 and "expected --pty" in str(res.exception)
    res = runner.invoke(app, ["rig", "serve", "--pty", "--speed", "0"])
    assert res.exit_code != 0 and "speed > 0" in str(res.exception)


def test_pty_sees_its_reader_come_and_go():
    rig = PtyRig()
    try:
        assert not rig.reader_present()
        reader = os.open(rig.path, os.O_RDONLY | os.O_NOCTTY)
        try:
            assert rig.reader_present()
            assert rig.send(b"0,0,511,1\n")
            assert os.read(reader, 10) == b"0,0,511,1\n"
            assert rig.unread() == 0
        finally:
            os.close(reader)
        assert not rig.wait_for_reader(0.05)
    finally:
        rig.close()
