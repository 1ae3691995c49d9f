"""The sketch's controller (firmware/pdr_logger/pdr_controller.h, compiled by the host's gcc) decides as
the model's (pipeline/model/loop.py ``decide``) on every sample of simulated runs: random effects from
the catalogue, loop delays, periods, guards, encoders (coarse ones put samples on the guard's edge
count), lead-ins and first modes.  Both see what the rig gives: the encoder's count, which the model
reads as the angle counts * 2 pi / counts_per_rev (derive's conversion)."""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass

import numpy as np
import pytest

from pipeline.model import loop
from pipeline.model.effects import make_effect
from pipeline.model.params import ControllerParams, DriveParams, ModelParams, build_spec
from pipeline.model.simulate import simulate
from pipeline.rig.randomised import DECODING, ENCODER_LINES, GEARBOX, draw_effects
from tests.firmware.sketch import guard_counts
from tests.firmware.toolchain import build_host_driver

RUNS = 220


@pytest.fixture(scope="module")
def sketch(tmp_path_factory) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(build_host_driver(tmp_path_factory.mktemp("host"))))
    i8p, i32p = np.ctypeslib.ndpointer(np.int8, flags="C"), np.ctypeslib.ndpointer(np.int32, flags="C")
    lib.pdr_commands.argtypes = [i32p, ctypes.c_int32, ctypes.c_uint32, ctypes.c_int32, ctypes.c_int8, i8p]
    lib.pdr_commands.restype = None
    lib.pdr_decode.argtypes = [np.ctypeslib.ndpointer(np.uint8, flags="C"), ctypes.c_int32]
    lib.pdr_decode.restype = ctypes.c_int32
    return lib


@dataclass(frozen=True)
class Run:
    counts: np.ndarray          # int32, the encoder's count at each sample
    counts_per_rev: float
    guard_rad: float
    lead_in: int                # motor-off samples before the controller starts
    first_dir: int


def simulated_run(rng: np.random.Generator) -> Run:
    """A closed-loop run of the model with drawn effects and loop delay, as its encoder counts it."""
    period = int(rng.integers(10, 101)) / 1000.0
    guard = 2 * math.pi * float(rng.uniform(0.08, 0.2))
    effects, _ = draw_effects(rng)
    if rng.random() < 0.75:
        effects += (make_effect("loop_delay", {"Td": float(rng.uniform(0.0, 2.0 * period))}),)
    spec = build_spec(ModelParams(), ControllerParams(period_s=period, guard_rad=guard),
                      DriveParams(v_in=float(rng.uniform(5.0, 12.0))), effects)
    n = int(rng.integers(100, 600))
    lead_in, first_dir = int(rng.integers(0, 40)), int(rng.choice((1, -1)))
    log = np.zeros(n, dtype=np.int8)
    log[min(lead_in, n - 1)] = first_dir
    x0 = (0.0, 0.0, float(rng.uniform(-1.0, 1.0)) * guard * spec.params.R)
    theta = simulate(spec, np.arange(n) * period, x0=x0, dir_log=log).theta
    gearbox = GEARBOX if rng.random() < 0.5 else 1.0                 # without one: a coarse count
    cpr = round(int(rng.choice(ENCODER_LINES)) * int(rng.choice(DECODING)) * gearbox, 6)
    edges = theta * cpr / (2 * math.pi)
    counts = np.floor(edges) if rng.random() < 0.5 else np.rint(edges)
    return Run(counts.astype(np.int32), cpr, guard, lead_in, first_dir)


def model_commands(run: Run) -> np.ndarray:
    """loop.py's decisions on the run's counts, the controller as ``simulate`` builds it for the sketch
    (``decide``'s own code, run by Python: the same lines without compiling one more signature)."""
    n = len(run.counts)
    c = loop.Controller(R=1.0, guard=run.guard_rad, V=1.0, v_bias=0.0, Td=0.0, log=np.zeros(n, dtype=np.int8),
                        closed_loop=True, start=run.lead_in, first=0, dir0=run.first_dir, continuous=False)
    theta = run.counts * (2 * math.pi / run.counts_per_rev)
    dirs, d = np.empty(n, dtype=np.int8), 0
    for k in range(n):
        d = dirs[k] = loop.decide.py_func(c, k, d, float(theta[k]))
    return dirs


def sketch_commands(sketch: ctypes.CDLL, run: Run) -> np.ndarray:
    dirs = np.empty(len(run.counts), dtype=np.int8)
    sketch.pdr_commands(np.ascontiguousarray(run.counts), len(run.counts), run.lead_in,
                        guard_counts(run.guard_rad, run.counts_per_rev), run.first_dir, dirs)
    return dirs


def test_the_sketch_decides_as_the_model_on_every_sample_of_simulated_runs(sketch):
    rng = np.random.default_rng(29)
    samples = switches = on_edge = 0
    for i in range(RUNS):
        run = simulated_run(rng)
        model, firmware = model_commands(run), sketch_commands(sketch, run)
        differ = np.flatnonzero(model != firmware)
        assert len(differ) == 0, (f"run {i}: first differs at sample {differ[0]}: "
                                  f"model {model[differ[0]]}, sketch {firmware[differ[0]]}")
        assert np.all(firmware[:run.lead_in] == 0) and np.all(firmware[run.lead_in:] != 0)
        g = guard_counts(run.guard_rad, run.counts_per_rev)
        samples += len(run.counts)
        switches += int(np.count_nonzero(np.diff(firmware[run.lead_in:]) != 0))
        on_edge += int(np.count_nonzero(np.isin(np.abs(run.counts), (g - 1, g))))
    assert samples > 50_000 and switches > 1000 and on_edge > 50, (samples, switches, on_edge)


def test_the_sketchs_quadrature_table_counts_every_edge_both_ways(sketch):
    """A random walk of the encoder, one edge at a time: the x4 decoding ends on the walk's position;
    a double step (an edge missed between two interrupts) is not counted either way."""
    rng = np.random.default_rng(4)
    gray = np.array([0b00, 0b01, 0b11, 0b10], dtype=np.uint8)       # A << 1 | B, one edge apart
    position = np.cumsum(rng.choice((-1, 0, 1), size=5000))
    ab = np.ascontiguousarray(gray[np.concatenate([[0], position]) % 4])
    assert sketch.pdr_decode(ab, len(ab)) == position[-1]
    jump = np.ascontiguousarray(gray[[0, 2, 0, 2]])
    assert sketch.pdr_decode(jump, len(jump)) == 0
