"""The firmware closes the loop with the model: simavr runs the built sketch (cosim.c, libsimavr) with
its encoder pins, current sensor input and H-bridge outputs wired to the model's plant (the paper's rig,
the sketch's own TOML), stepped exactly (the model's zero-order hold) every 200 us of simulated time.
What the firmware prints is a recording `pdr ingest` accepts, it reverses on exactly the samples where
the model's controller reverses on the same counts, and the model's own closed loop at those sample
instants reverses on the same samples."""

from __future__ import annotations

import json
import math
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.config import resolve_config
from pipeline.model import loop
from pipeline.model.linear import phi_gamma_into
from pipeline.model.simulate import simulate
from tests.firmware import sketch
from tests.firmware.toolchain import build_cosim

PDR = str(Path(sys.executable).parent / "pdr")
SIMULATED_S = 11.0
QUANTUM_S = 200e-6


pytestmark = [pytest.mark.slow, pytest.mark.long]


@pytest.fixture(scope="module")
def recording(firmware, tmp_path_factory) -> Path:
    """raw/ with logger.csv (the firmware's UART, byte for byte) and the sketch's logger.toml."""
    wired = {"ENCODER_A_PIN": "2", "ENCODER_B_PIN": "3", "CURRENT_SENSOR_PIN": "A0", "DRIVE_DIR_PIN": "7",
             "DRIVE_PWM_PIN": "9"}
    assert {k: sketch.settings()[k] for k in wired} == wired, "cosim.c wires the pins docs/RIG.md gives"
    build = tmp_path_factory.mktemp("cosim")
    elf, cosim = firmware[0], build_cosim(build)
    raw = build / "raw"
    raw.mkdir()
    (raw / "logger.toml").write_text(sketch.toml_text(), encoding="utf-8")
    plant_loop(cosim, elf, raw / "logger.csv", resolve_config([raw / "logger.toml"]))
    return raw


def plant_loop(cosim: Path, elf: Path, uart_out: Path, cfg) -> None:
    """Answer the simulated UNO every quantum: the count and ACS712 voltage now, then the plant stepped
    over the next quantum with the command its pins drive (so a command reaches the motor <= 200 us late)."""
    spec = cfg.plant_spec()
    A, B = spec.params.state_matrices()
    zoh = np.empty(12)
    phi_gamma_into(A, B, QUANTUM_S, zoh)
    phi, gamma = zoh[:9].reshape(3, 3), zoh[9:]
    edges_per_rad = cfg.encoder.counts_per_rev / (2 * math.pi)
    mv_per_a = 1000 * cfg.current_sensor.sensitivity_v_per_a
    x = np.zeros(3)                                          # current, omega, delta: at rest
    # its own stderr file: inheriting pytest's captured stderr made the harness exit at once
    errors = uart_out.with_name("cosim.stderr")
    with errors.open("wb") as err:
        proc = subprocess.Popen([str(cosim), str(elf), str(SIMULATED_S), str(QUANTUM_S * 1e6), str(uart_out)],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, bufsize=0)
    fin, fout = proc.stdout.fileno(), proc.stdin.fileno()
    try:
        while command := os.read(fin, 1):
            count = math.floor(x[2] / spec.params.R * edges_per_rad)
            try:
                os.write(fout, struct.pack("<ii", count, round(2500 + mv_per_a * x[0])))
            except BrokenPipeError:      # the harness ended early: its status and stderr say why, below
                break
            x = phi @ x + gamma * (struct.unpack("b", command)[0] * spec.v_drive)
    finally:
        proc.stdin.close()
        proc.stdout.close()
        rc = proc.wait(timeout=30)
        assert rc == 0, (rc, errors.read_bytes()[-3000:])


@pytest.fixture(scope="module")
def signals(recording, tmp_path_factory):
    """What `pdr ingest` makes of the recording (asserting it was accepted whole)."""
    processed = tmp_path_factory.mktemp("processed")
    done = subprocess.run([PDR, "ingest", str(recording / "logger.csv"), "-o", str(processed), "-q"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    report = json.loads((processed / "logger" / "ingest_report.json").read_text())
    assert report["quarantined"] == [] and report["rows"]["kept"] >= 200
    return pq.read_table(processed / "logger" / "signals.parquet").to_pandas()


def test_the_closed_loop_firmware_writes_a_recording_pdr_ingest_accepts(signals):
    lead_in = int(sketch.number("LEAD_IN_MS") // sketch.number("PERIOD_MS"))
    d = signals["dir"].to_numpy()
    assert np.all(d[:lead_in] == 0) and np.all(d[lead_in:] != 0)
    assert np.count_nonzero(np.diff(d[lead_in:])) >= 4                        # it swings from guard to guard
    assert np.all(np.abs(signals["current_a"].to_numpy()[:lead_in]) < 0.03)   # the zero, read at rest


def test_the_firmware_reverses_where_the_models_controller_does_on_its_counts(signals, recording):
    counts, dirs = signals["counts"].to_numpy(), signals["dir"].to_numpy()
    cfg = resolve_config([recording / "logger.toml"])
    c = loop.Controller(R=1.0, guard=cfg.controller.guard_rad, V=1.0, v_bias=0.0, Td=0.0,
                        log=np.zeros(len(counts), dtype=np.int8), closed_loop=True, start=int(np.argmax(dirs != 0)),
                        first=0, dir0=sketch.first_dir(), continuous=False)
    theta = counts * (2 * math.pi / cfg.encoder.counts_per_rev)
    d, model = 0, []
    for k in range(len(counts)):
        d = loop.decide.py_func(c, k, d, float(theta[k]))
        model.append(d)
    assert np.array_equal(np.array(model), dirs)


def test_the_models_closed_loop_reverses_on_the_same_samples(signals, recording):
    """The model alone at the logged instants (t_ms, which millis() truncates) with the sketch's lead-in
    and first mode: the same command on every sample, the angle and current within a few ADC steps."""
    dirs = signals["dir"].to_numpy()
    cfg = resolve_config([recording / "logger.toml"])
    first = np.where(dirs == 0, 0, sketch.first_dir()).astype(np.int8)
    model = simulate(cfg.plant_spec(), signals["t_s"].to_numpy(), dir_log=first)
    assert np.array_equal(model.dir, dirs)
    assert np.max(np.abs(model.theta - signals["theta_rad"].to_numpy())) < 0.05
    assert np.max(np.abs(model.current - signals["current_a"].to_numpy())) < 0.04       # 1.5 ADC steps
