"""``pdr discover``: name the effect the model is missing, add it, show the gap shrink."""

from __future__ import annotations

import gc
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional

import typer

DEFAULT_PROCESSED = Path("processed")


@contextmanager
def fewer_collections() -> Iterator[None]:
    """The garbage collector's first generation collected every 50,000 new objects instead of 700, until the
    block (or the decorated command) ends.  The command's imports (numpy, pandas, scipy, numba, matplotlib)
    leave ~250,000 long-lived objects the collector tracks; by the default thresholds they set off five full
    collections (~0.4 s on paper_clean, ~15 % of the command); with these, none, and ~0.1 s of young ones,
    at the same peak memory.  At the end what is still young joins the oldest generation (a freeze and an
    unfreeze, two list splices), or the default thresholds would walk all of it at the next allocation."""
    before = gc.get_threshold()
    gc.set_threshold(50_000, 20, 100)
    try:
        yield
    finally:
        if not gc.get_freeze_count():         # nobody else's frozen objects to thaw
            gc.freeze()
            gc.unfreeze()
        gc.set_threshold(*before)


def refuse_a_missing_csv(recordings: list[str]) -> None:
    """One raw CSV that is not there is said at once, before the ~0.5 s of imports discovering it needs."""
    from pipeline.errors import PdrError

    if len(recordings) == 1 and Path(recordings[0]).suffix.lower() == ".csv" and not Path(recordings[0]).is_file():
        raise PdrError("no such raw recording: expected a CSV file, a processed run folder or a run name",
                       path=recordings[0])


@fewer_collections()
def discover(
    recordings: list[str] = typer.Argument(..., metavar="RECORDING",
                                           help="A raw CSV path (ingested and derived on the fly), "
                                                "a processed run folder or a run name; or several raw CSV "
                                                "paths: one row each in <processed>/discovery/summary.csv, "
                                                "pooled estimates and trends per effect."),
    json_out: bool = typer.Option(False, "--json", help="Print one JSON object (docs/FORMAT.md) on stdout."),
    adopt: bool = typer.Option(False, "--adopt", help="Write the augmented \\[effects] table into the recording's "
                                                      "sidecar TOML (raw/<name>.toml). Never done without it."),
    out: Optional[Path] = typer.Option(None, "--out", help="Folder for the report, plots, TOML snippet and "
                                                           ".rrd (default: <processed>/discovery/<run>)."),
    processed: Path = typer.Option(DEFAULT_PROCESSED, "--processed", help="Folder of processed runs."),
    no_rrd: bool = typer.Option(False, "--no-rrd", help="Skip the Rerun recording."),
    cluster: str = typer.Option("", "--cluster", envvar="PDR_CLUSTER", show_envvar=True,
                                help="Several recordings: discover them on this dask scheduler's workers."),
    jobs: int = typer.Option(2, "--jobs", "-j", min=1, help="Several recordings: local worker processes."),
) -> None:
    """Localise where model and measurement disagree, fit every catalogued effect, keep only what
    the evidence supports, and report the verdict (explained / none / unexplained).

    Example: pdr discover raw/paper_run.csv --json      (many: pdr discover raw/day*.csv)

    Then: pdr validate raw/paper_run.csv --model processed/discovery/paper_run/effects.toml,
    or adopt it: pdr discover raw/paper_run.csv --adopt
    """
    refuse_a_missing_csv(recordings)
    import tempfile

    from pipeline.derive.stage import ingest_and_derive
    from pipeline.discover.adopt import adopt as adopt_effects
    from pipeline.discover.report import dumps, write_figures, write_report
    from pipeline.discover.stage import augmented_effects, discover_run, segment_to_discover
    from pipeline.errors import PdrError
    from pipeline.runs import DISCOVERY_DIR, resolve_runs

    if len(recordings) > 1:
        if adopt:
            raise PdrError("--adopt takes one recording (adopt what one run found)", key="--adopt")
        _discover_many(recordings, out if out is not None else processed / "discovery", json_out, cluster, jobs,
                       rrd=not no_rrd)
        return
    recording = recordings[0]
    item = Path(recording)
    with tempfile.TemporaryDirectory(prefix="pdr-discover-") as tmp:
        if item.suffix.lower() == ".csv" and item.is_file():
            runs = ingest_and_derive(item, Path(tmp))
            source_csv: Path | None = item
        else:
            runs = resolve_runs(recording, processed)
            source_csv = _raw_source(runs[0].ingest_report)
        if not runs:
            raise PdrError("no usable segment in the recording", path=recording)
        # one recording, one answer: one segment when the board reset mid-file
        paths = segment_to_discover(runs)
        d, doc = discover_run(paths, recording=str(recording))
    if len(runs) > 1:
        doc["segments"] = {"used": paths.name, "others": [p.name for p in runs if p != paths]}
    root = processed if item.suffix.lower() == ".csv" or not item.is_dir() else item.parent
    out_dir = out if out is not None else Path(root) / DISCOVERY_DIR / paths.name
    written, report_md = write_report(out_dir, d, doc, rrd=not no_rrd)
    # effects found beside a base the TOML does not give would be written beside Table I's: not adopted
    refused = adopt and bool(d.effects) and d.base_check is not None and d.base_check.base_off
    if adopt:
        if not d.effects or refused:
            doc["adopted"] = None
        elif source_csv is None:
            raise PdrError("cannot tell which raw recording this run came from; adopt by hand from "
                           f"{written['toml']}", path=recording)
        else:
            doc["adopted"] = str(adopt_effects(source_csv, augmented_effects(d)))
    doc["seconds"] = round(d.seconds, 3)      # printed, not written: the files stay byte-identical on a re-run
    # the answer first, flushed: the figures and the .rrd (about a second of drawing) come after it
    typer.echo(dumps(doc) if json_out else _summary(doc) + "\n" + _where(doc, written))
    sys.stdout.flush()
    write_figures(written, d, report_md, rrd=not no_rrd)
    if refused:
        raise PdrError("not adopted: the rig's [model] is not declared and the recording does not fit Table I's "
                       "base, so what was found holds beside a base the TOML does not give; run `pdr calibrate` on "
                       "two clean recordings of this rig with --adopt, then discover and adopt again", key="--adopt")


def _discover_many(recordings: list[str], out: Path, json_out: bool, cluster: str, jobs: int, rrd: bool) -> None:
    import json

    from pipeline.discover.across import findings
    from pipeline.discover.many import discover_many

    from pipeline.run.stop import nothing_left_to_stop, stop_signals, stopped_by

    with stop_signals():
        try:
            result = discover_many([Path(r) for r in recordings], out, jobs=jobs, cluster=cluster or None, rrd=rrd,
                                   show_progress=sys.stderr.isatty())
            nothing_left_to_stop()
        except BaseException as err:            # typer would turn a stop into a silent exit 130
            if (stop := stopped_by(err)) is None:
                raise
            why = "interrupted" if stop.exit_status == 130 else "terminated (SIGTERM)"
            typer.echo(f"pdr: {why}: the discoveries finished so far are in {out}/<run>/; the summary "
                       "across runs was not written (discover them again to have it)", err=True)
            raise typer.Exit(stop.exit_status) from None
    if json_out:
        doc = {"runs": json.loads(result.table.to_json(orient="records")),
               "pooled": json.loads(result.pooled.to_json(orient="records")),
               "files": {k: str(v) for k, v in result.written.items()}}
        typer.echo(json.dumps(doc, indent=2, sort_keys=True))
    else:
        counts = result.table["verdict"].value_counts().to_dict() if not result.table.empty else {}
        typer.echo(f"{len(result.table)} recording(s): " + ", ".join(f"{v} {k}" for k, v in sorted(counts.items())))
        for line in result.notes + findings(result.pooled):
            typer.echo(line)
        for f in result.failed:
            typer.echo(f"FAILED {f['recording']}: {f['error']}")
        typer.echo(f"summary: {result.written['summary']}, pooled: {result.written['pooled']}, "
                   f"plot: {result.written['plot']}")
    if result.failed:
        raise typer.Exit(1)


def _raw_source(report_path: Path) -> Path | None:
    import json

    try:
        rec = json.loads(report_path.read_text(encoding="utf-8")).get("recording")
    except (OSError, ValueError):
        return None
    src = rec.get("source") if isinstance(rec, dict) else rec
    return Path(src) if isinstance(src, str) and Path(src).is_file() else None


def _where(doc: dict, written: dict[str, Path]) -> str:
    """Where the report is and what to do with the effects found."""
    lines = [f"report: {written['markdown']} (its figures are drawn next)"]
    if doc.get("adopted"):
        lines.append(f"adopted into {doc['adopted']}")
    elif doc["effects"] and (doc.get("base_free_check") or {}).get("base_off"):
        lines.append(f"[effects] snippet: {written['toml']} (--adopt writes nothing until the rig is calibrated)")
    elif doc["effects"]:
        lines.append(f"[effects] snippet: {written['toml']} (add --adopt to write it into the rig's TOML)")
    return "\n".join(lines)


def _summary(doc: dict) -> str:
    lines = [f"{doc['run']}: {doc['verdict']}"]
    for e in doc["effects"]:
        params = ", ".join(f"{k} = {v:.4g} {e['units'][k]}" for k, v in e["parameters"].items())
        lines.append(f"  + {e['name']}: {params}")
    for sig, b in doc["mse_before"].items():
        a = doc["mse_after"].get(sig)
        if b is not None and a is not None:
            lines.append(f"  replay MSE {sig}: {b:.4g} -> {a:.4g}" + (f" ({100 * (a - b) / b:+.1f} %)" if b else ""))
    if doc.get("near_tie"):
        t = doc["near_tie"]
        lines.append(f"  near tie: {t['chosen']} vs {t['runner_up']} ({t['scores']})")
    for x in doc.get("unexplained", []):
        lines.append(f"  unexplained: {x}")
    if check := doc.get("base_free_check"):
        from pipeline.discover.base_free import base_free_text

        lines.append("  " + base_free_text(check))
    if doc.get("hint"):
        lines.append(f"  hint: {doc['hint']}")
    if doc.get("left_out"):
        lines.append(f"  left out: {doc['left_out']}")
    lines.append(f"  {doc['seconds']:.2f} s")
    return "\n".join(lines)
