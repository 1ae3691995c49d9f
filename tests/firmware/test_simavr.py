"""The built firmware runs in simavr (an ATmega328P at 16 MHz, nothing on its pins) for about 8 s of wall
time, and what its UART prints is a recording `pdr ingest` accepts with the sketch's own TOML: the header,
the lead-in rows at rest (dir 0), then q1 (the encoder stays at 0, short of the guard), a stamp every
period_s that does not drift."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from tests.firmware import sketch

pytestmark = pytest.mark.long      # simavr runs the firmware ~8 s wall: make test-all and CI

PDR = str(Path(sys.executable).parent / "pdr")
WALL_S = 8.0
_COLOUR = re.compile(rb"\x1b\[[0-9;]*m")


def uart_bytes(simavr_log: bytes) -> bytes:
    """What the firmware sent: simavr prints each UART line when its '\\n' arrives, coloured, with every
    control character (the '\\n' itself) shown as '.'; the sketch sends printable ASCII and '\\n' only."""
    lines = _COLOUR.sub(b"", simavr_log).split(b"\n")
    return b"".join(line[:-1] + b"\n" for line in lines if line.endswith(b"."))


def run_simavr(elf: Path, log: Path) -> bytes:
    with log.open("wb") as out:
        proc = subprocess.Popen(["simavr", "-m", "atmega328p", "-f", "16000000", str(elf)],
                                stdout=out, stderr=out)
        try:
            proc.wait(timeout=WALL_S)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=10)
    return uart_bytes(log.read_bytes())


@pytest.mark.slow
def test_the_firmware_in_simavr_prints_a_recording_pdr_ingest_accepts(firmware, tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "logger.csv").write_bytes(run_simavr(firmware[0], tmp_path / "simavr.log"))
    (raw / "logger.toml").write_text(sketch.toml_text(), encoding="utf-8")
    lines = (raw / "logger.csv").read_text().splitlines()
    assert lines[0].startswith("# pdr_logger ") and lines[1] == "t_ms,counts,adc,dir"
    assert len(lines) >= 22 and all(re.fullmatch(r"\d+,-?\d+,\d+,-?[01]", line) for line in lines[2:])

    done = subprocess.run([PDR, "ingest", str(raw / "logger.csv"), "-o", str(tmp_path / "processed"), "-q"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    report = json.loads((tmp_path / "processed" / "logger" / "ingest_report.json").read_text())
    assert report["quarantined"] == [] and report["rows"]["kept"] == len(lines) - 2
    assert report["lines"]["header"] == [2] and report["board_resets"] == 0

    signals = pq.read_table(tmp_path / "processed" / "logger" / "signals.parquet").to_pandas()
    period_ms, lead_in_ms = sketch.number("PERIOD_MS"), sketch.number("LEAD_IN_MS")
    lead_in = int(lead_in_ms // period_ms)
    assert list(signals["dir"].iloc[:lead_in]) == [0] * lead_in            # motor off, at rest
    assert set(signals["dir"].iloc[lead_in:]) == {1}                         # q1, the guard never reached
    assert set(signals["counts"]) == {0}
    stamps = signals["t_raw"].to_numpy()
    k = np.arange(len(stamps))
    assert np.all(np.abs(stamps - stamps[0] - k * period_ms) <= 2)        # millis() steps, no drift
    np.testing.assert_allclose(np.diff(signals["t_s"].to_numpy()), period_ms / 1000, atol=0.002)
