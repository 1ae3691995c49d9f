"""One Rerun recording per run: measured vs simulated, the guards, the 3-D trajectory.

What the viewer shows (the layout, ``rerun_blueprint.run_blueprint``, is saved
inside the ``.rrd``, so it opens on it):

- theta, omega, current: the measurement over the simulations on one time
  axis (one entity per signal, ``signals/theta``, whose scalar instances are
  the series), each with its residual beside it; the guards at +/- theta_g,
  switch and guard-crossing points on the angle plot;
- when the closed loop switches at exactly the logged samples it is the same
  computation as the replay (``coincidence``): one series "closed loop = replay"
  is drawn instead of two lines on top of each other, with one residual and
  one mode lane;
- the phase portrait in (current, omega, theta) with the guard planes
  (``rerun_phase``), the measured curve from the derive stage's smoothed current;
- a mode lane (``StateChange``), an event log (WARN only for what breaks the
  controller's rule), and a text panel with the metrics, per-phase and
  overshoot statistics.

Everything with time is sent with ``send_columns`` (one call per entity), which
is what keeps a 500-sample run to a few milliseconds of logging.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.model.simulate import SimResult
from pipeline.validate.compare import logged_dir, switch_indices
from pipeline.validate.rerun_blueprint import RUN_VIEW_NAMES, axis_ranges, legend_band, run_blueprint, tick_range
from pipeline.validate.rerun_io import (blueprint_chunks, rerun_executable, save_with_blueprint,  # noqa: F401
                                        verify_rrd, verify_rrds)
from pipeline.validate.rerun_phase import log_phase_portrait

TIMELINE = "time"
VIEW_NAMES = RUN_VIEW_NAMES
# Closed loop and replay are drawn as one series when every command agrees and no signal differs
# by more than this share of its peak: 1e-9 of 1.2 rad is six orders below an encoder step,
# invisible at any zoom, and far above the ~1e-15 by which the same computation can differ.
COINCIDENCE_TOL = 1e-9
# A logged reversal counts as "at the guard" within this much of it: the encoder's steps (1e-3 rad at
# x4 decoding, 4e-3 at x1) put the sampled angle up to a step on the near side of the true one.
GUARD_SLACK_RAD = 0.01


def _rgba(r: int, g: int, b: int, a: int = 255) -> int:
    """A colour as rerun's packed 0xRRGGBBAA (its fast path: no per-call array coercion)."""
    return (r << 24) | (g << 16) | (b << 8) | a


RGB = {"measured": (230, 230, 230), "closed_loop": (255, 140, 0), "replay": (0, 170, 255),
       "guard": (230, 60, 60)}
MEASURED, CLOSED, GUARD = (_rgba(*RGB[k]) for k in ("measured", "closed_loop", "guard"))
# signal -> (kinematics column, SimResult field, unit)
SIGNALS = {"theta": ("theta_rad", "theta", "rad"), "omega": ("omega_rad_s", "omega", "rad/s"),
           "current": ("current_a", "current_measured", "A")}
MODE_NAMES = {1: "q1 (u = +V)", -1: "q2 (u = -V)", 0: "off"}
# The mode lane's states: raw value, label drawn on the lane (short: a lane segment is ~1 s wide), colour.
MODE_STATES = {1: ("q1", "q1 +V", (60, 160, 90)), -1: ("q2", "q2 -V", (150, 90, 210)), 0: ("off", "off", (90, 90, 90))}


def coincidence(a: SimResult, b: SimResult) -> float | None:
    """The largest difference between two simulations, as a share of each signal's peak;
    None when their commands differ at any sample."""
    if not np.array_equal(a.dir, b.dir):
        return None
    worst = 0.0
    for field in ("theta", "omega", "current_measured"):
        x, y = getattr(a, field), getattr(b, field)
        peak = max(float(np.max(np.abs(x))), float(np.max(np.abs(y))), 1e-300)
        worst = max(worst, float(np.max(np.abs(x - y))) / peak)
    return worst


def ways_coincide(sims: dict[str, SimResult]) -> bool:
    c = coincidence(sims["closed_loop"], sims["replay"]) if len(sims) == 2 else None
    return c is not None and c <= COINCIDENCE_TOL


def model_series(sims: dict[str, SimResult]) -> dict[str, tuple[SimResult, tuple]]:
    """The model lines to draw: label -> (simulation, RGB colour); the ways run (fewer without an encoder)."""
    if ways_coincide(sims):
        return {"closed loop = replay": (sims["closed_loop"], RGB["closed_loop"])}
    return {way.replace("_", " "): (sims[way], RGB[way]) for way in ("closed_loop", "replay") if way in sims}


def _measured(kin: pd.DataFrame, name: str) -> np.ndarray | None:
    if name not in kin.columns:
        return None
    return column(kin, name, dtype=float, na_value=np.nan)


@functools.lru_cache(maxsize=None)
def _series_style(kind: str, names: tuple[str, ...], colors: tuple, widths: tuple[float, ...] = (1.5,),
                  marker: str = ""):
    """The static style of an entity's series (one per scalar instance), built once per process:
    the same few styles recur in every run, and building one is ~0.2 ms of rerun's Python converters."""
    import rerun as rr

    packed = np.array([c if isinstance(c, int) else _rgba(*c) for c in colors], dtype=np.uint32)
    if kind == "points":
        return rr.SeriesPoints(names=list(names), colors=packed, markers=marker, marker_sizes=4.0)
    return rr.SeriesLines(names=list(names), colors=packed, widths=list(widths))


def log_signal(rec, path: str, time_column, series: dict[str, tuple[np.ndarray, int | tuple, float]]) -> None:
    """Several series of one signal as one entity, one scalar instance each, drawn in order (the last on top).

    One row per sample instead of one per sample and series: a third of the
    rows (each costs rerun a 16-byte row id and a time), one log call instead
    of three.  The viewer draws each instance as its own line, named and
    coloured by ``SeriesLines``.  A sample a series lacks (NaN) is a gap.
    """
    import rerun as rr

    names = tuple(series)
    rec.log(path, _series_style("lines", names, tuple(c for _v, c, _w in series.values()),
                                tuple(w for _v, _c, w in series.values())), static=True)
    values = np.column_stack([v for v, _c, _w in series.values()])
    rec.send_columns(path, indexes=[time_column], columns=rr.Scalars.columns(scalars=values))


def log_guards(rec, path: str, t: np.ndarray, guard: float) -> None:
    """The guards +/- theta_g as one entity of two instances under one name (one legend entry)."""
    import rerun as rr

    ends = t[[0, -1]]          # a guard is a straight line: its two ends are enough
    name = f"guards +/-{guard:.3f} rad"
    rec.log(path, _series_style("lines", (name, name), (GUARD, GUARD), (1.0, 1.0)), static=True)
    rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=ends)],
                     columns=rr.Scalars.columns(scalars=np.array([[guard, -guard]] * 2)))


def log_points(rec, path: str, t: np.ndarray, values: np.ndarray, name: str, color, marker: str) -> None:
    import rerun as rr

    rec.log(path, _series_style("points", (name,), (color,), marker=marker), static=True)
    if len(t):
        rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                         columns=rr.Scalars.columns(scalars=values))


def log_mode_lane(rec, path: str, t: np.ndarray, d: np.ndarray) -> None:
    """The command as a state lane, one colour per mode."""
    import rerun as rr

    rec.log(path, _mode_configuration(), static=True)
    change = np.concatenate([[0], np.flatnonzero(d[1:] != d[:-1]) + 1])
    states = [MODE_STATES[int(v)][0] for v in d[change]]
    rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t[change])],
                     columns=rr.StateChange.columns(state=states))


@functools.lru_cache(maxsize=1)
def _mode_configuration():
    import rerun as rr

    values, labels, colors = zip(*MODE_STATES.values())
    return rr.StateConfiguration(values=list(values), labels=list(labels),
                                 colors=np.array([_rgba(*c) for c in colors], dtype=np.uint32))


def guard_crossings(theta: np.ndarray, guard: float) -> np.ndarray:
    """Samples at which the angle first reaches a guard (|theta| >= theta_g after being inside)."""
    outside = np.abs(theta) >= guard
    return np.flatnonzero(outside[1:] & ~outside[:-1]) + 1


def event_rows(t: np.ndarray, theta: np.ndarray, d: np.ndarray, sims: dict[str, SimResult], guard: float,
               period: float) -> list[tuple[float, str, str]]:
    """The event log: (time, text, level), time-ordered.

    INFO: logged switches and guard crossings, what a healthy run is made of.
    DEBUG: the closed loop's own switches (listed only when it departs from the replay).
    WARN: what breaks the controller's rule -- a logged q1/q2 reversal with the
    angle inside the guards, a guard reached without the command reversing
    within a sample of it (the encoder's step can put the sampled crossing one
    sample either side), a closed-loop switch more than one control period
    from every logged one.
    """
    rows: list[tuple[float, str, str]] = []
    sw = switch_indices(d)
    for k in sw:
        a, b = int(d[k - 1]), int(d[k])
        if theta is None:           # no encoder: the switch, without where the pinion was
            rows.append((t[k], f"switch {MODE_NAMES[a]} -> {MODE_NAMES[b]} (logged)", "INFO"))
            continue
        inside = a * b == -1 and abs(theta[k]) < guard - GUARD_SLACK_RAD
        rows.append((t[k], f"switch {MODE_NAMES[a]} -> {MODE_NAMES[b]} (logged), theta = {theta[k]:+.3f} rad"
                     + (" inside the guards" if inside else ""), "WARN" if inside else "INFO"))
    for k in guard_crossings(theta, guard) if theta is not None else ():
        reversed_ = np.any((sw >= k - 1) & (sw <= k + 1)) or d[k] == 0
        rows.append((t[k], f"guard reached (measured): theta = {theta[k]:+.3f} rad"
                     + ("" if reversed_ else ", the logged command did not reverse"), "INFO" if reversed_ else "WARN"))
    if "closed_loop" in sims and not ways_coincide(sims):
        cl = sims["closed_loop"]
        for k in switch_indices(cl.dir):
            slip = float(np.min(np.abs(t[sw] - t[k]))) if len(sw) else np.inf
            late = slip > 1.5 * period
            rows.append((t[k], f"switch -> {MODE_NAMES[int(cl.dir[k])]} (closed-loop simulation), theta = "
                         f"{cl.theta[k]:+.3f} rad" + (f", {slip:.2f} s from any logged switch" if late else ""),
                         "WARN" if late else "DEBUG"))
    rows.sort(key=lambda r: r[0])
    return [(tk, f"t = {tk:7.3f} s  {text}", level) for tk, text, level in rows]


def _events(rec, rows: list[tuple[float, str, str]]) -> None:
    import rerun as rr

    if rows:
        rec.send_columns("events", indexes=[rr.TimeColumn(TIMELINE, duration=[r[0] for r in rows])],
                         columns=rr.TextLog.columns(text=[r[1] for r in rows], level=[r[2] for r in rows]))


def theta_band(kin: pd.DataFrame, sims: dict[str, SimResult], guard: float, entries: int) -> tuple[float, float]:
    """The angle plot's y range: the data and the guards, rounded out to 0.1 rad, with the legend's
    band on top."""
    values = [np.abs(s.theta) for s in sims.values()] + [np.abs(column(kin, c, dtype=float))
                                                          for c in ("theta_rad",) if c in kin.columns]
    peak = max([guard, *(float(np.nanmax(v)) for v in values)])
    peak = float(np.ceil(peak * 10.0) / 10.0)
    lo, hi = legend_band(-peak, peak, entries)
    return round(lo, 3), round(hi, 3)


def residual_ranges(kin: pd.DataFrame, sims) -> tuple:
    """Each residual plot's y range (``tick_range`` of the largest residual of any simulation)."""
    out = []
    for name_in_kin, field, _unit in SIGNALS.values():
        meas = _measured(kin, name_in_kin)
        peak = max((float(np.nanmax(np.abs(meas - getattr(s, field)))) for s in sims if meas is not None),
                   default=np.nan)
        out.append(tick_range(peak))
    return tuple(out)


def log_run(rec, name: str, kin: pd.DataFrame, sims: dict[str, SimResult], validation: dict,
            guard: float, derived: dict[str, dict[str, np.ndarray]] | None = None, period: float = 0.05) -> None:
    """Log one run into an open recording stream (no file handling here)."""
    import rerun as rr

    t = column(kin, "t_s", dtype=float)
    every = rr.TimeColumn(TIMELINE, duration=t)
    d = logged_dir(kin) if "dir" in kin.columns else None
    models = model_series(sims)
    for sig, (name_in_kin, field, _unit) in SIGNALS.items():
        meas = _measured(kin, name_in_kin)
        lines = {label: (getattr(sim, field), color, 1.5) for label, (sim, color) in models.items()}
        if meas is not None:
            lines["measured"] = (meas, RGB["measured"], 1.5)
        if lines:           # no encoder and no model: no angle plot at all
            log_signal(rec, f"signals/{sig}", every, lines)
        if meas is not None and models:
            residuals = {f"measured - {'model' if len(models) == 1 else label}": (meas - getattr(sim, field), color, 1.5)
                         for label, (sim, color) in models.items()}
            log_signal(rec, f"residuals/{sig}", every, residuals)
    theta = _measured(kin, "theta_rad")       # None without an encoder: what needs it is left out
    if theta is not None or models:
        log_guards(rec, "signals/theta/guards", t, guard)
    if theta is not None:
        sw = switch_indices(d)
        log_points(rec, "signals/theta/switches_logged", t[sw], theta[sw], "switch (logged)", MEASURED, "diamond")
        gc = guard_crossings(theta, guard)
        log_points(rec, "signals/theta/guard_crossings", t[gc], theta[gc], "guard crossing", GUARD, "circle")
    if len(models) > 1:
        sw_cl = switch_indices(sims["closed_loop"].dir)
        log_points(rec, "signals/theta/switches_closed_loop", t[sw_cl], sims["closed_loop"].theta[sw_cl],
                   "switch (closed loop)", CLOSED, "cross")
    if d is not None:
        log_mode_lane(rec, "mode/logged", t, d)
    if len(models) > 1:
        log_mode_lane(rec, "mode/closed_loop", t, sims["closed_loop"].dir)
    if d is not None:
        _events(rec, event_rows(t, theta, d, sims, guard, period))
    log_phase_portrait(rec, "trajectory", portrait_strips(kin, models), guard)
    coincide = coincidence(*sims.values()) if len(sims) == 2 else None
    rec.log("stats", rr.TextDocument(stats_markdown(name, validation, derived, coincide),
                                     media_type=rr.MediaType.MARKDOWN), static=True)


def legend_entries(sims: dict[str, SimResult]) -> int:
    """Lines of the angle plot's legend: the models, measured, guards, logged switches, guard
    crossings, and the closed loop's switches when it departs from the replay."""
    models = len(model_series(sims))
    return models + 4 + (models > 1)


def portrait_strips(kin: pd.DataFrame, models: dict[str, tuple[SimResult, tuple]]) -> dict:
    """The phase portrait's curves: the models, then the measurement on top, its current the derive
    stage's smoothed one (the raw current's ADC steps and noise would scribble over the curve)."""
    strips = {label: (np.column_stack([sim.current_measured, sim.omega, sim.theta]), color, 1.0)
              for label, (sim, color) in models.items()}
    label, current = "measured (smoothed current)", _measured(kin, "current_smooth_a")
    if current is None:
        label, current = "measured", _measured(kin, "current_a")
    if current is not None and "theta_rad" in kin.columns:       # no encoder: no measured trajectory
        measured = np.column_stack([current, _measured(kin, "omega_rad_s"), _measured(kin, "theta_rad")])
        strips[label] = (measured, RGB["measured"], 1.5)
    return strips


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "nan" if not np.isfinite(v) else f"{v:.4g}"
    return str(v)


def stats_markdown(name: str, validation: dict, derived: dict[str, dict[str, np.ndarray]] | None = None,
                   coincide: float | None = None) -> str:
    """The statistics panel: metrics of both ways, oscillation/overshoot, energy, per-phase table.
    ``coincide``: ``coincidence`` of the two simulations, said first when they are drawn as one."""
    ways = tuple(w for w in ("closed_loop", "replay") if validation.get(w))   # fewer without an encoder
    lines = [f"# {name}", ""]
    for why in (validation.get("skipped") or {}).values():
        lines += [why[0].upper() + why[1:] + ".", ""]
    if coincide is not None and coincide <= COINCIDENCE_TOL:
        apart = "are identical" if coincide == 0.0 else f"differ by at most {coincide:.1g} of a signal's peak"
        lines += [f"Closed loop = replay: the closed loop switches at the logged samples; the two simulations "
                  f"{apart} and are drawn as one line.", ""]
    lines += ["## Errors (measured - simulated)", "",
             "| signal | way | MSE | RMSE | fit % |", "|---|---|---|---|---|"]
    for way in ways:
        for sig, e in validation[way]["signals"].items():
            unit = SIGNALS[sig][2]
            lines.append(f"| {sig} [{unit}] | {way} | {_fmt(e['mse'])} | {_fmt(e['rmse'])} | {_fmt(e['fit_pct'])} |")
    lines += ["", "## Oscillation and overshoot (Sec. IV-B)", "",
              "| | half-cycles | period [s] | amplitude [rad] | overshoot [rad] |", "|---|---|---|---|---|"]
    rows = [("measured", validation["measured"]["oscillation"])] + [(w, validation[w]["oscillation"]) for w in ways]
    for label, o in ((label, o) for label, o in rows if o is not None):
        lines.append(f"| {label} | {o['n_half_cycles']} | {_fmt(o['period_s'])} | {_fmt(o['amplitude_rad'])} "
                     f"| {_fmt(o['overshoot_rad'])} |")
    lines += ["", "## Switches", "", "| way | logged | simulated | mean slip [s] | max slip [s] |",
              "|---|---|---|---|---|"]
    for way in ways:
        s = validation[way]["switches"]
        lines.append(f"| {way} | {s['n_measured']} | {s['n_simulated']} | {_fmt(s['mean_abs_s'])} "
                     f"| {_fmt(s['max_abs_s'])} |")
    me = validation["measured"]["energy"]
    lines += ["", "## Energy (Sec. IV-C, paper estimate)", ""]
    if me is not None:
        lines.append(f"- measured: {me['energy_paper_j']:.3f} J")
    for way in ways:
        err = validation[way]["energy_error"]
        # no percentage when the measured energy is zero (a constant current): nothing to compare against
        extra = f" ({err['paper_pct']:+.2f} % vs measured)" if err and err.get("paper_pct") is not None else ""
        lines.append(f"- {way}: {validation[way]['energy']['energy_paper_j']:.3f} J{extra}")
    for title, key in (("Per phase (derive stage)", "phases"), ("Guard overshoot per crossing (derive stage)",
                                                                "overshoot")):
        table = (derived or {}).get(key)
        if table and len(next(iter(table.values()))):
            lines += ["", f"## {title}", "", *_md_table(table)]
    return "\n".join(lines) + "\n"


def _md_table(columns: dict[str, np.ndarray]) -> list[str]:
    head = "| " + " | ".join(map(str, columns)) + " |"
    rule = "|" + "---|" * len(columns)
    body = ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in zip(*(a.tolist() for a in columns.values()))]
    return [head, rule, *body]




def write_rrd(target: Path, name: str, kin: pd.DataFrame, sims: dict[str, SimResult], validation: dict,
              guard: float, derived: dict[str, dict[str, np.ndarray]] | None = None, verify: bool = True,
              period: float = 0.05) -> None:
    """Save to a temporary file beside ``target``, close the stream, verify, rename."""
    import rerun as rr

    from pipeline.io.atomic import atomic_path

    ranges = axis_ranges(run_blueprint, theta_band(kin, sims, guard, legend_entries(sims)),
                         residual_ranges(kin, sims.values()))
    with atomic_path(Path(target)) as tmp:
        rec = rr.RecordingStream("pdr", recording_id=name)
        save_with_blueprint(rec, tmp, blueprint_chunks(run_blueprint), y_ranges=ranges)
        log_run(rec, name, kin, sims, validation, guard, derived, period)
        rec.flush()
        rec.disconnect()
        if verify:
            verify_rrd(tmp)
