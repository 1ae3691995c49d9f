"""``pdr discover RAW.csv --json`` as a user waits for it, until its answer and whole, before vs after in the same run.

Draws recordings of the randomised rig (``pipeline.rig.randomised``, the seed and indices of
``make bench-discovery``), then runs each variant's ``pdr discover RAW.csv --json`` in a fresh
process, one command at a time (as a user runs it), the variants interleaved per recording in
a rotating order so a change of the machine's load hits them alike.  Wall time by the clock, twice:
until the JSON object is complete on stdout (the answer) and until the command ends (figures and
.rrd drawn); CPU as user + system of the command and every process it waited for; the 1-minute
load average before each command is recorded.  The variants'
decisions (verdict, effects and their parameters) are compared to the first variant's.

    python -m benchmarks.bench_discover_command --variant before=/path/to/other/.venv/bin/pdr \\
        --variant after=.venv/bin/pdr [--variant after-env=.venv/bin/pdr:SOME_ENV=VALUE] \\
        [--indices 0,10,...] [--seed 15] [--out benchmarks/results/discover_command.json]

Without ``--variant`` (as ``make bench`` runs it): this install's ``pdr`` alone.

A variant is ``NAME=PDR[:ENV=VALUE,...]``; the default indices are 25 of the baseline's timed
draws and its five slowest decisions.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT_INDICES = (*range(0, 250, 10), 93, 62, 275, 101, 65)
DEFAULT_OUT = Path("benchmarks/results/discover_command.json")
PDR = Path(sys.executable).with_name("pdr")


def _parse_variant(text: str) -> tuple[str, Path, dict[str, str]]:
    name, _, rest = text.partition("=")
    pdr, _, env = rest.partition(":")
    extra = dict(kv.split("=", 1) for kv in env.split(",") if kv)
    return name, Path(pdr).absolute(), extra


def run_command(pdr: Path, csv: Path, processed: Path, env: dict[str, str]) -> dict:
    """One ``pdr discover RAW.csv --json`` in a fresh process: its decision; the wall seconds until the JSON
    object was complete on stdout (what a user or a script waits for) and until the command ended (the
    figures and the .rrd drawn); its CPU seconds."""
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen([str(pdr), "discover", str(csv), "--json", "--processed", str(processed)],
                                stdout=subprocess.PIPE, stderr=err, text=True, cwd=csv.parent,
                                env={**os.environ, **env})
        answer_s, lines, doc = None, [], None
        for line in proc.stdout:
            lines.append(line)
            if doc is None and line.rstrip("\n") == "}":      # the object's last line (report.dumps' layout)
                doc = json.loads("".join(lines))
                answer_s = time.perf_counter() - t0
        proc.wait()
        err.seek(0)
        stderr = err.read()
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    row = {"answer_s": answer_s, "wall_s": wall, "cpu_s": cpu, "load_before": load}
    if proc.returncode != 0 or doc is None:
        return row | {"error": (stderr.strip().splitlines() or ["?"])[-1]}
    return row | {"verdict": doc["verdict"], "effects": {e["name"]: e["parameters"] for e in doc["effects"]},
                  "stopped_for_time": bool(doc.get("stopped_for_time"))}


# values that differ by less than this share are the same finding: a faster simulator's other rounding moves
# a fitted value by ~1e-9 of itself, well inside any interval a recording gives
SAME_VALUE = 1e-6


def same_decision(run: dict, first: dict) -> bool:
    """The same verdict, the same effects in the same order, each value within ``SAME_VALUE`` of the first's."""
    if (run.get("verdict"), run.get("error")) != (first.get("verdict"), first.get("error")):
        return False
    a, b = run.get("effects") or {}, first.get("effects") or {}
    if list(a) != list(b) or any(list(a[n]) != list(b[n]) for n in a):
        return False
    return all(abs(a[n][k] - b[n][k]) <= SAME_VALUE * max(abs(b[n][k]), 1e-300) for n in a for k in a[n])


def _answer(run: dict) -> str:
    return f"{run['answer_s']:5.2f} s" if run["answer_s"] is not None else "  -   "


def _stats(values: list[float]) -> dict:
    return {"median": float(np.median(values)), "max": float(np.max(values)), "mean": float(np.mean(values))}


def main(variants: list[tuple[str, Path, dict[str, str]]] | None = None, indices: list[int] | tuple[int, ...] = DEFAULT_INDICES,
         seed: int = 15, out: Path = DEFAULT_OUT) -> dict:
    """``variants`` default: this install's ``pdr`` as a user gets it (what ``make bench`` runs)."""
    variants = variants or [("this", PDR, {})]
    indices = list(indices)
    from pipeline.rig.randomised import randomised_setup
    from pipeline.rig.recording import make_recording, write_recording

    rows = []
    with tempfile.TemporaryDirectory(prefix="pdr-bench-discover-") as tmp:
        work = Path(tmp)
        for k, i in enumerate(indices):
            draw = randomised_setup(np.random.default_rng([seed, i]))
            rec = make_recording(draw.setup)
            write_recording(rec, work / "raw", f"r{i:04d}")
            csv = work / "raw" / f"r{i:04d}.csv"
            row = {"index": i, "label": draw.label, "samples": len(rec.truth), "runs": {}}
            order = variants[k % len(variants):] + variants[:k % len(variants)]
            for name, pdr, env in order:
                row["runs"][name] = run_command(pdr, csv, work / f"processed-{name}", env)
            first = row["runs"][variants[0][0]]
            for name, _, _ in variants[1:]:
                r = row["runs"][name]
                r["same_decision"] = same_decision(r, first)
            rows.append(row)
            print(f"{i:4d} {row['samples']:6d} samples  " + "  ".join(
                f"{n} {_answer(row['runs'][n])} answer {row['runs'][n]['wall_s']:5.2f} s wall "
                f"{row['runs'][n]['cpu_s']:5.2f} s CPU"
                + ("" if row["runs"][n].get("same_decision", True) else " (other decision)")
                for n, _, _ in variants) + f"  load {first['load_before']:.1f}", flush=True)
    summary = {}
    for name, _, _ in variants:
        runs = [r["runs"][name] for r in rows]
        answers = [r["answer_s"] for r in runs if r["answer_s"] is not None]
        summary[name] = {"answer_s": _stats(answers) if answers else None,
                         "wall_s": _stats([r["wall_s"] for r in runs]),
                         "cpu_s": _stats([r["cpu_s"] for r in runs]),
                         "answer_over_2s": sum(a > 2 for a in answers), "over_10s": sum(r["wall_s"] > 10 for r in runs),
                         "same_decision": sum(r.get("same_decision", True) for r in runs),
                         "stopped_for_time": sum(r.get("stopped_for_time", False) for r in runs)}
    loads = [r["runs"][n]["load_before"] for r in rows for n, _, _ in variants]
    result = {"seed": seed, "indices": indices, "variants": {n: {"pdr": str(p), "env": e} for n, p, e in variants},
              "cores": os.cpu_count(), "load_before": _stats(loads) | {"min": float(np.min(loads))},
              "summary": summary, "recordings": rows}
    for name, s in summary.items():
        answer = (f"JSON complete median {s['answer_s']['median']:.2f} s, max {s['answer_s']['max']:.2f} s "
                  f"(over 2 s: {s['answer_over_2s']}); " if s["answer_s"] else "no JSON; ")
        print(f"{name:12s} {answer}whole command median {s['wall_s']['median']:.2f} s, max {s['wall_s']['max']:.2f} s; "
              f"CPU median {s['cpu_s']['median']:.2f} s, max {s['cpu_s']['max']:.2f} s; "
              f"over 10 s: {s['over_10s']}; same decision as {variants[0][0]}: {s['same_decision']}/{len(rows)}; "
              f"stopped for time: {s['stopped_for_time']}")
    print(f"load average (1 min) before the commands: min {result['load_before']['min']:.1f}, "
          f"median {result['load_before']['median']:.1f}, max {result['load_before']['max']:.1f} on {os.cpu_count()} cores")
    from pipeline.io.atomic import write_json

    write_json(out, result)
    print(f"wrote {out}")
    return result


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", action="append", help="NAME=PDR[:ENV=VALUE,...] (default: this install's pdr)")
    ap.add_argument("--indices", default=",".join(map(str, DEFAULT_INDICES)))
    ap.add_argument("--seed", type=int, default=15)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    a = ap.parse_args()
    main([_parse_variant(v) for v in a.variant or []], [int(x) for x in a.indices.split(",")], a.seed, a.out)
