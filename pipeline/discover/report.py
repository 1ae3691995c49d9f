"""What discovery hands back: JSON, an ``[effects]`` TOML snippet, a Markdown report with
PNG plots, and a Rerun recording with measurement, base and augmented model overlaid
(``rerun_report``).

Everything is rendered from a ``Discovery`` (pure functions returning text or bytes);
``write_report`` and ``write_figures`` are the only functions that touch the disk, atomically.  PNGs carry
no timestamp or version metadata, so a re-run gives identical bytes.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from pipeline.config import effects_toml_snippet
from pipeline.discover.rerun_report import write_rrd
from pipeline.discover.stage import Discovery, augmented_effects
from pipeline.io.atomic import write_bytes, write_json, write_text

FILES = {"json": "discovery.json", "toml": "effects.toml", "markdown": "report.md",
         "signals_png": "signals.png", "residuals_png": "residuals.png", "localisation_png": "localisation.png",
         "candidates_png": "candidates.png", "rrd": "discovery.rrd"}
_SIGNALS = (("theta", "theta_rad", "theta", "rad"), ("omega", "omega_rad_s", "omega", "rad/s"),
            ("current", "current_a", "current_measured", "A"))
_COLORS = {"measured": "0.25", "base": "tab:orange", "augmented": "tab:blue"}


def _measured(d: Discovery, column: str) -> np.ndarray | None:
    kin = d.meas.kinematics
    return kin[column].to_numpy(dtype=float, na_value=np.nan) if column in kin.columns else None


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, metadata={"Software": None}, pil_kwargs={"compress_level": 1})
    return buf.getvalue()


def _per_signal_png(d: Discovery, title: str, draw) -> bytes:
    """One panel per signal on a shared time axis; ``draw(ax, sig, field, unit, measured)``."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 7.5))
    axes = fig.subplots(3, 1, sharex=True)
    for ax, (sig, column, field, unit) in zip(axes, _SIGNALS):
        draw(ax, sig, field, unit, _measured(d, column))
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    return _png(fig)


def signals_png(d: Discovery, way: str = "replay") -> bytes:
    """Measured, base model and augmented model per signal, on one time axis."""
    t = d.meas.t

    def draw(ax, sig, field, unit, y):
        if y is not None:
            ax.plot(t, y, color=_COLORS["measured"], lw=1.4, label="measured")
        ax.plot(t, getattr(d.base[way], field), color=_COLORS["base"], lw=1.0, label="base model")
        if d.effects:
            ax.plot(t, getattr(d.final[way], field), color=_COLORS["augmented"], lw=1.0, ls="--",
                    label="augmented model")
        ax.set_ylabel(f"{sig} [{unit}]")
        if sig == "theta":
            ax.legend(loc="upper right", fontsize=8)

    return _per_signal_png(d, f"{d.meas.name}: {d.verdict} ({way.replace('_', ' ')})", draw)


def residuals_png(d: Discovery, way: str = "replay") -> bytes:
    """Residual (measured - model) before and after, per signal."""
    t = d.meas.t

    def draw(ax, sig, field, unit, y):
        if y is None:
            ax.set_ylabel(f"{sig}: not logged")
            return
        # the base model's residual a wide pale band, the augmented one's a thin line on it: where the
        # effects changed nothing the two coincide and both still show
        for label, sims, mse, color, lw, alpha in (("before", d.base, d.mse_before, _COLORS["base"], 2.6, 0.55),
                                                   ("after", d.final, d.mse_after, _COLORS["augmented"], 0.9, 1.0)):
            ax.plot(t, y - getattr(sims[way], field), color=color, lw=lw, alpha=alpha,
                    label=f"{label} (MSE {mse[way].get(sig, float('nan')):.3g})")
        ax.axhline(0.0, color="0.5", lw=0.6)
        ax.set_ylabel(f"residual {sig} [{unit}]")
        ax.legend(loc="upper right", fontsize=8)

    return _per_signal_png(d, f"{d.meas.name}: residuals before and after ({way.replace('_', ' ')})", draw)


def localisation_png(d: Discovery) -> bytes:
    """Residual RMS (noise standard deviations, log scale) by state bin and by lag after events,
    before and after: where the disagreement lives and whether the added effects removed it."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import LogLocator, MaxNLocator

    keys = [k for k, rows in d.tables_before.items() if rows]
    n_rows = max(1, (len(keys) + 2) // 3)       # one (empty) row when no table has rows, e.g. a stuck timer
    fig = Figure(figsize=(12, 2.2 * n_rows + 0.6))
    axes = fig.subplots(n_rows, 3, squeeze=False).ravel()
    styles = {"theta": "o-", "current": "s--"}
    for ax, key in zip(axes, keys):
        for label, tables, color in (("before", d.tables_before, _COLORS["base"]),
                                     ("after", d.tables_after, _COLORS["augmented"])):
            rows = tables[key]
            x = np.arange(len(rows))
            for s in d.meas.signals:
                ax.plot(x, [max(r[f"{s}_rms_noise"], 1e-3) for r in rows], styles.get(s, "o-"), color=color,
                        ms=3, lw=1.0, label=f"{s} {label}")
        ax.axhline(1.0, color="0.5", lw=0.6)
        ax.set_yscale("log")
        ax.yaxis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))    # 2 and 5 per decade: a third of the ticks
        ax.yaxis.set_major_formatter(_plain_log_formatter())
        ax.yaxis.set_minor_formatter(_plain_log_formatter(labelOnlyBase=False))
        ax.set_title(key.replace("_", " "), fontsize=9, y=1.0)   # y given: no search for ticks above
        ax.set_xlabel("lag [samples]" if "after" in key else "bin (quantiles, low to high)", fontsize=8)
        ax.set_ylabel("residual RMS / noise sigma", fontsize=8)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=7)
    for ax in axes[len(keys):]:
        ax.set_visible(False)
    if keys:                                   # one legend, above the panels, off the data
        fig.legend(*axes[0].get_legend_handles_labels(), loc="upper right", ncols=4, fontsize=7, frameon=False)
    else:
        fig.text(0.5, 0.5, "no state bins or event lags to localise the residual in", ha="center", va="center")
    fig.suptitle(f"{d.meas.name}: residual RMS / noise (1 = noise floor)", fontsize=10, x=0.3)
    _margins(fig, top=0.75, bottom=0.5, left=0.7, hspace=0.75, wspace=0.3)
    return _png(fig)


def _plain_log_formatter(**kwargs):
    """Log-axis tick labels as plain numbers ("0.1", "1", "20") on the ticks matplotlib's ``LogFormatter``
    labels; the default formatter writes them as mathtext ($10^{-1}$), whose parsing was half this figure's
    drawing."""
    from matplotlib.ticker import LogFormatter

    class PlainLogFormatter(LogFormatter):
        def __call__(self, x, pos=None):
            return f"{x:g}" if super().__call__(x, pos) else ""

    return PlainLogFormatter(**kwargs)


def _margins(fig, top: float, bottom: float, left: float, hspace: float, wspace: float = 0.2) -> None:
    """Fixed margins in inches: what ``tight_layout`` would find for these labels, without the extra
    draw it costs (it laid out the discovery figures in about as long as drawing them)."""
    w, h = fig.get_size_inches()
    fig.subplots_adjust(left=left / w, right=1 - 0.15 / w, bottom=bottom / h, top=1 - top / h,
                        hspace=hspace, wspace=wspace)


OUTCOME_COLORS = {"adopted": "tab:green", "adopted, later pruned": "yellowgreen",
                  "passed, not chosen": "tab:blue", "rejected": "0.55", "screened out": "white"}
# Screened out (never fitted) hatched on white, rejected (fitted, failed a check) solid grey: two
# greys alone looked alike.
OUTCOME_HATCHES = {"screened out": "////"}


def outcomes(d: Discovery) -> list[str]:
    """Per candidate of every round (``discovery_json``'s order): what became of it.  A round adopts
    the candidate that removes the most held-out likelihood among those that clear every check; the
    others that clear them are "passed, not chosen"."""
    final = {e.name for e in d.effects}
    out = []
    for rnd in d.selection.rounds:
        for a in rnd:
            if not hasattr(a, "fit"):
                out.append("screened out")
            elif a.accepted:
                out.append("adopted" if a.fit.name in final else "adopted, later pruned")
            else:
                out.append("passed, not chosen" if a.clears else "rejected")
    return out


def candidate_reason(a, fate: str) -> str:
    """What a bar's label says became of a candidate: for a rejected one, the checks it failed (the
    first two by name, the count of the others: the report's table lists them all)."""
    if fate == "rejected":
        failed = [k for k, ok in a.checks.items() if not ok]
        return "rejected: failed " + ", ".join(failed[:2]) + (f" +{len(failed) - 2}" if len(failed) > 2 else "")
    return {"screened out": "screened out (coarse scan)"}.get(fate, fate)


def score_limit(scores: list[float]) -> float:
    """A round's x range, fitted to the round's best score (a round whose scores are all small would
    draw zero-length bars on a fixed axis)."""
    top = max(scores, default=0.0)
    return max(0.01, nice_ceiling(1.15 * top)) if top > 0.0 else 0.01


def nice_ceiling(x: float) -> float:
    """The smallest 1, 2 or 5 times a power of ten that is >= x."""
    p = 10.0 ** float(np.floor(np.log10(x)))
    return next(m * p for m in (1.0, 2.0, 5.0, 10.0) if m * p >= x * (1 - 1e-12))


def candidates_figure(d: Discovery):
    """Each candidate's held-out evidence, per round: one bar per candidate,
    coloured (and, screened out, hatched) by what became of it, labelled with its name, the reason
    and its score; each round's axis fitted to its scores."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    rounds = d.selection.rounds
    fates = iter(outcomes(d))
    fig = Figure(figsize=(11, 1.4 + 0.3 * sum(len(r) for r in rounds) + 1.0 * max(len(rounds), 1)))
    axes = fig.subplots(max(len(rounds), 1), 1, squeeze=False,
                        height_ratios=[max(len(r), 1) for r in rounds] or None)[:, 0]
    seen: list[str] = []
    for ax, rnd in zip(axes, rounds):
        names = [a.fit.name if hasattr(a, "fit") else a.name for a in rnd]
        scores = [max(a.score, 0.0) for a in rnd]
        fate = [next(fates) for _ in rnd]
        seen += [f for f in fate if f not in seen]
        y = np.arange(len(rnd))[::-1]                                   # the first candidate on top
        # a score of 0 still gets a stub of its fate's colour; the printed score is the value
        ax.barh(y, [max(sc, 0.006 * score_limit(scores)) for sc in scores], color=[OUTCOME_COLORS[f] for f in fate],
                edgecolor="0.35", linewidth=0.6, hatch=[OUTCOME_HATCHES.get(f, "") for f in fate])
        ax.set_yticks(y, [f"{n} - {candidate_reason(a, f)}" for n, a, f in zip(names, rnd, fate)])
        hi = score_limit(scores)
        ax.set_xlim(0, hi)
        for yi, sc in zip(y, scores):
            ax.text(min(sc, hi) + 0.01 * hi, yi, f"{sc:.3f}", va="center", fontsize=7)
        charge = d.selection.policy.evidence_per_parameter
        if charge < hi:
            ax.axvline(charge, color="0.3", linestyle=":", linewidth=0.8)       # one parameter's charge
        ax.set_title(f"round {rnd[0].round}: held-out evidence (dotted: one parameter's charge)", fontsize=9, y=1.0)
        ax.tick_params(labelsize=8)
    axes[-1].set_xlabel("held-out negative log-likelihood removed, in independent samples", fontsize=8)
    order = [f for f in OUTCOME_COLORS if f in seen]
    fig.legend([Patch(facecolor=OUTCOME_COLORS[f], edgecolor="0.35", hatch=OUTCOME_HATCHES.get(f, ""))
                for f in order], order, loc="upper center", ncols=len(order), fontsize=8, frameon=False)
    _margins(fig, top=0.7, bottom=0.5, left=4.2, hspace=0.45)
    return fig


def candidates_png(d: Discovery) -> bytes:
    return _png(candidates_figure(d))


def _fmt(v: float) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.4g}"


def markdown(d: Discovery, doc: dict) -> str:
    """The static report for people who do not open the viewer."""
    lines = [f"# Discovery: {d.meas.name}", "", f"Recording: `{doc['recording']}`  ",
             f"Verdict: **{d.verdict}**  ", f"Simulations: {doc['simulations']}", ""]
    if check := doc.get("base_free_check"):
        from pipeline.discover.base_free import base_free_text

        lines += ["## The rig's own base model", "", base_free_text(check) + ". The effects below are valued "
                  "with the base free; the MSEs are against the declared (Table I) base.", ""]
        if doc.get("hint"):
            lines += [f"**Hint:** {doc['hint']}", ""]
    if d.effects:
        lines += ["## Effects added (in the order found)", "", "| effect | parameter | value | ~95 % interval | unit |",
                  "|---|---|---|---|---|"]
        for e in doc["effects"]:
            for p, v in e["parameters"].items():
                lo, hi = e.get("interval", {}).get(p, [float("nan")] * 2)
                lines.append(f"| `{e['name']}` | {p} | {_fmt(v)} | [{_fmt(lo)}, {_fmt(hi)}] | {e['units'][p]} |")
        lines += ["", "Adopt into the rig's TOML (`pdr discover RECORDING --adopt` does it for you):", "",
                  "```toml", doc["effects_toml"].rstrip(), "```", ""]
    lines += ["## MSE before and after", "", "| way | signal | before | after | change |", "|---|---|---|---|---|"]
    for way in ("replay", "closed_loop"):
        for sig, b in d.mse_before[way].items():
            a = d.mse_after[way].get(sig, float("nan"))
            change = f"{100 * (a - b) / b:+.1f} %" if b else "-"
            lines.append(f"| {way.replace('_', ' ')} | {sig} | {_fmt(b)} | {_fmt(a)} | {change} |")
    lines += ["", f"Closed loop confirms: {'yes' if d.closed_loop_confirmed else 'no'} "
              "(free runs jump when a simulated switch slips by one control period; replay is the fair measure).", ""]
    if doc.get("near_tie"):
        t = doc["near_tie"]
        lines += [f"**Near tie** in round {t['round']}: `{t['chosen']}` vs `{t['runner_up']}`, scores "
                  + ", ".join(f"{k} {_fmt(v)}" for k, v in t["scores"].items()) + ".", ""]
    if doc.get("unexplained"):
        lines += ["## Unexplained structure", ""] + [f"- {x}" for x in doc["unexplained"]] + [""]
    lines += ["## Where the base model disagrees (replay residuals)", ""]
    lines += [f"- {x}" for x in d.localisation_before] or ["- nothing above the noise floor"]
    lines += ["", "## After", ""] + ([f"- {x}" for x in d.localisation_after] or ["- nothing"])
    lines += ["", "## Residual RMS by state and after events (noise standard deviations; before -> after)", ""]
    lines += [f"![localisation]({FILES['localisation_png']})", ""] + _tables_md(d)
    lines += ["", "## Candidates", "",
              "| round | candidate | held-out evidence | value | ~95 % interval | charge | outcome |",
              "|---|---|---|---|---|---|---|"]
    for c, fate in zip(doc["candidates"], outcomes(d)):
        p, v = next(iter(c["parameters"].items()))
        lo, hi = c.get("interval", {}).get(p, [float("nan")] * 2)
        failed = ", ".join(k for k, ok in c.get("checks", {}).items() if not ok)
        result = {"screened out": "screened out by the coarse scan", "rejected": f"rejected: failed {failed}",
                  "passed, not chosen": "passed every check, not chosen (a better candidate was adopted)",
                  }.get(fate, fate)
        lines.append(f"| {c['round']} | `{c['name']}` | {_fmt(c['score'])} | {p} = {_fmt(v)} | "
                     f"[{_fmt(lo)}, {_fmt(hi)}] | {_fmt(c.get('charge', float('nan')))} | {result} |")
    lines += ["", "Held-out evidence: the negative log-likelihood the candidate removes on cycles it was not fitted "
              "on, in independent samples; an effect is adopted when it exceeds its charge (per parameter), removes "
              f"at least {d.selection.policy.min_heldout_share:.0%} of some signal's held-out structure, and is of a "
              "nameable size.", "",
              f"![signals]({FILES['signals_png']})", "", f"![residuals]({FILES['residuals_png']})", "",
              f"![candidates]({FILES['candidates_png']})", ""]
    return "\n".join(lines)


def _tables_md(d: Discovery) -> list[str]:
    sigs = list(d.meas.signals)
    out = []
    for key, rows in d.tables_before.items():
        after = d.tables_after.get(key, [])
        if not rows:
            continue
        first = "lag" if "lag" in rows[0] else "bin"
        out += [f"**{key.replace('_', ' ')}**", "", f"| {first} | n | " + " | ".join(sigs) + " |",
                "|---|---|" + "---|" * len(sigs)]
        for b, a in zip(rows, after):
            label = str(b["lag"]) if first == "lag" else f"{b['from']:.3g} .. {b['to']:.3g}"
            cells = " | ".join(f"{b[f'{s}_rms_noise']:.3g} -> {a[f'{s}_rms_noise']:.3g}" for s in sigs)
            out.append(f"| {label} | {b['n']} | {cells} |")
        out.append("")
    return out


def write_report(out_dir: Path, d: Discovery, doc: dict, *, rrd: bool = True) -> tuple[dict[str, Path], str]:
    """The JSON, the ``[effects]`` snippet and the Markdown report into ``out_dir`` (atomic writes): what
    the command's answer names, written before it is printed; the paths of every output (the figures' and,
    with ``rrd``, the .rrd's too, for ``write_figures``) and the Markdown."""
    out_dir = Path(out_dir)
    paths = {k: out_dir / v for k, v in FILES.items() if rrd or k != "rrd"}
    write_json(paths["json"], doc)
    write_text(paths["toml"], effects_toml_snippet(augmented_effects(d)))
    md = markdown(d, doc)
    write_text(paths["markdown"], md)
    return paths, md


def write_outputs(out_dir: Path, d: Discovery, doc: dict, *, rrd: bool = True) -> dict[str, Path]:
    """Every output of one discovery into ``out_dir`` (atomic writes); returns the paths."""
    paths, md = write_report(out_dir, d, doc, rrd=rrd)
    write_figures(paths, d, md, rrd=rrd)
    return paths


FIGURES = {"signals_png": signals_png, "residuals_png": residuals_png, "candidates_png": candidates_png,
           "localisation_png": localisation_png}


def write_figures(paths: dict[str, Path], d: Discovery, report_md: str, *, rrd: bool) -> None:
    """The four PNGs and (``rrd``) the Rerun recording, at ``paths`` (``FILES``' keys)."""
    for key, draw in FIGURES.items():
        write_bytes(paths[key], draw(d))
    if rrd:
        write_rrd(paths["rrd"], d, report_md)


def dumps(doc: dict) -> str:
    """The JSON as printed by ``pdr discover --json`` (one object, stable key order)."""
    return json.dumps(doc, indent=2, sort_keys=True, allow_nan=False, default=float)
