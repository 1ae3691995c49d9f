"""One table across all runs: ``processed/summary.csv`` and the console table.

Built from every run's ``validation.json`` (not from in-memory results), so it
is the same whether the runs were validated now or skipped as unchanged.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from pipeline.io.atomic import write_text
from pipeline.validate.console import wide_console
from pipeline.validate.gate import run_dirs
from pipeline.validate.stage import summary_row

SUMMARY_NAME = "summary.csv"


def summary_table(processed: Path) -> pd.DataFrame:
    rows = []
    for root in run_dirs(processed):
        path = root / "validation.json"
        if path.is_file():
            rows.append(summary_row(json.loads(path.read_text(encoding="utf-8"))))
    return pd.DataFrame(rows)


def write_summary(processed: Path) -> pd.DataFrame:
    """Write ``processed/summary.csv`` (deterministic: sorted runs, fixed float format)."""
    table = summary_table(processed)
    write_text(Path(processed) / SUMMARY_NAME, table.to_csv(index=False, float_format="%.6g", lineterminator="\n"))
    return table


def _g(v) -> str:
    return "-" if v is None or (isinstance(v, float) and v != v) else f"{v:.3g}"


def _count(v) -> str:
    """A switch count, "-" for a way not run (a recording without an encoder has no closed loop)."""
    return "-" if v is None or (isinstance(v, float) and v != v) else str(int(v))


def render_summary(table: pd.DataFrame, console=None, limit: int = 60) -> None:
    """Console table: MSEs of both ways, switch counts, energy error (first ``limit`` runs)."""
    from rich.table import Table

    console = console or wide_console()
    if table.empty:
        console.print("no validated runs")
        return
    t = Table(title=f"validation summary ({len(table)} runs; MSE: theta rad^2, omega (rad/s)^2, current A^2)")
    cols = [("run", "run"), ("replay θ", "replay_theta_mse"), ("replay ω", "replay_omega_mse"),
            ("replay I", "replay_current_mse"), ("closed θ", "closed_loop_theta_mse"),
            ("closed ω", "closed_loop_omega_mse"), ("closed I", "closed_loop_current_mse"),
            ("switches log/sim", None), ("energy err %", "closed_loop_energy_error_pct")]
    for head, _ in cols:
        t.add_column(head, justify="left" if head == "run" else "right")
    for row in table.head(limit).to_dict("records"):
        cells = []
        for _head, key in cols:
            if key is None:
                cells.append("/".join(_count(row.get(k)) for k in ("measured_switches", "closed_loop_switches")))
            elif key == "run":
                cells.append(str(row[key]))
            else:
                cells.append(_g(row.get(key)))
        t.add_row(*cells)
    console.print(t)
    if len(table) > limit:
        console.print(f"... {len(table) - limit} more runs in processed/{SUMMARY_NAME}")
