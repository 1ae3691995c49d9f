"""The virtual rig's recording API: a synthetic capture, its rig TOML and its ground truth.

Other stages use this in their tests; the API is stable:

``RigSetup``  (frozen) what to record
    effects        tuple[Effect, ...]  hidden in the plant, never written to the TOML
    config         RigConfig           what the user believes: written to the TOML ([encoder],
                                       [current_sensor], [drive], [controller], [model], and its
                                       [effects], which the plant also has)
    duration_s     24.95               active logging (500 samples at 50 ms, the paper's run)
    pre_roll_s     1.0                 motor-off samples (dir = 0) first, so zero_v = "auto" has rest data
    noise_v        5/1024              V, sigma of the sensor + ADC noise (one ADC step)
    zero_sigma_v   0.015               V, sigma of the ACS712 part's zero around 2.5 V
    jitter_ms      0.6                 loop overrun, U(0, jitter_ms): millis() steps by 50 or 51
    zero_v         "calibrated"        what the TOML says: "calibrated" (measured at rest, 0.1 mV),
                                       "auto" or "nominal" (2.5 V)
    artefacts      Artefacts()         serial dialect/artefacts (``pipeline.rig.serial``), all off
    seed           0                   used when ``make_recording`` gets no seed
    open_after_s   0.0                 the capture opens this long after the board started: earlier
                                       samples are not in the file (logging opened mid-motion)
    first_dir      1                   the motor's first command after the pre-roll (1 or -1)
    counts_rounding "round"            the encoder count of an angle: "round" or "floor" (a counter that
                                       counts edges passed, not the nearest one)
    plant_model    None                the rig's true [model] when it differs from the TOML's in a way no
                                       catalogued effect expresses (an effect outside the catalogue)

``make_recording(setup, seed=None) -> Recording``
    ``csv_bytes`` (the capture), ``toml_text`` (the user's rig file), ``truth`` (DataFrame, one
    row per sample the board took after the capture opened, in order: sample, segment, line (1-based, 0 = dropped), status
    ("ok"/"garbled"/"dropped"), t_ms (millis()), t_raw (printed time value), t_s (true instant,
    s since the first captured sample), theta_rad, omega_rad_s, current_a, current_measured_a (I + I0),
    dir, counts, adc, v_sensor (V before the ADC), stuck), ``truth_meta`` (dict: effects, plant,
    sensor zero and noise, timing, segments, turning points, injected artefacts with line
    numbers, dropped samples).  Same setup and seed => same bytes; a 500-sample
    recording takes a few tenths of a second.
``write_recording(rec, out_dir, name)``
    ``<out_dir>/<name>.csv``, ``<name>.toml`` and ``<out_dir>/truth/<name>.truth.parquet`` + ``.json``
    (the pipeline never reads truth/).

Physics: ``pipeline.rig.plant.run_reference`` (independent of the fast simulator); a board
reset switches the motor off, the rig sits ``reset_gap_s`` unpowered (it comes to rest on
its springs), then logging restarts with millis() near 0 and the counter at 0 wherever the
pinion then is.  Random streams for timing, sensor and serial noise are separate, so
asking for an artefact never changes the physics or the sensor readings.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from pipeline.config import RigConfig, default_config
from pipeline.model.effects import Effect, PlantSpec
from pipeline.rig import sensors
from pipeline.rig.plant import run_reference
from pipeline.rig.serial import Artefacts, SerialRows, render, time_text
from pipeline.runs import check_name  # noqa: F401  (re-exported: the rig's API)

ZERO_V_MODES = ("calibrated", "auto", "nominal")
TRUTH_DIR = "truth"
# Integration tolerances for recordings: errors of a few 1e-9 rad, a millionth of an encoder
# count, at 2/3 of the cost of the reference defaults (1e-10 / 1e-12).
_TOL = {"rtol": 1e-9, "atol": 1e-11}

if TYPE_CHECKING:
    from pipeline.model.params import ModelParams


@dataclass(frozen=True)
class RigSetup:
    effects: tuple[Effect, ...] = ()
    config: RigConfig = field(default_factory=default_config)
    duration_s: float = 24.95
    pre_roll_s: float = 1.0
    noise_v: float = 5.0 / 1024
    zero_sigma_v: float = 0.015
    jitter_ms: float = 0.6
    zero_v: str = "calibrated"
    artefacts: Artefacts = Artefacts()
    seed: int = 0
    open_after_s: float = 0.0
    first_dir: int = 1
    counts_rounding: str = "round"
    plant_model: ModelParams | None = None

    def __post_init__(self) -> None:
        if self.zero_v not in ZERO_V_MODES:
            raise ValueError(f"zero_v must be one of {ZERO_V_MODES}, got {self.zero_v!r}")
        if self.first_dir not in (1, -1):
            raise ValueError(f"first_dir must be 1 or -1, got {self.first_dir!r}")
        if self.counts_rounding not in sensors.COUNT_ROUNDING:
            raise ValueError(f"counts_rounding must be one of {sensors.COUNT_ROUNDING}, got {self.counts_rounding!r}")
        if self.open_after_s < 0:
            raise ValueError(f"open_after_s must be >= 0, got {self.open_after_s}")
        if self.duration_s <= 0 or self.pre_roll_s < 0 or self.noise_v < 0 or self.zero_sigma_v < 0:
            raise ValueError("duration_s must be > 0 and pre_roll_s, noise_v, zero_sigma_v >= 0")

    def plant(self) -> PlantSpec:
        """What the virtual rig really is: the believed config plus the hidden effects (on its true [model])."""
        from dataclasses import replace

        config = self.config if self.plant_model is None else replace(self.config, model=self.plant_model)
        return config.plant_spec(tuple(self.effects))


@dataclass(frozen=True)
class Recording:
    csv_bytes: bytes
    toml_text: str
    truth: pd.DataFrame
    truth_meta: dict[str, Any]


def uncaptured_samples(setup: RigSetup, period: float) -> int:
    """Samples the board took before the capture opened (``open_after_s``)."""
    return int(round(setup.open_after_s / period))


def _sessions(setup: RigSetup, period: float) -> list[tuple[int, int]]:
    """(pre-roll samples, active samples) per logging session; the first also runs while the capture is closed."""
    n_pre = int(round(setup.pre_roll_s / period))
    n_act = int(np.floor(setup.duration_s / period + 1e-9)) + 1
    n_skip = uncaptured_samples(setup, period)
    reset = setup.artefacts.reset_after_s
    if reset is None:
        return [(n_pre, n_act + n_skip)]
    k = int(round(reset / period))
    if not n_skip < k < n_act + n_skip:
        raise ValueError(f"reset_after_s = {reset} s is outside the captured {setup.duration_s} s run")
    return [(n_pre, k), (n_pre, n_act + n_skip - k)]


def _simulate(setup: RigSetup, spec: PlantSpec, rng: np.random.Generator) -> tuple[dict[str, np.ndarray], list, list]:
    """True states at every loop instant of every session, and the plant's turning points."""
    period = spec.period_s
    R = spec.params.R
    cols: dict[str, list] = {k: [] for k in ("segment", "true_ms", "t_s", "theta", "omega", "current",
                                             "current_measured", "dir", "stuck", "theta_ref")}
    turns: list[dict] = []
    segments: list[dict] = []
    x = np.zeros(3)
    t0 = 0.0
    sessions = _sessions(setup, period)
    first = 0
    for s, (n_pre, n_act) in enumerate(sessions, start=1):
        last = s == len(sessions)
        n = n_pre + n_act
        true_ms, _ = sensors.loop_instants(n + (0 if last else 1), period, setup.jitter_ms, rng,
                                           start_ms=float(rng.uniform(0.0, 3.0)))
        t = t0 + (true_ms - true_ms[0]) / 1000.0
        dir_log = np.r_[np.zeros(n_pre, dtype=int), np.full(len(t) - n_pre, setup.first_dir, dtype=int)]
        theta_ref = float(x[2] / R)
        run = run_reference(spec, t, x0=tuple(x), dir_log=dir_log, closed_loop=True, theta_ref=theta_ref, **_TOL)
        r = run.result
        keep = slice(0, n)
        for key, arr in (("true_ms", true_ms), ("t_s", t), ("theta", r.theta), ("omega", r.omega),
                         ("current", r.current), ("current_measured", r.current_measured),
                         ("dir", r.dir), ("stuck", run.stuck)):
            cols[key].append(np.asarray(arr)[keep])
        cols["segment"].append(np.full(n, s))
        cols["theta_ref"].append(np.full(n, theta_ref))
        turns += [{"segment": s, "t_s": tp.t, "theta_rad": tp.theta, "kind": tp.kind}
                  for tp in run.turning_points if tp.t <= t[n - 1]]
        segments.append({"segment": s, "first_sample": first, "n_samples": n, "pre_roll_samples": n_pre,
                         "t_start_s": float(t[0]), "theta_ref_rad": theta_ref,
                         "millis_start": int(np.floor(true_ms[0]))})
        first += n
        if not last:                      # board reset at t[-1]: motor off, the rig settles, then logging restarts
            x = run.final_state
            gap = run_reference(spec, np.array([t[-1], t[-1] + setup.artefacts.reset_gap_s]), x0=tuple(x),
                                dir_log=np.zeros(2, dtype=int), closed_loop=False, **_TOL)
            x = gap.final_state
            t0 = float(t[-1] + setup.artefacts.reset_gap_s)
    return {k: np.concatenate(v) for k, v in cols.items()}, turns, segments


def _from_capture_start(sim: dict[str, np.ndarray], turns: list, segments: list, n_skip: int
                        ) -> tuple[dict[str, np.ndarray], list, list]:
    """Drop the samples taken before the capture opened; times count from the first captured sample."""
    if n_skip == 0:
        return sim, turns, segments
    shift = float(sim["t_s"][n_skip])
    sim = {k: v[n_skip:] for k, v in sim.items()}
    sim["t_s"] = sim["t_s"] - shift
    turns = [tp | {"t_s": tp["t_s"] - shift} for tp in turns if tp["t_s"] >= shift]
    first = segments[0] | {"n_samples": segments[0]["n_samples"] - n_skip, "uncaptured_samples": n_skip,
                           "t_start_s": 0.0, "pre_roll_samples": max(segments[0]["pre_roll_samples"] - n_skip, 0)}
    rest = [seg | {"first_sample": seg["first_sample"] - n_skip, "t_start_s": seg["t_start_s"] - shift}
            for seg in segments[1:]]
    return sim, turns, [first, *rest]


def make_recording(setup: RigSetup, seed: int | None = None) -> Recording:
    """One synthetic capture of the virtual rig (see the module docstring)."""
    seed = setup.seed if seed is None else int(seed)
    timing_rng, sensor_rng, serial_rng, wall_rng = (np.random.default_rng(s)
                                                    for s in np.random.SeedSequence(seed).spawn(4))
    cfg = setup.config
    spec = setup.plant()
    sim, turns, segments = _simulate(setup, spec, timing_rng)
    sim, turns, segments = _from_capture_start(sim, turns, segments, uncaptured_samples(setup, spec.period_s))

    cs = cfg.current_sensor
    counts = np.concatenate([
        sensors.encoder_counts(sim["theta"][sim["segment"] == seg["segment"]], cfg.encoder.counts_per_rev,
                               seg["theta_ref_rad"], setup.counts_rounding) for seg in segments])
    zero_part = sensors.part_zero_v(setup.zero_sigma_v, sensor_rng)
    v_sensor = sensors.acs712_volts(sim["current"], zero_part, cs.sensitivity_v_per_a, setup.noise_v, sensor_rng)
    adc = sensors.adc_read(v_sensor, cs.adc_vref, cs.adc_steps)
    zero_written: float | str = {
        "calibrated": lambda: sensors.calibrated_zero_v(zero_part, cs.sensitivity_v_per_a, spec.I0,
                                                        cs.adc_vref, cs.adc_steps),
        "auto": lambda: "auto",
        "nominal": lambda: sensors.NOMINAL_ZERO_V,
    }[setup.zero_v]()

    art = setup.artefacts
    wall_start = float(wall_rng.uniform(8 * 3600, 20 * 3600))       # the PC clock when logging started
    wall_s = wall_start + sim["t_s"] + 0.004 + wall_rng.uniform(0.0, 0.002, size=len(sim["t_s"]))
    rows = SerialRows(segment=sim["segment"], true_ms=sim["true_ms"], counts=counts, adc=adc,
                      dir=sim["dir"], wall_s=wall_s)
    out = render(rows, art, serial_rng)

    t_ms = np.floor(sim["true_ms"]).astype(np.int64)
    truth = pd.DataFrame({
        "sample": np.arange(len(t_ms), dtype=np.int64),
        "segment": sim["segment"].astype(np.int64),
        "line": out.line,
        "status": pd.array(out.status.astype(str), dtype="string"),
        "t_ms": t_ms,
        "t_raw": np.array([float(time_text(v, art.time_unit)) for v in sim["true_ms"]]),
        "t_s": sim["t_s"],
        "theta_rad": sim["theta"],
        "omega_rad_s": sim["omega"],
        "current_a": sim["current"],
        "current_measured_a": sim["current_measured"],
        "dir": sim["dir"].astype(np.int64),
        "counts": counts,
        "adc": adc,
        "v_sensor": v_sensor,
        "stuck": sim["stuck"].astype(bool),
    })
    meta = {
        "synthetic": True,
        "generator": "pdr rig (pipeline.rig.recording.make_recording)",
        "seed": seed,
        "hidden_effects": [e.to_json() for e in setup.effects],
        "declared_effects": [e.to_json() for e in cfg.effects],
        "plant": {"params": asdict(spec.params), "v_drive": spec.v_drive, "guard_rad": spec.guard_rad,
                  "period_s": spec.period_s, "Tc": spec.Tc, "gap": spec.gap, "Td": spec.Td, "I0": spec.I0},
        "sensor": {"zero_v_part": zero_part, "zero_v_written": zero_written, "zero_v_mode": setup.zero_v,
                   "sensitivity_v_per_a": cs.sensitivity_v_per_a, "noise_v": setup.noise_v,
                   "zero_sigma_v": setup.zero_sigma_v, "counts_per_rev": cfg.encoder.counts_per_rev,
                   "counts_rounding": setup.counts_rounding,
                   "adc_clipped_samples": int(np.sum((adc == 0) | (adc == cs.adc_steps - 1)))},
        "timing": {"period_s": spec.period_s, "jitter_ms": setup.jitter_ms, "duration_s": setup.duration_s,
                   "pre_roll_s": setup.pre_roll_s, "wall_start_s": wall_start, "open_after_s": setup.open_after_s,
                   "first_dir": setup.first_dir},
        "segments": segments,
        "turning_points": turns,
        "artefacts": {"requested": asdict(art), "injected": out.injected},
        "lines_dropped": [int(i) for i in np.flatnonzero(out.status == "dropped")],
        "n_lines": out.n_lines,
    }
    return Recording(csv_bytes=out.data, toml_text=rig_toml(cfg, art, zero_written, seed), truth=truth,
                     truth_meta=meta)


def rig_toml(cfg: RigConfig, art: Artefacts, zero_v: float | str, seed: int) -> str:
    """The rig file a user of this sketch writes: what they believe, none of the hidden effects."""
    import tomli_w

    d = cfg.to_dict()
    doc: dict[str, Any] = {s: d[s] for s in ("encoder", "current_sensor", "drive", "controller", "model")}
    doc["current_sensor"] = {**doc["current_sensor"], "zero_v": zero_v}
    if cfg.effects:
        doc["effects"] = d["effects"]
    columns = art.columns_toml()
    if columns is not None:
        doc["columns"] = columns
    head = ("# SYNTHETIC: made by the pdr virtual rig (pdr rig), not a real capture.\n"
            f"# seed {seed}; ground truth in {TRUTH_DIR}/ beside this file (the pipeline never reads it).\n")
    return head + tomli_w.dumps(doc)


def write_recording(rec: Recording, out_dir: Path, name: str) -> dict[str, Path]:
    """Write the capture, its TOML and the ground truth atomically; returns the paths written."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.io.atomic import atomic_path, write_bytes, write_json, write_text

    check_name(name)
    out_dir = Path(out_dir)
    paths = {"csv": out_dir / f"{name}.csv", "toml": out_dir / f"{name}.toml",
             "truth": out_dir / TRUTH_DIR / f"{name}.truth.parquet",
             "truth_json": out_dir / TRUTH_DIR / f"{name}.truth.json"}
    write_bytes(paths["csv"], rec.csv_bytes)
    write_text(paths["toml"], rec.toml_text)
    table = pa.Table.from_pandas(rec.truth, preserve_index=False).replace_schema_metadata(
        {"pdr": json.dumps({"what": "virtual rig ground truth", "seed": rec.truth_meta["seed"]})})
    with atomic_path(paths["truth"]) as tmp:
        pq.write_table(table, tmp, compression="zstd")
    write_json(paths["truth_json"], rec.truth_meta)
    return paths
