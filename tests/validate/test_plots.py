"""The overview PNG: a figure depends only on its run, its axes fit the data, its legend says what is drawn."""

import io

import numpy as np
import pytest
from PIL import Image

from pipeline.config import default_config
from pipeline.model.effects import make_effect
from pipeline.validate.compare import simulate_both
from pipeline.validate.plots import _Overview, coincide, nice_limit, overview_png, time_limits
from tests.validate.synthetic import synthetic_kinematics


def _run(effects=(), duration=24.95, seed=0):
    """A measured table and its two simulations by the base model (effects are hidden in the measurement)."""
    base = default_config().plant_spec()
    truth = default_config().plant_spec(tuple(make_effect(n, p) for n, p in effects))
    kin = synthetic_kinematics(truth, duration=duration, current_noise_a=0.02, seed=seed)
    return kin, simulate_both(base, kin), base.guard_rad


@pytest.fixture(scope="module")
def runs():
    return {"clean": _run(),
            "weak": _run((("driver_voltage_drop", {"Vd": 3.0}),), duration=26.1, seed=1),
            "short": _run(duration=7.3, seed=2)}


def _pixels(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB"))


def test_a_figure_depends_only_on_its_run_whatever_was_drawn_before(runs):
    """Each run drawn once in a new figure (every background drawn for it) is the reference; the
    process-wide figure must give the same pixels in any order, repeats (cached backgrounds) included."""
    fresh = _Overview()
    alone = {name: _pixels(fresh.render(name, *run)) for name, run in runs.items()}
    for name in ["short", "weak", "clean", "short", "clean", "weak", "clean"]:
        np.testing.assert_array_equal(_pixels(overview_png(name, *runs[name])), alone[name], err_msg=name)
    assert not np.array_equal(alone["clean"], alone["weak"])


def _panel_extent(fig: _Overview, i: int, rgb: np.ndarray, color) -> tuple[float, float]:
    """The data range a line of ``color`` covers in time panel ``i``, read from the pixels and the tick labels."""
    ax = fig.axes[i]
    h = rgb.shape[0]
    x0, y0, x1, y1 = ax.bbox.extents                                   # display coords, origin bottom-left
    rows = slice(int(h - y1) + 2, int(h - y0) - 2)
    cols = slice(int(x0) + 2, int(x1) - 2)
    hit = np.all(np.abs(rgb[rows, cols].astype(int) - color) <= 6, axis=2)
    ys = np.flatnonzero(hit.any(axis=1)) + rows.start
    ticks = [(float(t.get_text().replace("\u2212", "-")), t.get_position()[1]) for t in ax.get_yticklabels()
             if t.get_text()]
    (v_a, d_a), (v_b, d_b) = ticks[0], ticks[-1]
    px_a, px_b = (h - ax.transData.transform((0, d))[1] for d in (d_a, d_b))

    def value(px: float) -> float:
        return v_a + (px - px_a) * (v_b - v_a) / (px_b - px_a)

    return value(ys.max()), value(ys.min())


def test_lines_are_drawn_at_the_scale_of_their_tick_labels(runs):
    """The batch bug: the current drawn ~1.67x too large for its ticks after another run's background."""
    import pipeline.validate.plots as plots

    overview_png("short", *runs["short"])
    png = overview_png("clean", *runs["clean"])
    rgb, fig = _pixels(png), plots._FIGURE
    kin = runs["clean"][0]
    for i, col in enumerate(("theta_rad", "omega_rad_s", "current_a")):
        lo, hi = _panel_extent(fig, i, rgb, (51, 51, 51))                # measured: grey 0.2
        span = kin[col].max() - kin[col].min()
        assert hi == pytest.approx(kin[col].max(), abs=0.03 * span), col
        assert lo == pytest.approx(kin[col].min(), abs=0.03 * span), col


def test_axes_fit_the_data(runs):
    import pipeline.validate.plots as plots

    kin, sims, _guard = runs["weak"]
    overview_png("weak", *runs["weak"])
    fig = plots._FIGURE
    assert fig.axes[0].get_xlim() == (0.0, 27.0)                        # 26.1 s of data
    for ax, col in zip(fig.axes, ("theta_rad", "omega_rad_s", "current_a")):
        peak = max(np.abs(kin[col]).max(), *(np.abs(getattr(s, f)).max() for s in sims.values()
                                             for f in ("theta", "omega", "current_measured")
                                             if f.startswith(col.split("_")[0][:5])))
        top = ax.get_ylim()[1]
        assert peak <= top <= 1.15 * peak, col
    assert time_limits(np.array([0.0, 24.95])) == (0.0, 25.0)
    assert time_limits(np.array([12.05, 24.95])) == (12.0, 25.0)
    assert nice_limit(2.4) == 2.5 and nice_limit(0.306 * 1.02) == pytest.approx(0.35)


def test_legend_names_one_line_when_closed_loop_and_replay_coincide(runs):
    import pipeline.validate.plots as plots

    kin, sims, guard = runs["clean"]
    overview_png("clean", kin, {"closed_loop": sims["replay"], "replay": sims["replay"]}, guard)
    labels = [t.get_text() for t in plots._FIGURE.legend.get_texts()]
    assert labels == ["measured", "closed loop = replay", f"guard +/-{guard:.3g} rad"]
    fig = plots._FIGURE.fig
    assert len(fig.legends) + sum(ax.get_legend() is not None for ax in fig.axes) == 1     # drawn once
    kin, sims, guard = runs["weak"]
    assert not coincide(sims["closed_loop"], sims["replay"])
    overview_png("weak", kin, sims, guard)
    labels = [t.get_text() for t in plots._FIGURE.legend.get_texts()]
    assert labels == ["measured", "closed loop", "replay", f"guard +/-{guard:.3g} rad"]


def test_orange_shows_when_the_closed_loop_differs(runs):
    kin, sims, guard = runs["weak"]
    rgb = _pixels(overview_png("", kin, sims, guard)).astype(int)
    orange = np.all(np.abs(rgb - (255, 127, 14)) <= 10, axis=2)
    assert orange[100:].sum() > 2000                                    # lines, not just the legend's sample
    assert rgb.shape == (800, 1200, 3)


def test_backgrounds_shared_through_a_folder_give_the_figure_drawn_alone(runs, tmp_path, monkeypatch):
    """pdr run's workers share backgrounds: one saved by a figure and read by another gives the same
    PNG bytes; a run whose axes, guard or legend differ gets its own (never another run's); a file
    that is not a whole background is drawn over."""
    from pipeline.validate.plots import shared_backgrounds

    alone = {name: _Overview().render(name, *run) for name, run in runs.items()}
    with shared_backgrounds(tmp_path):
        drawn = {name: _Overview().render(name, *run) for name, run in runs.items()}
        saved = sorted(tmp_path.iterdir())
        reader = _Overview()
        monkeypatch.setattr(reader.canvas, "draw", lambda: pytest.fail("drawn although shared"))
        read = {name: reader.render(name, *run) for name, run in runs.items()}
    assert drawn == alone and read == alone
    assert len(saved) == 3                                      # three runs, three sets of limits

    kin, sims, guard = runs["clean"]
    other_guard = _Overview().render("g", kin, sims, 0.9 * guard)
    with shared_backgrounds(tmp_path):
        assert _Overview().render("g", kin, sims, 0.9 * guard) == other_guard
        assert len(list(tmp_path.iterdir())) == 4
        for path in tmp_path.iterdir():
            path.write_bytes(path.read_bytes()[:1000])          # torn: not whole backgrounds
        assert _Overview().render("clean", *runs["clean"]) == alone["clean"]


def test_the_measured_line_shows_over_the_model_lines(runs):
    """Where the replay follows the measurement, the measurement is still a line of its own colour,
    at least two pixels thick, over the wider model line (not a hairline lost in it)."""
    import pipeline.validate.plots as plots

    rgb = _pixels(overview_png("clean", *runs["clean"])).astype(int)
    fig = plots._FIGURE
    for i, ax in enumerate(fig.axes):
        x0, y0, x1, y1 = ax.bbox.extents
        h = rgb.shape[0]
        panel = rgb[int(h - y1) + 2:int(h - y0) - 2, int(x0) + 2:int(x1) - 2]
        measured = np.all(np.abs(panel - (51, 51, 51)) <= 6, axis=2)
        per_column = measured.sum(axis=0)
        assert (per_column > 0).mean() > 0.95, i                    # along the whole run
        assert np.median(per_column[per_column > 0]) >= 2, i        # and not a hairline


def test_the_title_gives_both_ways_mse_with_their_numbers(runs):
    """The title's figures are the validation's: the replay's and the closed loop's MSE per signal,
    one set when the two ways coincide."""
    from pipeline.validate.compare import compare
    from pipeline.validate.stage import overview_title

    kin, sims, _guard = runs["weak"]
    spec = default_config().plant_spec()
    validation = compare(kin, spec, sims)
    title = overview_title("weak", validation)
    figures = {way: ", ".join(f"{validation[way]['signals'][s]['mse']:.3g}" for s in ("theta", "omega", "current"))
               for way in ("replay", "closed_loop")}
    assert f"replay: {figures['replay']}" in title and f"closed loop: {figures['closed_loop']}" in title
    assert figures["replay"] != figures["closed_loop"]
    same = compare(kin, spec, {"closed_loop": sims["replay"], "replay": sims["replay"]})
    assert overview_title("clean", same).endswith(f"closed loop = replay: {figures['replay']}")
