"""The ingest stage: one raw capture -> one run per kept logging segment.

``ingest_capture`` is the pure part (bytes + config -> tables + reports);
``ingest_recording`` reads the file, resolves the rig TOML layers and writes.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.config import RigConfig, config_for_recording
from pipeline.errors import IngestError
from pipeline.ingest.convert import ZeroEstimate, amps, estimate_zero, saturation, seconds_from_start, to_signals
from pipeline.ingest.parse import ParsedFile, Quarantined, parse_capture
from pipeline.ingest.plain import parse_plain, read_plain_signals
from pipeline.ingest.segments import clean_segment, split_restarts
from pipeline.ingest.timeline import segment_offsets
from pipeline.ingest.timing import timing_stats
from pipeline.runs import RunPaths, check_recording_name, run_paths, segment_run_name
from pipeline.schemas import load_schema

MIN_SEGMENT_ROWS = 2          # a segment with fewer kept rows has no timing and is flagged, not a run


@dataclass
class RunData:
    name: str
    signals: pd.DataFrame
    report: dict


@dataclass
class IngestResult:
    runs: list[RunPaths]
    report: dict
    tables: dict[str, pd.DataFrame] = field(default_factory=dict, repr=False)   # run name -> signals


def _refuse_if_unreadable(parsed: ParsedFile, quarantined: list[Quarantined], kept: int, cfg: RigConfig,
                          source: str) -> None:
    read = kept + len(quarantined)
    limit = cfg.ingest.max_bad_fraction
    if read and len(quarantined) / read > limit:
        first = quarantined[0]
        binary = sum(q.reason.startswith("binary") for q in quarantined)
        what = "binary or non-UTF-8 content" if binary > len(quarantined) / 2 else "too many unreadable rows"
        raise IngestError(f"{what}: {len(quarantined)} of {read} data lines unreadable "
                          f"({100 * len(quarantined) / read:.1f}% > ingest.max_bad_fraction = {limit:g}); "
                          f"first at line {first.line}: {first.reason}", path=source, line=first.line)


def _current_zeros(parsed: ParsedFile, flagged: dict[int, str], cfg: RigConfig, source: str
                   ) -> dict[int, ZeroEstimate]:
    """The ACS712 zero of each segment that logs current.  A segment with no samples at rest (zero_v =
    "auto"; after a board reset the winding may still carry current) takes the zero of the last earlier
    segment that has its own, as the live decoder does (a first segment: the next one's, which the live
    decoder cannot know yet): the zero is the sensor part's, which a reset does not change.  Where no
    segment has any, the recording is refused."""
    zeros, failed = {}, {}
    for seg in parsed.segments:
        if seg.index in flagged or "adc" not in seg.values:
            continue
        try:
            zeros[seg.index] = estimate_zero(seg.values, cfg, source)
        except IngestError as err:
            failed[seg.index] = err
    if failed and not zeros:
        raise next(iter(failed.values()))
    own = sorted(zeros)
    for index in failed:
        earlier = [k for k in own if k < index]
        donor = earlier[-1] if earlier else own[0]
        zeros[index] = replace(zeros[donor], method=f"{zeros[donor].method}, of segment {donor} (none at rest in this one)")
    return zeros


@dataclass
class Capture:
    """A capture parsed, cleaned and made into signals tables: everything but the report's figures."""

    data: bytes
    cfg: RigConfig
    source: str
    parsed: ParsedFile
    times: list[tuple]                     # per segment: unwrapped time, counter wraps
    quarantined: list[Quarantined]
    flagged: dict[int, str]                # segment index -> why it is not a run
    zeros: dict[int, ZeroEstimate]
    names: dict[int, str]                  # segment index -> run name
    runs: list[RunData]


def _plain_capture(data: bytes, cfg: RigConfig, source: str, stem: str, parsed: ParsedFile,
                   cols: dict[str, np.ndarray]) -> Capture:
    """``read_capture`` of a capture ``read_plain_signals`` took: one segment, all of it kept, its columns
    made; what is left is the zero estimate (and with it current_a, when zero_v is "auto")."""
    seg = parsed.segments[0]
    zeros = _current_zeros(parsed, {}, cfg, source)      # raises, as below, when "auto" finds no rest
    if "adc" in seg.values and "current_a" not in cols:
        cols["current_a"] = amps(cols["current_v"], zeros[seg.index].zero_v, cfg)
    cols["segment"] = np.zeros(len(seg.line), dtype=np.int32)
    order = [c.name for c in load_schema("signals").columns]         # to_signals' order too
    signals = pd.DataFrame({k: cols[k] for k in order if k in cols}, copy=False)
    return Capture(data, cfg, source, parsed, [(seg.values["t_raw"], 0)], [], {}, zeros, {seg.index: stem},
                   [RunData(stem, signals, {})])


def read_capture(data: bytes, cfg: RigConfig, source: str, stem: str) -> Capture:
    """Bytes of one capture -> the signals table of each kept segment; every refusal is raised here,
    so once this returns the tables can be written while the report is put together."""
    plain = read_plain_signals(data, cfg, source)
    if plain is not None and len(plain[0].segments[0].line) >= MIN_SEGMENT_ROWS:
        return _plain_capture(data, cfg, source, stem, *plain)
    parsed = parse_plain(data, cfg.columns, source) or parse_capture(data, cfg.columns, source)
    parsed.segments = [part for seg in parsed.segments for part in split_restarts(seg, cfg.columns.time_unit)]
    for k, seg in enumerate(parsed.segments):
        seg.index = k
    times = [clean_segment(seg, cfg, source) for seg in parsed.segments]
    quarantined = sorted([*parsed.quarantined, *(q for s in parsed.segments for q in s.quarantined)],
                         key=lambda q: q.line)
    kept_rows = sum(len(s.line) for s in parsed.segments)
    _refuse_if_unreadable(parsed, quarantined, kept_rows, cfg, source)
    flagged: dict[int, str] = {s.index: f"fewer than {MIN_SEGMENT_ROWS} readable rows: not made a run"
                               for s in parsed.segments if len(s.line) < MIN_SEGMENT_ROWS}
    if len(flagged) == len(parsed.segments):
        raise IngestError(f"no segment with at least {MIN_SEGMENT_ROWS} readable rows", path=source)
    zeros = _current_zeros(parsed, flagged, cfg, source)
    keep = [s for s in parsed.segments if s.index not in flagged]
    names = {s.index: stem if len(keep) == 1 else segment_run_name(stem, k + 1) for k, s in enumerate(keep)}
    runs = [RunData(names[seg.index], to_signals(seg.values, seg.line, seconds_from_start(t, cfg.columns.time_unit),
                                                 seg.index, cfg, zeros.get(seg.index)), {})
            for seg, (t, _) in zip(parsed.segments, times) if seg.index in names]
    return Capture(data, cfg, source, parsed, times, quarantined, flagged, zeros, names, runs)


def capture_report(cap: Capture) -> dict:
    """The file report (timing, zeros, defects, quarantine, sha256); sets each run's own report too."""
    parsed, cfg, names, zeros = cap.parsed, cap.cfg, cap.names, cap.zeros
    seg_reports = []
    for seg, (t, wraps) in zip(parsed.segments, cap.times):
        entry = {"index": seg.index, "header_line": seg.header_line, "rows_kept": int(len(seg.line)),
                 "rows_quarantined": len(seg.quarantined), "columns": sorted(seg.layout),
                 "notes": seg.notes, "run": names.get(seg.index)}
        if seg.index not in names:
            entry["flagged"] = cap.flagged[seg.index]
            seg_reports.append(entry)
            continue
        zero = zeros.get(seg.index)
        entry |= {"first_line": int(seg.line[0]), "last_line": int(seg.line[-1]), "counter_wraps": wraps,
                  "wall_clock_start": parsed.prefix.wall_clock_at(int(seg.line[0])) if parsed.prefix else None,
                  "timing": timing_stats(t, cfg.columns.time_unit, seg.line, cfg.controller.period_s),
                  "current_zero": zero.to_dict() if zero else None,
                  "adc_saturation": saturation(seg.values["adc"], cfg.current_sensor.adc_steps) if zero else None,
                  "not_logged": [c for c in ("counts", "adc", "dir") if c not in seg.layout]}
        seg_reports.append(entry)
    kept = [entry for entry in seg_reports if entry["run"] is not None]
    if len(kept) > 1:               # after a board reset: every segment's place on the capture's one time axis
        offsets, how = segment_offsets([e["wall_clock_start"] for e in kept],
                                       [e["timing"]["duration_s"] for e in kept], cfg.controller.period_s)
        for entry, offset in zip(kept, offsets):
            entry |= {"time_offset_s": offset, "time_axis": how}
    defects = list(parsed.notes)
    for entry in seg_reports:
        defects += [f"segment {entry['index']}: {n}" for n in entry["notes"]]
        defects += [f"segment {entry['index']}: {d}" for d in entry.get("timing", {}).get("defects", [])]
    if len(parsed.header_lines) > 1:
        defects.append(f"{len(parsed.header_lines) - 1} board reset(s): repeated header at lines "
                       f"{parsed.header_lines[1:]}")
    kept_rows = sum(len(s.line) for s in parsed.segments)
    report = {
        "recording": cap.source,
        "sha256": hashlib.sha256(cap.data).hexdigest(),
        "bytes": len(cap.data),
        "config": cfg.to_dict(),
        "sources": cfg.sources,
        "lines": {"total": parsed.lines_total, "blank": parsed.blank_lines, "comment": parsed.comment_lines,
                  "header": parsed.header_lines},
        "rows": {"read": kept_rows + len(cap.quarantined), "kept": sum(len(r.signals) for r in cap.runs),
                 "quarantined": len(cap.quarantined)},
        "quarantined": [q.to_dict() for q in cap.quarantined],
        "timestamp_prefix": parsed.prefix.to_dict() if parsed.prefix else None,
        "board_resets": len(parsed.segments) - 1 - (1 if parsed.segments[0].header_line is None
                                                    and parsed.header_lines else 0),
        "defects": defects,
        "without_angle": without_angle(set().union(*(s.layout for s in parsed.segments))),
        "segments": seg_reports,
        "runs": [r.name for r in cap.runs],
    }
    for r in cap.runs:
        r.report = report | {"run": r.name}
    return report


def without_angle(logged: set[str]) -> str | None:
    """One sentence on what a capture without an encoder column loses, stage by stage (None with one)."""
    if "counts" in logged:
        return None
    if "dir" in logged:
        rest = ("derive keeps the current, phases and electrical energy from dir; validate replays the logged dir "
                "and compares the current only (closed loop skipped: it switches on the angle)")
    else:
        rest = ("derive keeps the current and its energy; without dir either, there are no phases, no input energy "
                "and nothing to drive the model with, so validate compares nothing")
    return ("no angle (no encoder column, columns.counts = \"\"): velocity, guard overshoot, cycles, the "
            f"mechanical energy terms and discovery are skipped; {rest}; the figures show what was logged")


def ingest_capture(data: bytes, cfg: RigConfig, source: str, stem: str) -> tuple[list[RunData], dict]:
    """Bytes of one capture -> the signals table and report of each kept segment, and the file report."""
    cap = read_capture(data, cfg, source, stem)
    return cap.runs, capture_report(cap)


def summary_text(report: dict) -> str:
    """The short console summary of one recording."""
    rows = report["rows"]
    lines = [f"{report['recording']}: {rows['kept']} rows kept, {rows['quarantined']} quarantined "
             f"of {rows['read']} -> {', '.join(report['runs'])}"]
    for seg in report["segments"]:
        timing = seg.get("timing") or {}
        if timing.get("median_period_s") is not None:
            lines.append(f"  segment {seg['index']}: median period {timing['median_period_s']:.6g} s, "
                         f"jitter {timing['jitter_std_s']:.3g} s, {timing['gaps']} gaps")
        if seg.get("current_zero") and seg["current_zero"]["method"] != "configured":
            z = seg["current_zero"]
            lines.append(f"  segment {seg['index']}: zero_v auto = {z['zero_v']:.4f} V "
                         f"(spread {z['spread_v']:.4f} V, {z['samples']} samples, {z['method']})")
    lines += [f"  defect: {d}" for d in report["defects"]]
    if report.get("without_angle"):
        lines.append(f"  {report['without_angle']}")
    return "\n".join(lines)


def ingest_signals(data: bytes, cfg: RigConfig, source: str, stem: str, processed: Path
                   ) -> tuple[list[RunData], dict, list[RunPaths]]:
    """``ingest_capture`` with each run's signals.parquet written as soon as its table exists.

    The Parquet encoding runs in a worker thread while this one puts the report together (timing
    statistics, sha256): both release the GIL, so on two cores the report costs no wall time.
    Every refusal is raised by ``read_capture``, before anything is written.
    """
    from concurrent.futures import ThreadPoolExecutor

    from pipeline.ingest.write import write_signals
    cap = read_capture(data, cfg, source, stem)
    out = [run_paths(processed, run.name) for run in cap.runs]
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = [pool.submit(write_signals, paths, run.signals, cfg) for paths, run in zip(out, cap.runs)]
        report = capture_report(cap)
        for job in pending:
            job.result()
    return cap.runs, report, out


def ingest_recording(csv_path: Path, processed: Path, *, config: RigConfig | None = None) -> IngestResult:
    """Read one raw CSV (never modified), resolve its rig TOML layers, write one run per kept segment."""
    from pipeline.ingest.write import write_run
    from pipeline.io.files import recording_file_problem
    csv_path = Path(csv_path)
    check_recording_name(csv_path.stem, csv_path)
    problem = recording_file_problem(csv_path)      # never open a FIFO or a device, nor read 4 GiB of zeros
    if problem is not None:
        raise IngestError(problem, path=csv_path)
    cfg = config if config is not None else config_for_recording(csv_path)
    try:
        data = csv_path.read_bytes()
    except OSError as err:
        raise IngestError(f"cannot read the recording: {err.strerror}", path=csv_path) from None
    runs, report, out = ingest_signals(data, cfg, str(csv_path), csv_path.stem, Path(processed))
    for run, paths in zip(runs, out):
        write_run(paths, run.signals, run.report, cfg)
    return IngestResult(runs=out, report=report, tables={r.name: r.signals for r in runs})
