"""The layouts saved inside the ``.rrd`` files: what the viewer opens on.

A run (``run_blueprint``): each signal in a row with its residual beside it, at
the same height, every time axis linked; the mode lane under them; the 3-D
phase portrait over the statistics and events on the right, the angle plot's
legend in a short view of its own above them (``_legend``).  The
side panels are collapsed and the time panel is paused: the recording is
complete when it is opened, so there is nothing to play, and the time cursor
stays where the viewer puts a finished recording's (see the viewer test).

Discovery (``discovery_blueprint``): the same rows for the measurement, the
base and the augmented model, the residual before and after, and the phase
portrait before and after, with the report beside them.

Each layout is built once per process (``rerun_io.blueprint_chunks``); what
differs between runs, the y ranges of the angle plot and of the residuals, is
added to each file's copy as view properties (``axis_ranges``), so runs share
the layout.
"""

from __future__ import annotations

import functools

import numpy as np

from pipeline.validate.rerun_io import stable_ids

SIGNAL_UNITS = (("theta", "rad"), ("omega", "rad/s"), ("current", "A"))
RUN_VIEW_NAMES = ("theta [rad]", "omega [rad/s]", "current [A]", "residual theta [rad]", "residual omega [rad/s]",
                  "residual current [A]", "mode", "legend", "trajectory (I, w, theta)", "statistics", "events")
DISCOVERY_VIEW_NAMES = ("theta [rad]", "omega [rad/s]", "current [A]", "residual theta [rad]",
                        "residual omega [rad/s]", "residual current [A]", "mode", "legend",
                        "before: base model (I, w, theta)", "after: augmented model (I, w, theta)", "report")
# The legend view's y range: far above any angle, so the view draws its legend and no data.
LEGEND_ONLY_RANGE = (1000.0, 1001.0)


def tick_range(peak: float) -> tuple[float, float] | None:
    """A symmetric y range for a residual of largest size ``peak`` = m x 10^k (1 <= m < 10) whose
    gridlines get labels.  The viewer labels multiples of a power of ten when they are ~19 px
    apart or more (seen on a ~150 px residual plot: steps of 1 on +/-3.85 are labelled, steps of
    0.01 on +/-0.1 are not, leaving only "0").  So: +/- 1.1 x peak while that spans at most 9
    steps of 10^k (m <= 4.09: the data fill 91 % of the height), else +/- 1.05 x 10^(k+1), one
    step each side (the data fill 39-90 %)."""
    if not np.isfinite(peak) or peak <= 0.0:
        return None
    step = 10.0 ** np.floor(np.log10(peak))
    half = 1.1 * peak if 1.1 * peak <= 4.5 * step else 1.05 * 10.0 * step
    return (round(float(-half), 12), round(float(half), 12))


def _time_series(name: str, origin: str, legend: bool = False, y_range: tuple[float, float] | None = None):
    import rerun.blueprint as rrb

    return rrb.TimeSeriesView(
        origin=origin, name=name, axis_x=rrb.TimeAxis(link="LinkToGlobal"),
        axis_y=rrb.ScalarAxis(range=y_range) if y_range is not None else None,
        plot_legend=rrb.PlotLegend(corner="LeftTop", visible=legend))


def _legend(origin: str = "/signals/theta", name: str = "legend"):
    """The angle plot's legend in a view of its own: the angle plot's series over a y range none of
    them reaches.  A legend drawn on the angle plot covered the data unless the plot's range kept a
    band free for it, a third of the plot's height; here it takes a quarter of the right column."""
    import rerun.blueprint as rrb

    return rrb.TimeSeriesView(
        origin=origin, name=name, axis_x=rrb.TimeAxis(link="LinkToGlobal"),
        axis_y=rrb.ScalarAxis(range=LEGEND_ONLY_RANGE, zoom_lock=True),
        plot_legend=rrb.PlotLegend(corner="LeftTop", visible=True),
        background=rrb.archetypes.PlotBackground(show_grid=False))


def _signal_rows(theta_range: tuple[float, float] | None, residual_ranges: tuple | None):
    """Three rows, each a signal with its residual beside it (same height), and the mode lane."""
    import rerun.blueprint as rrb

    residual_ranges = residual_ranges or (None,) * len(SIGNAL_UNITS)
    rows = [rrb.Horizontal(_time_series(f"{sig} [{unit}]", f"/signals/{sig}",
                                        y_range=theta_range if sig == "theta" else None),
                           _time_series(f"residual {sig} [{unit}]", f"/residuals/{sig}", y_range=res_range),
                           column_shares=[3, 2])
            for (sig, unit), res_range in zip(SIGNAL_UNITS, residual_ranges)]
    lane = rrb.StateTimelineView(origin="/mode", name="mode", time_view=rrb.TimeAxis(link="LinkToGlobal"))
    return rrb.Vertical(*rows, lane, row_shares=[4, 3, 3, 1.8])


def _portrait(name: str, origin: str):
    import rerun.blueprint as rrb

    from pipeline.validate.rerun_phase import CAMERA

    # no background of its own: the scheme's, which the palette's mid tones and the labels' boxes suit
    return rrb.Spatial3DView(origin=origin, name=name, eye_controls=rrb.EyeControls3D(kind="Orbital", **CAMERA),
                             line_grid=rrb.LineGrid3D(visible=False))


def _panels():
    import rerun.blueprint as rrb

    return (rrb.TimePanel(state="collapsed", play_state="following"), rrb.SelectionPanel(state="collapsed"),
            rrb.BlueprintPanel(state="collapsed"))


def _events_view():
    import rerun.blueprint as rrb

    return rrb.TextLogView(origin="/events", name="events", columns=rrb.TextLogColumns(
        timeline_columns=[rrb.encodings.TimelineColumn(timeline="time", visible=False)],
        text_log_columns=[rrb.encodings.TextLogColumn("LogLevel"), rrb.encodings.TextLogColumn("Body"),
                          rrb.encodings.TextLogColumn("EntityPath", visible=False)]))


def run_blueprint(theta_range: tuple[float, float] | None = None, residual_ranges: tuple | None = None):
    """The layout of ``<run>.rrd``; ``theta_range`` (the data and the guards), ``residual_ranges``
    (theta, omega, current; ``tick_range`` or None) label the residuals' axes."""
    import rerun.blueprint as rrb

    right = rrb.Vertical(_legend(), _portrait("trajectory (I, w, theta)", "/trajectory"),
                         rrb.Tabs(rrb.TextDocumentView(origin="/stats", name="statistics"), _events_view()),
                         row_shares=[2.1, 3, 2])
    bp = rrb.Blueprint(rrb.Horizontal(_signal_rows(theta_range, residual_ranges), right, column_shares=[3, 2]),
                       *_panels(), auto_views=False)
    return stable_ids(bp, "run")


def discovery_blueprint(theta_range: tuple[float, float] | None = None, residual_ranges: tuple | None = None):
    """The layout of ``discovery.rrd``: signals and residuals left, portraits before/after and the report right."""
    import rerun.blueprint as rrb

    right = rrb.Vertical(
        _legend(),
        rrb.Horizontal(_portrait("before: base model (I, w, theta)", "/trajectory_before"),
                       _portrait("after: augmented model (I, w, theta)", "/trajectory_after")),
        rrb.TextDocumentView(origin="/report", name="report"), row_shares=[1.1, 2, 3])
    bp = rrb.Blueprint(rrb.Horizontal(_signal_rows(theta_range, residual_ranges), right, column_shares=[5, 4]),
                       *_panels(), auto_views=False)
    return stable_ids(bp, "discovery")


def side_by_side_blueprint(names: tuple[str, ...], theta_range: tuple[float, float] | None = None):
    """Several runs in columns (``pdr view A B``), each run's data under ``/runs/<name>``, every time
    axis linked.  A column: the angle with the run's own legend beside it (each run names its own
    model lines: "closed loop = replay" only where they coincide), omega, current, the mode lane,
    and tabs with the phase portrait, the three residuals and the statistics, the full column wide."""
    import rerun.blueprint as rrb

    columns = []
    for name in names:
        root = f"/runs/{name}"
        angle = rrb.Horizontal(_time_series(f"{name}: theta [rad]", f"{root}/signals/theta", y_range=theta_range),
                               _legend(f"{root}/signals/theta", f"{name}: legend"), column_shares=[2.6, 1])
        plots = [_time_series(f"{name}: {sig} [{unit}]", f"{root}/signals/{sig}") for sig, unit in SIGNAL_UNITS[1:]]
        residuals = [_time_series(f"{name}: residual {sig} [{unit}]", f"{root}/residuals/{sig}")
                     for sig, unit in SIGNAL_UNITS]
        lane = rrb.StateTimelineView(origin=f"{root}/mode", name=f"{name}: mode",
                                     time_view=rrb.TimeAxis(link="LinkToGlobal"))
        tabs = rrb.Tabs(_portrait(f"{name}: trajectory (I, w, theta)", f"{root}/trajectory"), *residuals,
                        rrb.TextDocumentView(origin=f"{root}/stats", name=f"{name}: statistics"))
        columns.append(rrb.Vertical(angle, *plots, lane, tabs, row_shares=[3.5, 1.9, 1.9, 1.8, 3.3]))
    bp = rrb.Blueprint(rrb.Horizontal(*columns), *_panels(), auto_views=False)
    return stable_ids(bp, "side-by-side/" + "/".join(names))


@functools.lru_cache(maxsize=16)
def view_ids(build, *args) -> dict[str, str]:
    """Display name -> view id of a layout; the ids derive from positions (``stable_ids``), so
    they are the ids in the layout's cached chunks."""
    from rerun.blueprint.api import Container

    out: dict[str, str] = {}

    def walk(container) -> None:
        for child in container.contents:
            if isinstance(child, Container):
                walk(child)
            else:
                out[child.name] = str(child.id)

    walk(build(*args).root_container)
    return out


def axis_ranges(build, theta_range: tuple[float, float] | None, residual_ranges: tuple) -> dict[str, tuple]:
    """View id -> y range of a layout with signal rows: the angle plot and the residuals
    (theta, omega, current), those that have one."""
    ids = view_ids(build)
    names = ["theta [rad]"] + [f"residual {sig} [{unit}]" for sig, unit in SIGNAL_UNITS]
    return {ids[n]: r for n, r in zip(names, (theta_range, *residual_ranges)) if r is not None}
