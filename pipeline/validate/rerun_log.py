"""One Rerun recording per run: measured vs simulated, the guards, the 3-D trajectory.

What the viewer shows (the blueprint is saved inside the ``.rrd``, so it
opens on this layout):

- theta, omega, current: measured, closed-loop and replay simulations on one
  time axis (one entity per signal, ``signals/theta``, whose three scalar
  instances are the three series; ``residuals/theta`` likewise), the guards at
  +/- theta_g on the angle plot, switch and guard-crossing events as points;
- the trajectory in (current, omega, theta) for measured and simulated runs
  with the two guard planes theta = +/- theta_g (the paper's Figs. 7 and 8).
  The three axes differ by an order of magnitude (0.5 A, 10 rad/s, 1.2 rad),
  so the data stay in SI units and a ``Transform3D`` scale on ``trajectory``
  maps each axis's extent to +/-1; labelled arrows give the axes and units;
- a mode lane (``StateChange``), an event log, the residuals, and a text
  panel with the metrics, per-phase and overshoot statistics.

Everything with time is sent with ``send_columns`` (one call per entity), which
is what keeps a 500-sample run to a few milliseconds of logging.
"""

from __future__ import annotations

import functools
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.errors import PdrError
from pipeline.model.simulate import SimResult
from pipeline.validate.compare import logged_dir, switch_indices

TIMELINE = "time"


def _rgba(r: int, g: int, b: int, a: int = 255) -> int:
    """A colour as rerun's packed 0xRRGGBBAA (its fast path: no per-call array coercion)."""
    return (r << 24) | (g << 16) | (b << 8) | a


MEASURED, CLOSED, REPLAY, GUARD = _rgba(200, 200, 200), _rgba(255, 140, 0), _rgba(0, 170, 255), _rgba(230, 60, 60)
GUARD_PLANE = _rgba(230, 60, 60, 70)
SERIES = {"measured": MEASURED, "closed_loop": CLOSED, "replay": REPLAY}
# signal -> (kinematics column, SimResult field, unit)
SIGNALS = {"theta": ("theta_rad", "theta", "rad"), "omega": ("omega_rad_s", "omega", "rad/s"),
           "current": ("current_a", "current_measured", "A")}
MODE_NAMES = {1: "q1 (u = +V)", -1: "q2 (u = -V)", 0: "off"}

# The views of the saved blueprint, by name (the viewer test checks each is present).
VIEW_NAMES = ("theta [rad]", "omega [rad/s]", "current [A]", "mode", "trajectory (I, w, theta)",
              "residual theta [rad]", "residual omega [rad/s]", "residual current [A]", "statistics", "events")


def blueprint():
    """The layout the viewer opens on: signals left, 3-D trajectory and tabs right."""
    import rerun.blueprint as rrb

    def series(name: str, origin: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(origin=origin, name=name,
                                  plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightTop, visible=True))

    left = rrb.Vertical(
        series("theta [rad]", "/signals/theta"),
        series("omega [rad/s]", "/signals/omega"),
        series("current [A]", "/signals/current"),
        rrb.StateTimelineView(origin="/mode", name="mode"),
        row_shares=[3, 3, 3, 2],
    )
    right = rrb.Vertical(
        rrb.Spatial3DView(origin="/trajectory", name="trajectory (I, w, theta)",
                          background=rrb.Background(color=(20, 20, 24))),
        rrb.Tabs(
            rrb.Vertical(series("residual theta [rad]", "/residuals/theta"),
                         series("residual omega [rad/s]", "/residuals/omega"),
                         series("residual current [A]", "/residuals/current"), name="residuals"),
            rrb.TextDocumentView(origin="/stats", name="statistics"),
            rrb.TextLogView(origin="/events", name="events"),
        ),
        row_shares=[3, 2],
    )
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[3, 2]),
                         rrb.TimePanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         rrb.BlueprintPanel(state="collapsed"), auto_views=False)


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


def _scalars(rec, path: str, t: np.ndarray, values: np.ndarray, name: str, color, width: float = 1.5) -> None:
    """One time series (its non-finite samples left out)."""
    import rerun as rr

    ok = np.isfinite(values)
    rec.log(path, _series_style("lines", (name,), (color,), (width,)), static=True)
    rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t[ok])],
                     columns=rr.Scalars.columns(scalars=values[ok]))


def log_signal(rec, path: str, time_column, series: dict[str, tuple[np.ndarray, int, float]]) -> None:
    """Several series of one signal (measured, closed loop, replay) as one entity, one scalar instance each.

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


def _points(rec, path: str, t: np.ndarray, values: np.ndarray, name: str, color, marker: str) -> None:
    import rerun as rr

    rec.log(path, _series_style("points", (name,), (color,), marker=marker), static=True)
    if len(t):
        rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                         columns=rr.Scalars.columns(scalars=values))


def _mode_lane(rec, path: str, t: np.ndarray, d: np.ndarray) -> None:
    import rerun as rr

    change = np.concatenate([[0], np.flatnonzero(d[1:] != d[:-1]) + 1])
    states = [MODE_NAMES[int(v)] for v in d[change]]
    rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t[change])],
                     columns=rr.StateChange.columns(state=states))


def guard_crossings(theta: np.ndarray, guard: float) -> np.ndarray:
    """Samples at which the angle first reaches a guard (|theta| >= theta_g after being inside)."""
    outside = np.abs(theta) >= guard
    return np.flatnonzero(outside[1:] & ~outside[:-1]) + 1


def _events(rec, t: np.ndarray, theta: np.ndarray, d: np.ndarray, sim: SimResult, guard: float) -> None:
    import rerun as rr

    rows: list[tuple[float, str, str]] = []
    for k in switch_indices(d):
        rows.append((t[k], f"switch {MODE_NAMES[int(d[k - 1])]} -> {MODE_NAMES[int(d[k])]} (logged), "
                           f"theta = {theta[k]:+.3f} rad", "INFO"))
    for k in switch_indices(sim.dir):
        rows.append((t[k], f"switch -> {MODE_NAMES[int(sim.dir[k])]} (closed-loop simulation), "
                           f"theta = {sim.theta[k]:+.3f} rad", "DEBUG"))
    for k in guard_crossings(theta, guard):
        rows.append((t[k], f"guard crossed (measured): theta = {theta[k]:+.3f} rad, |theta| >= {guard:.4f}", "WARN"))
    if not rows:
        return
    rows.sort(key=lambda r: r[0])
    rec.send_columns("events", indexes=[rr.TimeColumn(TIMELINE, duration=[r[0] for r in rows])],
                     columns=rr.TextLog.columns(text=[r[1] for r in rows], level=[r[2] for r in rows]))


def _extent(*arrays: np.ndarray | None, floor: float) -> float:
    vals = [np.nanmax(np.abs(a)) for a in arrays if a is not None and np.isfinite(a).any()]
    return max([floor, *vals]) * 1.05


def _trajectory(rec, kin: pd.DataFrame, sims: dict[str, SimResult], guard: float) -> None:
    import rerun as rr

    theta = _measured(kin, "theta_rad")
    omega = _measured(kin, "omega_rad_s")
    current = _measured(kin, "current_a")
    cl = sims["closed_loop"]
    ext = np.array([_extent(current, cl.current_measured, floor=0.05),
                    _extent(omega, cl.omega, floor=0.5),
                    _extent(theta, cl.theta, floor=guard)])
    # Each axis's extent maps to 1 so the trajectory fills the view whatever the units.
    rec.log("trajectory", rr.Transform3D(scale=(1.0 / ext).tolist()), static=True)
    strips = {"closed_loop": np.column_stack([cl.current_measured, cl.omega, cl.theta]),
              "replay": np.column_stack([sims["replay"].current_measured, sims["replay"].omega,
                                         sims["replay"].theta])}
    if current is not None:
        m = np.column_stack([current, omega, theta])
        strips["measured"] = m[np.isfinite(m).all(axis=1)]
    for name, xyz in strips.items():
        rec.log(f"trajectory/{name}", rr.LineStrips3D([xyz], colors=[SERIES[name]], radii=rr.Radius.ui_points(1.0),
                                                     labels=[name.replace("_", " ")], show_labels=False), static=True)
    rec.log("trajectory/guard_planes", rr.Boxes3D(
        centers=[[0.0, 0.0, guard], [0.0, 0.0, -guard]],
        half_sizes=[[ext[0], ext[1], ext[2] * 0.002]] * 2,
        colors=[GUARD_PLANE] * 2, fill_mode="solid",
        labels=[f"guard theta = +{guard:.3f} rad", f"guard theta = -{guard:.3f} rad"]), static=True)
    units = (("current I", "A"), ("omega w", "rad/s"), ("theta", "rad"))
    rec.log("trajectory/axes", rr.Arrows3D(
        vectors=np.diag(ext).tolist(), origins=[[0.0, 0.0, 0.0]] * 3,
        colors=np.array([_rgba(255, 80, 80), _rgba(80, 220, 80), _rgba(90, 140, 255)], dtype=np.uint32),
        radii=rr.Radius.ui_points(1.5),
        labels=[f"{n} [{u}] (to {e:.3g} {u})" for (n, u), e in zip(units, ext)]), static=True)


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "nan" if not np.isfinite(v) else f"{v:.4g}"
    return str(v)


def stats_markdown(name: str, validation: dict, derived: dict[str, dict[str, np.ndarray]] | None = None) -> str:
    """The statistics panel: metrics of both ways, oscillation/overshoot, energy, per-phase table."""
    ways = ("closed_loop", "replay")
    lines = [f"# {name}", "", "## Errors (measured - simulated)", "",
             "| signal | way | MSE | RMSE | fit % |", "|---|---|---|---|---|"]
    for way in ways:
        for sig, e in validation[way]["signals"].items():
            unit = SIGNALS[sig][2]
            lines.append(f"| {sig} [{unit}] | {way} | {_fmt(e['mse'])} | {_fmt(e['rmse'])} | {_fmt(e['fit_pct'])} |")
    lines += ["", "## Oscillation and overshoot (Sec. IV-B)", "",
              "| | half-cycles | period [s] | amplitude [rad] | overshoot [rad] |", "|---|---|---|---|---|"]
    rows = [("measured", validation["measured"]["oscillation"])] + [(w, validation[w]["oscillation"]) for w in ways]
    for label, o in rows:
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


def log_run(rec, name: str, kin: pd.DataFrame, sims: dict[str, SimResult], validation: dict,
            guard: float, derived: dict[str, dict[str, np.ndarray]] | None = None) -> None:
    """Log one run into an open recording stream (no file handling here)."""
    import rerun as rr

    t = column(kin, "t_s", dtype=float)
    every = rr.TimeColumn(TIMELINE, duration=t)
    d = logged_dir(kin)
    for sig, (name_in_kin, field, _unit) in SIGNALS.items():
        meas = _measured(kin, name_in_kin)
        sim = {way: getattr(sims[way], field) for way in ("closed_loop", "replay")}
        lines = {} if meas is None else {"measured": (meas, MEASURED, 2.0)}
        lines.update({way.replace("_", " "): (v, SERIES[way], 1.5) for way, v in sim.items()})
        log_signal(rec, f"signals/{sig}", every, lines)
        if meas is not None:
            residuals = {f"measured - {way.replace('_', ' ')}": (meas - v, SERIES[way], 1.5) for way, v in sim.items()}
            log_signal(rec, f"residuals/{sig}", every, residuals)
    ends = t[[0, -1]]          # a guard is a straight line: its two ends are enough
    _scalars(rec, "signals/theta/guard_upper", ends, np.full(2, guard), "+guard", GUARD, 1.0)
    _scalars(rec, "signals/theta/guard_lower", ends, np.full(2, -guard), "-guard", GUARD, 1.0)
    theta = _measured(kin, "theta_rad")
    sw = switch_indices(d)
    _points(rec, "signals/theta/switches_logged", t[sw], theta[sw], "switch (logged)", MEASURED, "diamond")
    sw_cl = switch_indices(sims["closed_loop"].dir)
    _points(rec, "signals/theta/switches_closed_loop", t[sw_cl], sims["closed_loop"].theta[sw_cl],
            "switch (closed loop)", CLOSED, "cross")
    gc = guard_crossings(theta, guard)
    _points(rec, "signals/theta/guard_crossings", t[gc], theta[gc], "guard crossing", GUARD, "circle")
    _mode_lane(rec, "mode/logged", t, d)
    _mode_lane(rec, "mode/closed_loop", t, sims["closed_loop"].dir)
    _events(rec, t, theta, d, sims["closed_loop"], guard)
    _trajectory(rec, kin, sims, guard)
    rec.log("stats", rr.TextDocument(stats_markdown(name, validation, derived),
                                     media_type=rr.MediaType.MARKDOWN), static=True)


@functools.lru_cache(maxsize=1)
def _blueprint_chunks():
    """The chunks of ``blueprint()``, built once per process and kept in memory.

    ``RecordingStream.save(path, default_blueprint=...)`` rebuilds the
    blueprint on every call: 36 archetypes through rerun's Python converters,
    ~10 ms per ``.rrd``.  The blueprint is the same for every run, so it is
    logged once into a file of its own and its chunks are read back; each
    ``.rrd`` then gets a copy of them (~4 ms).  Not in the forkserver: saving
    starts rerun's threads, and a process must not fork after that.
    """
    import rerun as rr
    from rerun.chunk import RrdReader

    with tempfile.TemporaryDirectory(prefix="pdr-blueprint-") as folder:
        path = Path(folder) / "blueprint.rrd"
        rec = rr.RecordingStream("pdr", recording_id="blueprint")
        rec.save(path, default_blueprint=blueprint())
        rec.flush()
        rec.disconnect()
        reader = RrdReader(path)
        return reader.store(store=reader.blueprints()[0]).stream().collect()


def _save_with_blueprint(rec, path: Path) -> None:
    """``rec.save(path, default_blueprint=blueprint())`` from the cached chunks.

    What ``rerun.sinks.save`` does, with the blueprint stream filled by
    ``send_chunks`` instead of by logging the blueprint again (rerun-sdk is
    pinned: ``rerun_bindings.new_blueprint`` and ``save`` are its internals).
    The tests read the blueprint back from the file and open it in the viewer.
    """
    import rerun as rr
    import rerun_bindings as bindings
    from rerun.recording_stream import RecordingStream

    stream = RecordingStream._from_native(bindings.new_blueprint(
        application_id="pdr", make_default=False, make_thread_default=False, default_enabled=True))
    rr.send_chunks(_blueprint_chunks(), recording=stream)
    bindings.save(path=str(path), default_blueprint=stream.memory_recording().storage,
                  recording=rec.to_native(), write_footer=True)


def rerun_executable() -> str:
    """The native ``rerun`` binary shipped in the rerun-sdk wheel.

    Called directly rather than through ``.venv/bin/rerun`` (a Python wrapper
    that starts an interpreter first): 30 ms instead of 120 ms per verify.
    """
    import importlib.util

    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        native = Path(spec.origin).with_name("rerun")
        if native.exists():
            return str(native)
    found = shutil.which("rerun")
    if found is None:
        raise PdrError("the rerun CLI (package rerun-sdk, module rerun_cli) is not installed")
    return found


def _verify(paths: list[Path]) -> str | None:
    """Run ``rerun rrd verify`` on the files; None when all pass, else the tool's last line."""
    proc = subprocess.run([rerun_executable(), "rrd", "verify", *map(str, paths)], capture_output=True, text=True)
    if proc.returncode == 0:
        return None
    msg = (proc.stderr or proc.stdout).strip().splitlines()
    return f"rerun rrd verify failed: {msg[-1] if msg else 'exit ' + str(proc.returncode)}"


def verify_rrd(path: Path) -> None:
    """``rerun rrd verify``: the file loads and every chunk is interpretable."""
    error = _verify([path])
    if error is not None:
        raise PdrError(error, path=path)


def verify_rrds(paths: list[Path]) -> dict[Path, str]:
    """``verify_rrd`` on many files with one start of the tool (~40 ms each saved); returns the failures.

    When the batch fails, each file is verified on its own so only the culprits are named.
    """
    if not paths or _verify(paths) is None:
        return {}
    failed = {}
    for path in paths:
        error = _verify([path])
        if error is not None:
            failed[path] = error
    return failed


def write_rrd(target: Path, name: str, kin: pd.DataFrame, sims: dict[str, SimResult], validation: dict,
              guard: float, derived: dict[str, dict[str, np.ndarray]] | None = None, verify: bool = True) -> None:
    """Save to a temporary file beside ``target``, close the stream, verify, rename."""
    import rerun as rr

    from pipeline.io.atomic import atomic_path

    with atomic_path(Path(target)) as tmp:
        rec = rr.RecordingStream("pdr", recording_id=name)
        _save_with_blueprint(rec, tmp)
        log_run(rec, name, kin, sims, validation, guard, derived)
        rec.flush()
        rec.disconnect()
        if verify:
            verify_rrd(tmp)
