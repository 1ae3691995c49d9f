"""What ``pdr run`` did, as figures (``RunReport``) and as the end-of-run summary a user reads."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from pipeline.runs import printable


@dataclass
class RunReport:
    ran: list[dict] = field(default_factory=list)       # one result per recording processed or refused
    skipped: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)    # raw entries that are not recordings (.mat, ...)
    wall_s: float = 0.0
    pool_ready_s: float | None = None      # when the first worker could take a recording (from the run's start)
    ingested_ahead: int = 0                # recordings this process ingested meanwhile
    derived_ahead: int = 0                 # ... and derived too
    started: float = 0.0                   # perf_counter at the run's start
    notes: list[str] = field(default_factory=list)   # what else happened (on a cluster: workers lost, re-runs)

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.ran if r["status"] != "ok"]

    def cpu_seconds(self) -> float:
        """CPU time the recordings took in the workers (excludes pool start-up and waiting)."""
        return sum(r.get("cpu_s", 0.0) for r in self.ran)

    def stage_cpu_seconds(self) -> dict[str, float]:
        """CPU seconds per stage summed over the recordings (``rrd_verify``: the ``rerun`` child processes)."""
        return _summed(r.get("cpu_stage_s", {}) for r in self.ran)

    def stage_seconds(self) -> dict[str, float]:
        return _summed(r["timing_s"] for r in self.ran)


def _summed(per_recording) -> dict[str, float]:
    total: dict[str, float] = {}
    for d in per_recording:
        for k, v in d.items():
            total[k] = total.get(k, 0.0) + v
    return total


def _listed(names: list[str], limit: int = 8) -> str:
    return ", ".join(names[:limit]) + (f", ... ({len(names) - limit} more)" if len(names) > limit else "")


def print_report(report: RunReport, processed: Path) -> None:
    """End-of-run summary: what ran, what was skipped, what failed and why, where the time went."""
    from pipeline.validate.console import wide_console

    console = wide_console()
    n_runs = sum(len(r["runs"]) for r in report.ran if r["status"] == "ok")
    ok = len(report.ran) - len(report.failed)
    console.print(f"[bold]pdr run[/]: {ok} recording(s) processed ({n_runs} runs), "
                  f"{len(report.skipped)} unchanged and skipped, {len(report.failed)} failed"
                  + (f", {len(report.removed)} stale run(s) removed" if report.removed else "")
                  + f" in {report.wall_s:.2f} s", markup=True, highlight=False)
    if report.skipped:
        console.print(f"unchanged (raw bytes, rig TOML layers and code as stamped): {_listed(report.skipped)}",
                      markup=False)
    if report.ignored:
        console.print(f"not recordings (only <name>.csv is read): {_listed(report.ignored)}", markup=False)
    if report.removed:
        console.print(f"removed runs of recordings no longer in the raw folder: {', '.join(report.removed)}",
                      markup=False)
    if any(r["status"] == "ok" for r in report.ran):
        secs = report.stage_seconds()
        total = sum(secs.values()) or 1.0
        parts = ", ".join(f"{k} {v:.2f} s ({100 * v / total:.0f} %)" for k, v in secs.items())
        console.print(f"time by stage (summed over workers): {parts}")

        from pipeline.validate.summary import render_summary, summary_table

        table = summary_table(processed)
        ran = {name for r in report.ran for name in r["runs"]}
        render_summary(table[table["run"].isin(ran)] if not table.empty else table, console)
    for note in report.notes:
        console.print(note, markup=False, highlight=False)
    for r in report.failed:     # one line each, however long: a script may grep them
        console.print("[red]FAILED[/] ", end="")
        console.print(f"{printable(r['recording'])}: {printable(r['error'])}", markup=False, highlight=False,
                      soft_wrap=True)
