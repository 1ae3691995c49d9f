"""The randomised discovery matrix: does ``pdr discover RAW.csv`` hold on rigs and captures it was not tuned on?

Each recording is drawn by ``pipeline.rig.randomised.randomised_setup`` (a lab's own sample
period, supply, sensor, encoder, columns, terminal, capture start, resets, lost rows, noise,
and 0-3 hidden catalogued effects or one outside the catalogue), written as CSV + TOML, and
decided by the functions ``pdr discover RAW.csv`` calls (ingest, derive, the segment it discovers on,
``discover_run``) in the worker; on every ``--timed-every``-th recording (default: all) the
command a user runs, ``pdr discover RAW.csv --json``, also runs in a fresh process, timed
whole (start-up, ingest, derive, discovery, report and .rrd), and its decision is checked to
be the in-process one.  The recordings are decided two at a time (a process pool of two, one
per core); then, with the pool closed and nothing else of ours running, the commands run one
at a time as a user waits for one, each with the 1-minute load average beside it (the machine
may be shared).

A recording is right when the named effects are exactly the hidden ones and the verdict is
``explained``; ``none`` with no name on a clean one; ``unexplained`` with no name outside the
catalogue.  Parameter errors are |found - true| / |true| for every hidden effect that was named.
Each finished recording is appended to ``<out>.partial.jsonl``: a run stopped part-way is
finished, not redone, by running the same command again.

    python -m benchmarks.discovery_matrix [--recordings N] [--seed S] [--timed-every K] [--out FILE]
                                          [--partial-summary]

Without ``--seed`` the draw's seed is fresh (printed, and written with the results): the protocol of
docs/BENCHMARKS.md.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.protocol import rate_interval, rate_text
from pipeline.model.effects import CATALOGUE

DEFAULT_OUT = Path("benchmarks/results/discovery_randomised.json")
PDR = Path(sys.executable).with_name("pdr")


def expected_verdict(label: str) -> str:
    return "none" if label == "clean" else "unexplained" if label.startswith("outside:") else "explained"


def _command(csv: Path, processed: Path) -> tuple[dict | str, float, float]:
    """``pdr discover RAW.csv --json`` in a fresh process: its JSON (or its last error line), wall and CPU seconds
    (CPU: user + system of the command and every process it waited for, its drawing processes included)."""
    t0, before = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([str(PDR), "discover", str(csv), "--json", "--processed", str(processed)],
                          capture_output=True, text=True, cwd=csv.parent)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        return (proc.stderr.strip().splitlines() or ["?"])[-1], wall, cpu
    return json.loads(proc.stdout), wall, cpu


def _in_process(csv: Path, processed: Path) -> dict | str:
    """What the command decides, by the functions it calls (ingest, derive, ``segment_to_discover``, discover_run),
    without its start-up and without writing its report, plots and .rrd; or the error it would print."""
    from pipeline.derive.stage import derive_run
    from pipeline.discover.stage import discover_run, segment_to_discover
    from pipeline.errors import PdrError
    from pipeline.ingest.stage import ingest_recording

    try:
        runs = ingest_recording(csv, processed).runs
        for paths in runs:
            derive_run(paths)
        _, doc = discover_run(segment_to_discover(runs), recording=str(csv))
    except PdrError as err:
        return str(err)
    return doc


def _found(doc: dict) -> dict[str, dict[str, float]]:
    return {e["name"]: e["parameters"] for e in doc["effects"]}


def _write_draw(index: int, seed: int, work: Path):
    """Draw recording ``index`` and write it as ``<work>/raw/r<index>.csv`` + TOML: the draw, the recording, the CSV."""
    from pipeline.rig.randomised import randomised_setup
    from pipeline.rig.recording import make_recording, write_recording

    draw = randomised_setup(np.random.default_rng([seed, index]))
    name = f"r{index:04d}"
    rec = make_recording(draw.setup)
    write_recording(rec, work / "raw", name)
    return draw, rec, work / "raw" / f"{name}.csv"


def run_one(index: int, seed: int, work: Path) -> dict:
    """Draw recording ``index``, write it and decide it in-process (``time_command`` times the command later)."""
    name = f"r{index:04d}"
    t0 = time.perf_counter()
    draw, rec, csv = _write_draw(index, seed, work)
    row = {"index": index, "label": draw.label, "n_effects": len(draw.effects), "outside": draw.outside,
           "expected": expected_verdict(draw.label), "make_s": time.perf_counter() - t0,
           "samples": len(rec.truth), "conventions": draw.conventions,
           "truth": {e.name: e.parameters for e in draw.effects}, "discover_wall_s": None, "discover_cpu_s": None}
    t0, c0 = time.perf_counter(), time.process_time()
    doc = _in_process(csv, work / "in-process" / name)
    row |= {"in_process_wall_s": time.perf_counter() - t0, "in_process_cpu_s": time.process_time() - c0,
            "decided_by": "in-process"}
    if isinstance(doc, str):
        return row | {"verdict": "error", "found": {}, "error": doc, "right": False, "param_err": {}}
    found = _found(doc)
    errors = {}
    for name_, params in row["truth"].items():
        if name_ in found:
            err = max(abs(found[name_][k] - v) / abs(v) for k, v in params.items())
            errors[name_] = err if np.isfinite(err) else None      # a parameter found as NaN: kept, not lost in JSON
    right = set(found) == set(row["truth"]) and doc["verdict"] == row["expected"]
    return row | {"verdict": doc["verdict"], "found": found, "right": right, "param_err": errors,
                  "truth_in_interval": _truth_in_interval(doc, row["truth"]), "work": doc.get("work")}


def _truth_in_interval(doc: dict, truth: dict[str, dict[str, float]]) -> dict[str, bool]:
    """Per hidden effect named, whether every true parameter lies in the ~95 % interval the answer gives: an
    error is judged against what the recording can tell (a 0.06 A offset in 0.14 A of noise over 300 samples
    is known to about +-35 %)."""
    out = {}
    for e in doc["effects"]:
        spans = e.get("interval") or {}
        if e["name"] in truth and all(k in spans for k in truth[e["name"]]):
            out[e["name"]] = all(spans[k][0] <= v <= spans[k][1] for k, v in truth[e["name"]].items())
    return out


def _running() -> int | None:
    """Tasks running on the machine now, this one included (/proc/loadavg's 4th field; None without it):
    the 1-minute load average still remembers the in-process decisions for a minute after they end."""
    try:
        return int(Path("/proc/loadavg").read_text().split()[3].split("/")[0])
    except (OSError, IndexError, ValueError):
        return None


def time_command(row: dict, seed: int, work: Path) -> dict:
    """``row`` (decided in-process) with the command's wall and CPU seconds, the 1-minute load average just
    before it, and whether the command decided as the in-process functions did.  Run one at a time."""
    csv = work / "raw" / f"r{row['index']:04d}.csv"
    if not csv.is_file():                       # a row finished by a stopped run: draw its recording again
        _write_draw(row["index"], seed, work)
    load, running = os.getloadavg()[0], _running()
    cmd, wall, cpu = _command(csv, work / "processed")
    doc = row.get("error") if row["verdict"] == "error" else {"verdict": row["verdict"], "effects": [
        {"name": k, "parameters": v} for k, v in row["found"].items()]}
    agrees = (isinstance(cmd, dict) and isinstance(doc, dict)
              and (cmd["verdict"], _found(cmd)) == (doc["verdict"], _found(doc))) or cmd == doc
    return row | {"discover_wall_s": wall, "discover_cpu_s": cpu, "discover_load_1min": load, "running_before": running,
                  "decided_by": "in-process and command", "command_agrees": agrees}


def _kind(label: str) -> str:
    if label == "clean" or label.startswith("outside:"):
        return label
    return f"{label.count('+') + 1} effect(s)"


def summarise(rows: list[dict]) -> dict:
    """Confusion tables, parameter errors and times, as printed and as written to JSON."""
    df = pd.DataFrame(rows)
    df["kind"] = df["label"].map(_kind)
    verdicts = pd.crosstab(df["kind"], df["verdict"])
    per_effect = []
    for name in CATALOGUE:
        present = df["truth"].map(lambda t: name in t)
        named = df["found"].map(lambda f: name in f)
        errs = [r["param_err"][name] for r in rows if r["param_err"].get(name) is not None]
        per_effect.append({"effect": name, "hidden_in": int(present.sum()), "named_when_hidden": int((present & named).sum()),
                           "named_when_absent": int((~present & named).sum()),
                           "param_err_median": float(np.median(errs)) if errs else None,
                           "param_err_max": float(np.max(errs)) if errs else None})
    single = df[df["n_effects"] == 1]
    first = single.apply(lambda r: next(iter(r["found"]), r["verdict"]), axis=1) if len(single) else pd.Series(dtype=str)
    confusion = pd.crosstab(single["label"], first) if len(single) else pd.DataFrame()
    named_errs = [e for r in rows for e in r["param_err"].values()]
    errs = [e for e in named_errs if e is not None]
    no_effect = df[df["label"].eq("clean") | df["label"].str.startswith("outside:")]
    timed = df[df["discover_wall_s"].notna()]
    wall, cpu = timed["discover_wall_s"].astype(float), timed["discover_cpu_s"].astype(float)
    load, running = (timed[k].dropna().astype(float) if k in timed else pd.Series(dtype=float)
                     for k in ("discover_load_1min", "running_before"))
    agree = timed["command_agrees"].dropna() if "command_agrees" in timed else pd.Series(dtype=bool)
    return {
        "recordings": len(df), "right": int(df["right"].sum()), "right_fraction": float(df["right"].mean()),
        "right_interval_95": rate_interval(int(df["right"].sum()), len(df)),
        "right_by_kind": {k: f"{int(g['right'].sum())}/{len(g)}" for k, g in df.groupby("kind")},
        "effect_named_without_one": int(no_effect["found"].map(bool).sum()), "without_one": len(no_effect),
        "errors": int((df["verdict"] == "error").sum()),
        "verdicts_by_kind": verdicts.to_dict(orient="index"),
        "single_effect_confusion": confusion.to_dict(orient="index"),
        "per_effect": per_effect,
        "param_err_median": float(np.median(errs)) if errs else None,
        "param_err_max": float(np.max(errs)) if errs else None,
        "param_err_within_20pct": f"{sum(e <= 0.2 for e in errs)}/{len(named_errs)}",
        "param_err_not_finite": len(named_errs) - len(errs),
        # in right answers: how often the truth lies in the interval given, and where the error is over 20 %
        "truth_in_interval_right": _coverage(rows, 0.0),
        "truth_in_interval_right_over_20pct": _coverage(rows, 0.2),
        "command_timed": len(timed),
        "command_agrees_with_in_process": f"{int(agree.astype(bool).sum())}/{len(agree)}",
        "in_process_cpu_s": {"median": float(df["in_process_cpu_s"].median()), "max": float(df["in_process_cpu_s"].max())}
        if "in_process_cpu_s" in df else None,
        "discover_wall_s": {"median": float(wall.median()), "max": float(wall.max()), "mean": float(wall.mean()),
                            "over_10s": int((wall > 10).sum()), "over_2s": int((wall > 2).sum())} if len(timed) else None,
        "discover_timed_one_at_a_time": bool(len(timed)) and "discover_load_1min" in timed
        and bool(timed["discover_load_1min"].notna().all()),
        "discover_load_1min": {"median": float(load.median()), "min": float(load.min()), "max": float(load.max())}
        if len(load) else None,
        "running_before_command": {"median": float(running.median()), "max": float(running.max())}
        if len(running) else None,
        "discover_cpu_s": {"median": float(cpu.median()), "max": float(cpu.max()), "mean": float(cpu.mean())}
        if len(timed) else None,
        "load_average_at_end": os.getloadavg(),
    }


def _coverage(rows: list[dict], above: float) -> str:
    """Of right answers' effects whose parameter error exceeds ``above``: how many hold the truth in their interval."""
    cases = [r.get("truth_in_interval", {}).get(name) for r in rows if r["right"]
             for name, err in r["param_err"].items() if err is None or err > above]
    cases = [c for c in cases if c is not None]
    return f"{sum(cases)}/{len(cases)}"


def print_summary(s: dict) -> None:
    pd.set_option("display.width", 250)
    pd.set_option("display.max_columns", 30)
    print(f"\nRight: {rate_text(s['right'], s['recordings'])}; by kind: {s['right_by_kind']}")
    named = rate_text(s["effect_named_without_one"], s["without_one"])
    print(f"Effect named on a recording without a catalogued one: {named}; "
          f"discover failed: {s['errors']}")
    print("\nVerdicts (rows: what is hidden):")
    print(pd.DataFrame(s["verdicts_by_kind"]).T.fillna(0).astype(int))
    if s["single_effect_confusion"]:
        print("\nConfusion matrix of single-effect recordings (rows: hidden; columns: first effect named, or the verdict):")
        print(pd.DataFrame(s["single_effect_confusion"]).T.fillna(0).astype(int))
    print("\nPer effect (over every recording):")
    print(pd.DataFrame(s["per_effect"]).set_index("effect").round(4))
    print(f"\nParameter error where named: median {s['param_err_median']}, max {s['param_err_max']} "
          f"(within 20 %: {s['param_err_within_20pct']}); in right answers the truth inside the interval given: "
          f"{s['truth_in_interval_right']}, of those over 20 %: {s['truth_in_interval_right_over_20pct']}")
    w = s["discover_wall_s"]
    print(f"The command ran on {s['command_timed']} recordings (its decision equal to the in-process one on "
          f"{s['command_agrees_with_in_process']}); in-process CPU (ingest, derive, discovery, no report): "
          f"{s['in_process_cpu_s']}")
    if w is None:
        return
    load = s.get("discover_load_1min")
    how = (f"one at a time, 1-minute load average before each {load['min']:.1f}-{load['max']:.1f}, median {load['median']:.1f}"
           + (f"; tasks running before each: median {s['running_before_command']['median']:.0f}, "
              f"max {s['running_before_command']['max']:.0f}" if s.get("running_before_command") else "")
           if s.get("discover_timed_one_at_a_time") else
           f"beside in-process decisions, load average at the end {s['load_average_at_end'][0]:.1f}")
    print(f"pdr discover RAW.csv, wall per recording ({how}): median {w['median']:.2f} s, max {w['max']:.2f} s, "
          f"mean {w['mean']:.2f} s; over 2 s: {w['over_2s']}, over 10 s: {w['over_10s']}")
    c = s["discover_cpu_s"]
    print(f"  CPU of that command (user + system, its own threads summed; blind to the load): median {c['median']:.2f} s, "
          f"max {c['max']:.2f} s, mean {c['mean']:.2f} s")


def _done_rows(partial: Path, seed: int) -> dict[int, dict]:
    """Rows a stopped run of the same seed already finished (one JSON object per line)."""
    if not partial.is_file():
        return {}
    rows = [json.loads(line) for line in partial.read_text().splitlines() if line.strip()]
    return {r["index"]: {"decided_by": "command", "command_agrees": None} | r for r in rows if r.get("seed") == seed}


def summarise_partial(seed: int, out: Path, wanted: int) -> dict:
    """The summary of what a stopped run finished (its partial file is kept, so the run can still be finished)."""
    partial = out.with_name(out.name + ".partial.jsonl")
    rows = [r for _, r in sorted(_done_rows(partial, seed).items())]
    if not rows:
        raise SystemExit(f"{partial}: no finished recording for seed {seed}")
    summary = summarise(rows)
    print(f"PARTIAL: {len(rows)} of {wanted} recordings finished")
    print_summary(summary)
    from pipeline.io.atomic import write_json

    write_json(out, {"seed": seed, "complete": False, "wanted": wanted, "summary": summary, "recordings": rows})
    print(f"\nwrote {out}")
    return summary


def _print_row(r: dict) -> None:
    print(f"{'ok ' if r['right'] else 'BAD'} {r['index']:4d} {r['label']:60s} -> {r['verdict']:11s} "
          f"{'+'.join(r['found']) or '-':50s} err {max((e if e is not None else float('inf') for e in r['param_err'].values()), default=float('nan')):.3f} "
          f"{r['samples']:6d} samples"
          + (f" pdr discover {r['discover_wall_s']:.2f} s wall {r['discover_cpu_s']:.2f} s CPU"
             + (f" (load {r['discover_load_1min']:.1f})" if r.get("discover_load_1min") is not None else "")
             if r["discover_wall_s"] is not None else "")
          + (f"  [{r['error']}]" if r.get("error") else ""), flush=True)


def main(recordings: int, seed: int, out: Path, workers: int = 2, timed_every: int = 1,
         only: list[int] | None = None) -> dict:
    """Run (or finish: rows already in ``<out>.partial.jsonl`` for this seed are kept) and summarise;
    the command itself runs on every ``timed_every``-th recording (1: all), after every in-process
    decision, one at a time; ``only``: just these indices."""
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial.jsonl")
    done = _done_rows(partial, seed)
    rows = {}
    indices = only if only is not None else list(range(recordings))
    with tempfile.TemporaryDirectory(prefix="pdr-bench-randomised-") as tmp, partial.open("a") as log:
        work = Path(tmp)
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {i: pool.submit(run_one, i, seed, work) for i in indices if i not in done}
            for i in indices:
                r = done[i] if i in done else futures[i].result() | {"seed": seed}
                if i not in done:
                    log.write(json.dumps(r, sort_keys=True) + "\n")
                    log.flush()
                rows[i] = r
                _print_row(r)
        timed = [i for i in indices if i % timed_every == 0 and rows[i].get("discover_wall_s") is None]
        if timed:
            print(f"\nthe command, one at a time, on {len(timed)} recordings:", flush=True)
        for i in timed:
            rows[i] = time_command(rows[i], seed, work)
            log.write(json.dumps(rows[i], sort_keys=True) + "\n")     # replaces the untimed row on a resume
            log.flush()
            _print_row(rows[i])
    summary = summarise([rows[i] for i in indices])
    print_summary(summary)
    from pipeline.io.atomic import write_json

    write_json(out, {"seed": seed, "complete": True, "wanted": recordings, "summary": summary,
                     "recordings": [rows[i] for i in indices]})
    partial.unlink()
    print(f"\nwrote {out} (seed {seed}: repeat this run with --seed {seed})")
    return summary
