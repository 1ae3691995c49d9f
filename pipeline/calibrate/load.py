"""Calibration's inputs: recordings of one rig as measurements, and the rig's prior model."""

from __future__ import annotations

from pathlib import Path

from pipeline.calibrate.structure import declared_model
from pipeline.derive.stage import ingest_and_derive
from pipeline.discover.measurement import Measurement, measurement_from_kinematics
from pipeline.errors import PdrError
from pipeline.model.params import ModelParams
from pipeline.runs import RunPaths, config_sources, ingest_segment, load_config, resolve_runs
from pipeline.validate.stage import load_kinematics


def _runs(recording: str, processed: Path, tmp: Path) -> list[RunPaths]:
    item = Path(recording)
    if item.suffix.lower() == ".csv":
        if not item.is_file():
            raise PdrError("no such recording", path=recording)
        return ingest_and_derive(item, tmp / f"{len(list(tmp.iterdir()))}")
    return resolve_runs(recording, processed)


def _measurement(paths: RunPaths) -> Measurement:
    segment = ingest_segment(paths)
    index = segment.get("index", 0)
    return measurement_from_kinematics(load_kinematics(paths), load_config(paths), paths.name,
                                       angle_reference_known=not (isinstance(index, int) and index > 0))


def load_measurements(recordings: list[str], processed: Path, tmp: Path) -> tuple[list[Measurement], ModelParams, bool]:
    """Every segment of every recording, the prior [model] (the first recording's) and whether the rig
    declared it; refuses recordings whose [model] differ (they are not of one rig as configured)."""
    tmp.mkdir(parents=True, exist_ok=True)
    measurements, models, declared = [], [], False
    for recording in recordings:
        runs = _runs(recording, processed, tmp)
        if not runs:
            raise PdrError("no usable segment in the recording", path=recording)
        for paths in runs:
            measurements.append(_measurement(paths))
            models.append(measurements[-1].config.model)
            declared = declared or declared_model(config_sources(paths))
    if any(m != models[0] for m in models):
        raise PdrError("the recordings' TOMLs declare different [model] tables: calibrate recordings of one rig, "
                       "configured alike", path=recordings[0])
    return measurements, models[0], declared


def adopt_target(recordings: list[str]) -> Path:
    """``rig.toml`` in the raw folder of the recordings (they must be raw CSVs in one folder)."""
    folders = {Path(r).resolve().parent for r in recordings if Path(r).suffix.lower() == ".csv"}
    if len(folders) != 1 or any(Path(r).suffix.lower() != ".csv" for r in recordings):
        raise PdrError("--adopt needs raw CSV recordings in one folder (it writes that folder's rig.toml)",
                       key="--adopt")
    folder = folders.pop()
    for r in recordings:
        sidecar = Path(r).with_suffix(".toml")
        if sidecar.is_file() and any(line.strip().startswith("[model") for line in sidecar.read_text().splitlines()):
            raise PdrError(f"{sidecar.name} declares its own [model], which overrides rig.toml: remove it there "
                           "first, or copy the calibrated table into it by hand", path=sidecar)
    return folder / "rig.toml"
