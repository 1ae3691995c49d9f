"""Many runs' discoveries as tables: one row per run, and per rig and effect parameter the pooled
estimate, the agreement test and the trend over recording time (``pooled.py``); plus their plot.

Pure: discovery documents (``discovery.json``) in, DataFrames and PNG bytes out.
A rig is the physics a recording's TOML layers declare ([model], [effects],
[drive], [controller], [encoder]): recordings with the same declared rig
are pooled, whatever their sensor calibration, column names or file names.
"""

from __future__ import annotations

import hashlib
import io
import json
from datetime import datetime, timezone

import numpy as np
import pandas as pd

from pipeline.config import RigConfig
from pipeline.discover.pooled import pool, standard_errors, trend

RIG_SECTIONS = ("model", "effects", "drive", "controller", "encoder")
POOLED_COLUMNS = ("rig", "effect", "parameter", "runs", "runs_found", "pooled", "lo", "hi", "method", "q", "p_agree",
                  "agree", "i2", "tau", "trend_per_day", "trend_lo", "trend_hi", "p_trend", "change_pct", "span_days",
                  "trend_flagged")
DAY_S = 86400.0


def rig_key(config: RigConfig) -> str:
    """A short name for the declared rig (same physics, same key)."""
    d = config.to_dict()
    blob = json.dumps({s: d[s] for s in RIG_SECTIONS}, sort_keys=True)
    return "rig-" + hashlib.sha256(blob.encode()).hexdigest()[:8]


def iso_utc(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, tz=timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def run_row(doc: dict, recorded_s: float, rig: str) -> dict:
    """One run's row of ``summary.csv``: verdict, effects, each parameter with its interval, replay MSEs."""
    row: dict = {"run": doc["run"], "recording": doc["recording"], "recorded": iso_utc(recorded_s),
                 "recorded_s": recorded_s, "rig": rig, "verdict": doc["verdict"],
                 "effects": ";".join(e["name"] for e in doc["effects"])}
    for e in doc["effects"]:
        for param, value in e["parameters"].items():
            lo, hi = e["interval"][param]
            row[f"{e['name']}.{param}"] = value
            row[f"{e['name']}.{param}_lo"] = lo
            row[f"{e['name']}.{param}_hi"] = hi
    for sig, v in doc["mse_before"].items():
        row[f"mse_before_{sig}"] = v
    for sig, v in doc["mse_after"].items():
        row[f"mse_after_{sig}"] = v
    return row


def failed_row(recording: str, run: str, recorded_s: float | None, rig: str | None, error: str) -> dict:
    return {"run": run, "recording": recording, "recorded": iso_utc(recorded_s) if recorded_s is not None else None,
            "recorded_s": recorded_s, "rig": rig, "verdict": "failed", "effects": "", "error": error}


def summary_frame(rows: list[dict]) -> pd.DataFrame:
    """Runs in recording order (then name); fixed columns first, then each parameter's three columns."""
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    table = table.sort_values(["recorded_s", "run"], kind="stable", na_position="last").reset_index(drop=True)
    fixed = [c for c in ("run", "recording", "recorded", "recorded_s", "rig", "verdict", "effects", "error")
             if c in table.columns]
    params = sorted({c[:-3] for c in table.columns if c.endswith("_lo")})
    mse = sorted(c for c in table.columns if c.startswith("mse_"))
    return table[fixed + [c for p in params for c in (p, f"{p}_lo", f"{p}_hi")] + mse]


def parameters(table: pd.DataFrame) -> list[str]:
    return sorted(c[:-3] for c in table.columns if c.endswith("_lo"))


def pooled_frame(table: pd.DataFrame) -> pd.DataFrame:
    """Per rig and effect parameter: runs that found it, pooled estimate and interval, agreement, trend."""
    rows = []
    if table.empty or "rig" not in table.columns:
        return pd.DataFrame(rows, columns=list(POOLED_COLUMNS))
    done = table[table["verdict"] != "failed"]
    for rig, runs in done.groupby("rig", sort=True):
        for param in parameters(runs):
            found = runs[runs[param].notna()]
            if found.empty:
                continue
            x = found[param].to_numpy(float)
            se = standard_errors(found[f"{param}_lo"].to_numpy(float), found[f"{param}_hi"].to_numpy(float))
            keep = se > 0
            if not keep.any():
                continue
            p = pool(x[keep], se[keep])
            days = (found["recorded_s"].to_numpy(float) - float(found["recorded_s"].min())) / DAY_S
            tr = trend(days[keep], x[keep], se[keep], p)
            effect, name = param.split(".", 1)
            row = {"rig": rig, "effect": effect, "parameter": name, "runs": len(runs), "runs_found": int(keep.sum()),
                   "pooled": p.estimate, "lo": p.lo, "hi": p.hi, "method": p.method, "q": p.q,
                   "p_agree": p.p_agree, "agree": p.agree, "i2": p.i2, "tau": p.tau}
            if tr is not None:
                row.update(trend_per_day=tr.slope_per_day, trend_lo=tr.lo, trend_hi=tr.hi, p_trend=tr.p,
                           change_pct=tr.change_pct, span_days=tr.span_days, trend_flagged=tr.flagged)
            else:
                row.update(trend_flagged=False)
            rows.append(row)
    return pd.DataFrame(rows, columns=list(POOLED_COLUMNS))


def findings(pooled: pd.DataFrame) -> list[str]:
    """Console lines: each pooled parameter, whether the runs agree, and any flagged trend."""
    out = []
    for r in pooled.to_dict("records"):
        agree = ("runs agree" if r["agree"] else
                 f"runs disagree (Q = {r['q']:.1f}, p = {r['p_agree']:.2g}; between-run sd {r['tau']:.3g})")
        out.append(f"{r['rig']} {r['effect']}.{r['parameter']}: {r['pooled']:.5g} [{r['lo']:.5g}, {r['hi']:.5g}] "
                   f"from {r['runs_found']} of {r['runs']} runs, {agree}")
        if r.get("trend_flagged"):
            out.append(f"  TREND: {r['change_pct']:+.1f} % over {r['span_days']:.3g} days "
                       f"(slope {r['trend_per_day']:.3g}/day, p = {r['p_trend']:.2g})")
    return out


def parameters_png(table: pd.DataFrame, pooled: pd.DataFrame) -> bytes:
    """Each parameter over the runs (estimate and interval against recording time), one panel per rig and
    parameter, with the pooled band and, when flagged, the trend line."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    panels = [(r["rig"], f"{r['effect']}.{r['parameter']}", r) for r in pooled.to_dict("records")]
    n = max(1, len(panels))
    fig = Figure(figsize=(8.0, 2.6 * n), dpi=80)
    FigureCanvasAgg(fig)
    if not panels:
        fig.text(0.5, 0.5, "no effect found in any run", ha="center", va="center")
    for i, (rig, param, r) in enumerate(panels):
        ax = fig.add_subplot(n, 1, i + 1)
        runs = table[(table["rig"] == rig) & table[param].notna()]
        t0 = float(table.loc[table["rig"] == rig, "recorded_s"].min())
        days = (runs["recorded_s"].to_numpy(float) - t0) / DAY_S
        x = runs[param].to_numpy(float)
        err = np.vstack([x - runs[f"{param}_lo"].to_numpy(float), runs[f"{param}_hi"].to_numpy(float) - x])
        ax.errorbar(days, x, yerr=err, fmt="o", ms=3, color="tab:blue", lw=1, label="run (95 % interval)")
        ax.axhspan(r["lo"], r["hi"], color="tab:orange", alpha=0.3, label=f"pooled ({r['method']})")
        ax.axhline(r["pooled"], color="tab:orange", lw=1)
        if r.get("trend_flagged"):
            w = 1.0 / (err.mean(axis=0) / 1.96) ** 2
            mid_t, mid_x = np.average(days, weights=w), np.average(x, weights=w)
            ends = np.array([days.min(), days.max()])
            ax.plot(ends, mid_x + r["trend_per_day"] * (ends - mid_t), color="tab:red", lw=1.5,
                    label=f"trend {r['change_pct']:+.1f} % (p = {r['p_trend']:.1g})")
        ax.set_title(f"{rig}: {param}", fontsize=9)
        ax.set_xlabel("days since the rig's first recording", fontsize=8)
        ax.legend(fontsize=7, loc="best")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()
