"""Virtual-rig recordings whose start is a nuisance: logging opened while the rig was running,
a noisy first current reading, a loop delay with a command in flight at the first sample.

Each goes through the virtual rig's own plant and sensor chain (``pipeline.rig``), is written
as a CSV + TOML, ingested and derived like a user's recording.  A late start is made the way
it happens on the bench: the board has been running (``pre_roll_s`` of motor-off, then the
controller), and the capture holds only the lines printed after ``open_s`` (millis() and the
encoder count carry on from where the board is).
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.config import RigConfig, default_config
from pipeline.model.effects import Effect

SHIPPED_NOISE_V = 5.0 / 1024        # the rig's default sensor + ADC noise, V


def sensor_config(sensitivity_v_per_a: float, config: RigConfig | None = None) -> RigConfig:
    """The rig with another ACS712 part (0.185, 0.100 or 0.066 V/A)."""
    cfg = config if config is not None else default_config()
    return replace(cfg, current_sensor=replace(cfg.current_sensor, sensitivity_v_per_a=sensitivity_v_per_a))


def _late_capture(csv: bytes, first_ms: int) -> bytes:
    """The header and the data lines printed from millis() = ``first_ms`` on."""
    lines = csv.decode().splitlines(keepends=True)
    header, rows = lines[0], lines[1:]
    return (header + "".join(r for r in rows if int(r.split(",")[0]) >= first_ms)).encode()


def _opening(truth: pd.DataFrame, open_s: float, after_switch: int | None) -> int:
    """Index of the first sample the capture keeps: ``open_s`` into the run, or ``after_switch``
    samples after the controller's third reversal (so that, under a loop delay, a reversed
    command is still on its way to the motor at the first sample)."""
    if after_switch is None:
        return int(np.searchsorted(truth["t_ms"].to_numpy() - truth["t_ms"].iloc[0], 1000.0 * open_s))
    d = truth["dir"].to_numpy()
    switches = np.flatnonzero((d[1:] != d[:-1]) & (d[:-1] != 0)) + 1
    return int(switches[2] + after_switch)


def _first_current(csv: bytes, adc_shift: int) -> bytes:
    """The capture with the first data line's ADC reading moved by ``adc_shift`` steps."""
    lines = csv.decode().splitlines(keepends=True)
    t, counts, adc, rest = lines[1].split(",", 3)
    lines[1] = ",".join((t, counts, str(int(adc) + adc_shift), rest))
    return "".join(lines).encode()


def rig_case(effects: tuple[Effect, ...] = (), *, seed: int = 0, open_s: float = 0.0, after_switch: int | None = None,
             first_adc_shift: int = 0, config: RigConfig | None = None, work: Path | None = None,
             **setup) -> tuple[pd.DataFrame, RigConfig, pd.DataFrame]:
    """(kinematics, rig config, ground truth of the samples kept) of one virtual-rig capture.

    ``open_s`` / ``after_switch``: the capture opens late (``_opening``); ``first_adc_shift``:
    the first kept line's ADC reading moves by that many steps (a noisy first current sample)."""
    from pipeline.derive.stage import derive_run
    from pipeline.ingest.stage import ingest_recording
    from pipeline.rig.recording import RigSetup, make_recording, write_recording
    from pipeline.runs import load_config

    work = Path(work) if work is not None else Path(tempfile.mkdtemp(prefix="pdr-nuisance-"))
    rec = make_recording(RigSetup(effects=tuple(effects), config=config or default_config(), **setup), seed=seed)
    csv = rec.csv_bytes
    truth = rec.truth
    if open_s > 0 or after_switch is not None:
        k = _opening(truth, open_s, after_switch)
        csv = _late_capture(csv, int(truth["t_ms"].iloc[k]))
        truth = truth.iloc[k:].reset_index(drop=True)
    if first_adc_shift:
        csv = _first_current(csv, first_adc_shift)
    rec = replace(rec, csv_bytes=csv)
    write_recording(rec, work / "raw", "rec")
    paths = ingest_recording(work / "raw" / "rec.csv", work / "processed").runs[0]
    derive_run(paths)
    return pd.read_parquet(paths.kinematics), load_config(paths), truth
