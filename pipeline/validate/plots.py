"""Static overview PNG per run, for people without the viewer and for CI logs.

Four panels: theta with the guards, omega, current (measured vs closed loop vs
replay, one line "closed loop = replay" when the two coincide, the measurement
on top) and the (theta, omega) phase portrait; 1200 x 800 px.

Speed matters (one PNG per run in ``pdr run``, target >= 10 runs/s on two
cores).  Drawing axes, ticks and labels is 80 % of a matplotlib savefig, and
it is the same for every run of a rig: the axis limits are rounded to "nice"
symmetric values (steps of ~10 %), the rendered background (axes, ticks, guards,
legend) is cached per set of limits, and each run sets its own limits, restores
the matching background and draws its lines and title
(blitting) and encodes the PNG itself (``png_rgb``): ~20 ms instead of ~160 ms.
``pdr run``'s workers also share the backgrounds they draw (``shared_backgrounds``):
a background is the same pixels in any process forked from one forkserver, and
drawing one costs ~60 ms where reading another worker's costs ~1 ms.
The title, the one text that changes per run, is drawn by Pillow in matplotlib's
own font (``_TitleStamp``): matplotlib 3.11 lays text out glyph by glyph in
Python, ~0.2 ms per character, which made a 100-character title cost as much
as all the lines.
"""

from __future__ import annotations

import hashlib
import math
import struct
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.io.atomic import write_bytes
from pipeline.model.simulate import SimResult

_COLORS = {"measured": "0.2", "closed_loop": "tab:orange", "replay": "tab:blue"}
_LABELS = {"measured": "measured", "closed_loop": "closed loop", "replay": "replay"}
# Drawn in this order, widest first: where all three agree each still shows (a pale blue band, an
# orange core, the measurement as a dark line on top, as wide as the core so no model line hides it).
_WIDTHS = {"replay": 2.6, "closed_loop": 1.5, "measured": 1.5}
# The replay's wide band translucent: the measurement on top stays the one dark line over it.
_ALPHAS = {"replay": 0.45, "closed_loop": 1.0, "measured": 1.0}
# kinematics column, SimResult field, axis label
_PANELS = (("theta_rad", "theta", "theta [rad]"), ("omega_rad_s", "omega", "omega [rad/s]"),
           ("current_a", "current_measured", "current [A]"))
# Steps of about 10 %: the axes fit the data (within 10 % plus a 2 % margin), and runs of one rig
# still share a few backgrounds (each miss is a full draw).
_NICE = (1.0, 1.1, 1.2, 1.3, 1.5, 1.7, 2.0, 2.2, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0)
_MARGIN = 1.02
# Closed loop and replay are "the same line" when they agree to this share of the signal's range:
# far below a pixel, far above rounding (they coincide to ~1e-15 when no switch slips).
_SAME = 1e-6


def nice_limit(x: float) -> float:
    """Smallest value of ``_NICE`` (times a power of ten) >= x."""
    if not math.isfinite(x) or x <= 0:
        return 1.0
    p = 10.0 ** math.floor(math.log10(x))
    return next(n * p for n in _NICE if n * p >= x * (1 - 1e-12))


def time_limits(t: np.ndarray) -> tuple[float, float]:
    """The time axis: the data's span rounded out to a 1-2-5 step of about 1/50 of it (24.95 s -> 0..25)."""
    if not len(t) or not np.isfinite(t).all():
        return 0.0, 1.0
    t0, t1 = float(t[0]), float(t[-1])
    span = max(t1 - t0, 1e-3)
    p = 10.0 ** math.floor(math.log10(span / 50))
    step = next(n * p for n in (1.0, 2.0, 5.0, 10.0) if n * p >= span / 50 * (1 - 1e-12))
    lo = math.floor(t0 / step + 1e-9) * step
    hi = math.ceil(t1 / step - 1e-9) * step
    return lo, max(hi, lo + step)


def _abs_max(*arrays: np.ndarray) -> float:
    vals = [float(np.nanmax(np.abs(a))) for a in arrays if len(a) and np.isfinite(a).any()]
    return max(vals) if vals else 1.0


def coincide(a: SimResult, b: SimResult) -> bool:
    """Whether two simulations draw as one line: every plotted signal agrees to ``_SAME`` of its range."""
    for _c, field, _l in _PANELS:
        x, y = np.asarray(getattr(a, field), float), np.asarray(getattr(b, field), float)
        if x.shape != y.shape:
            return False
        scale = max(_abs_max(x, y), 1e-12)
        if np.nanmax(np.abs(x - y), initial=0.0) > _SAME * scale:
            return False
    return True


class _Overview:
    """One figure per process; a rendered background per set of axis limits, guard and legend.

    Everything a background shows (limits, ticks, guards, legend) is set from
    the run being drawn before the background is looked up or drawn, so a
    figure depends only on its run, never on the runs drawn before it.
    """

    def __init__(self) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.ticker import MaxNLocator

        self.fig = Figure(figsize=(12.0, 8.0), dpi=100)
        self.canvas = FigureCanvasAgg(self.fig)
        self.canvas.get_renderer()          # its pixel buffer, which a background read from a file fills
        # Fixed margins: a layout engine would cost more than drawing the lines.
        gs = self.fig.add_gridspec(3, 2, width_ratios=[2.2, 1], left=0.07, right=0.985, bottom=0.07,
                                   top=0.925, wspace=0.2, hspace=0.12)
        first = self.fig.add_subplot(gs[0, 0])
        self.axes = [first] + [self.fig.add_subplot(gs[i, 0], sharex=first) for i in (1, 2)]
        self.phase = self.fig.add_subplot(gs[:2, 1])
        self.lines: dict[tuple[int, str], object] = {}
        for i, (_col, _field, label) in enumerate(_PANELS):
            ax = self.axes[i]
            for way, color in _COLORS.items():
                (self.lines[i, way],) = ax.plot([], [], color=color, lw=_WIDTHS[way], alpha=_ALPHAS[way],
                                                animated=True)
            ax.set_ylabel(label, fontsize=11)
            ax.grid(alpha=0.3)
            ax.margins(x=0.0)
            ax.yaxis.set_major_locator(MaxNLocator(5, symmetric=True))
            ax.tick_params(labelsize=10)
            if i < 2:
                ax.tick_params(labelbottom=False)
        self.axes[2].set_xlabel("t [s]", fontsize=11)
        self.phase_lines = {way: self.phase.plot([], [], color=c, lw=_WIDTHS[way], alpha=_ALPHAS[way],
                                                 animated=True)[0] for way, c in _COLORS.items()}
        self.phase.set_xlabel("theta [rad]", fontsize=11)
        self.phase.set_ylabel("omega [rad/s]", fontsize=11)
        self.phase.set_title("phase portrait", fontsize=11)
        self.phase.tick_params(labelsize=10)
        self.phase.grid(alpha=0.3)
        self.guards = [self.axes[0].axhline(0.0, color="tab:red", lw=0.9, ls="--") for _ in range(2)]
        self.phase_guards = [self.phase.axvline(0.0, color="tab:red", lw=0.9, ls="--") for _ in range(2)]
        self.legend = None
        self.legend_key: tuple[float, tuple[str, ...], bool] | None = None
        self.title = _TitleStamp(self.fig, fontsize=13.0, top=0.985)
        self.backgrounds: dict[tuple, np.ndarray] = {}        # key -> the canvas's RGBA pixels

    def _set_background(self, limits: tuple[float, ...], guard: float, ways: tuple[str, ...], same: bool) -> None:
        """Point every artist of the background at this run's limits, guards and legend (cheap)."""
        t_lo, t_hi, th, om, cu = limits
        self.axes[0].set_xlim(t_lo, t_hi)
        for ax, lim in zip(self.axes, (th, om, cu)):
            ax.set_ylim(-lim, lim)
        self.phase.set_xlim(-th, th)
        self.phase.set_ylim(-om, om)
        for line, g in zip(self.guards, (guard, -guard)):
            line.set_ydata([g, g])
        for line, g in zip(self.phase_guards, (guard, -guard)):
            line.set_xdata([g, g])
        if self.legend_key != (guard, ways, same):
            self._set_legends(guard, ways, same)

    def _set_legends(self, guard: float, ways: tuple[str, ...], same: bool) -> None:
        """Rebuilt only when the guard, the ways drawn or their coincidence change: a legend costs a few
        ms to lay out.  ``ways``: the simulations run (none, or replay alone, without an encoder)."""
        self.legend_key = (guard, ways, same)
        ways = ("measured", "replay") if same else ("measured", *(w for w in ("closed_loop", "replay") if w in ways))
        handles = [self.lines[0, w] for w in ways] + [self.guards[0]]
        labels = [("closed loop = replay" if same and w == "replay" else _LABELS[w]) for w in ways]
        labels.append(f"guard +/-{guard:.3g} rad")
        if self.legend is not None:
            self.legend.remove()
        # One legend, below the phase portrait (beside the current panel): off the data.
        self.legend = self.phase.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.12),
                                        ncols=1, fontsize=11, frameon=False)

    def _background(self, limits: tuple[float, ...], guard: float, ways: tuple[str, ...], same: bool) -> np.ndarray:
        self._set_background(limits, guard, ways, same)
        key = (*limits, guard, ways, same)
        if key not in self.backgrounds:
            pixels = _read_shared(key, self.canvas.get_width_height())
            if pixels is None:
                self.canvas.draw()
                pixels = np.array(self.canvas.buffer_rgba())
                _write_shared(key, pixels)
            if len(self.backgrounds) > 16:
                self.backgrounds.clear()
            self.backgrounds[key] = pixels
        return self.backgrounds[key]

    def render(self, title: str, kin: pd.DataFrame, sims: dict[str, SimResult], guard: float) -> bytes:
        t = column(kin, "t_s", dtype=float)
        measured = [column(kin, col, dtype=float, na_value=np.nan) if col in kin.columns
                    else np.full(len(t), np.nan) for col, _f, _l in _PANELS]
        run = tuple(way for way in ("closed_loop", "replay") if way in sims)     # fewer without an encoder
        simulated = {way: [getattr(sims[way], f) for _c, f, _l in _PANELS] for way in run}
        same = len(run) == 2 and coincide(sims["closed_loop"], sims["replay"])
        limits = (*time_limits(t),
                  *(nice_limit(_MARGIN * _abs_max(measured[i], *(simulated[w][i] for w in run))) for i in range(3)))
        np.asarray(self.canvas.buffer_rgba())[...] = self._background(limits, guard, run, same)
        # Models first, the measurement on top; one model line when the two coincide.
        ways = ("replay",) if same else run[::-1]
        for i, ax in enumerate(self.axes):
            for way in ways:
                self.lines[i, way].set_data(t, simulated[way][i])
                ax.draw_artist(self.lines[i, way])
            self.lines[i, "measured"].set_data(t, measured[i])
            ax.draw_artist(self.lines[i, "measured"])
        for way in ways:
            self.phase_lines[way].set_data(simulated[way][0], simulated[way][1])
            self.phase.draw_artist(self.phase_lines[way])
        self.phase_lines["measured"].set_data(measured[0], measured[1])
        self.phase.draw_artist(self.phase_lines["measured"])
        rgb = np.asarray(self.canvas.buffer_rgba())[..., :3]
        self.title.stamp(rgb, title)
        return png_rgb(rgb)


class _TitleStamp:
    """A centred one-line title drawn into the rendered RGB buffer by Pillow (FreeType in C).

    Same font file and pixel size as a matplotlib ``suptitle`` of ``fontsize``
    points would use; the text is blended in black over what the background has
    there (white margin), so it reads the same, at ~1/10 of the cost.
    """

    def __init__(self, fig, fontsize: float, top: float) -> None:
        from matplotlib import font_manager
        from PIL import ImageFont

        self.font = ImageFont.truetype(font_manager.findfont(font_manager.FontProperties()),
                                       size=max(1, round(fontsize * fig.dpi / 72.0)))
        width, height = fig.canvas.get_width_height()
        self.width, self.y0 = width, int(round((1.0 - top) * height))
        ascent, descent = self.font.getmetrics()
        self.height = ascent + descent + 2

    def stamp(self, rgb: np.ndarray, text: str) -> None:
        """Blend ``text`` into ``rgb`` (H x W x 3 uint8, a writable view of the canvas) in place."""
        from PIL import Image, ImageDraw

        mask = Image.new("L", (self.width, self.height), 0)
        ImageDraw.Draw(mask).text((self.width / 2, 1), text, font=self.font, fill=255, anchor="ma")
        alpha = np.asarray(mask, dtype=np.uint16)[..., None]
        region = rgb[self.y0:self.y0 + self.height]
        alpha = alpha[:len(region)]
        region[...] = (region.astype(np.uint16) * (255 - alpha) // 255).astype(np.uint8)


def png_rgb(rgb: np.ndarray) -> bytes:
    """An 8-bit RGB image as PNG: rows unfiltered, zlib level 1, no ancillary chunks (so no timestamp).

    A third of Pillow's time at compress_level=1 on the overview (which spent
    most of its effort choosing row filters), and smaller: the figure is mostly
    flat colour, which zlib compresses well without a filter.
    """
    h, w, _ = rgb.shape
    rows = np.zeros((h, 1 + 3 * w), np.uint8)                        # filter type 0 before each row
    pixels = rows[:, 1:].reshape(h, w, 3)
    for channel in range(3):            # channel by channel: numpy copies a 3-byte pixel at a time otherwise,
        pixels[..., channel] = rgb[..., channel]                     # 3 ms instead of 0.5 for the overview

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)             # 8 bits, truecolour, no interlace
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows.tobytes(), 1))
            + chunk(b"IEND", b""))


_SHARED: Path | None = None        # the folder of backgrounds shared with the other workers, if any


@contextmanager
def shared_backgrounds(folder: Path | None) -> Iterator[None]:
    """Within: backgrounds are looked up in ``folder`` before being drawn, and every one drawn is
    saved there.  ``pdr run`` gives its workers one folder per run, which it removes at the end."""
    global _SHARED
    previous, _SHARED = _SHARED, (Path(folder) if folder is not None else None)
    try:
        yield
    finally:
        _SHARED = previous


def _shared_file(key: tuple) -> Path | None:
    if _SHARED is None:
        return None
    return _SHARED / (hashlib.sha256(repr(key).encode()).hexdigest()[:32] + ".rgba")


def _read_shared(key: tuple, size: tuple[int, int]) -> np.ndarray | None:
    """The background of ``key`` another worker drew (None: none, or not a whole one)."""
    path = _shared_file(key)
    width, height = size
    try:
        pixels = np.fromfile(path, dtype=np.uint8) if path is not None else None
    except OSError:
        return None
    if pixels is None or pixels.size != height * width * 4:
        return None
    return pixels.reshape(height, width, 4)


def _write_shared(key: tuple, pixels: np.ndarray) -> None:
    """Offer a background just drawn to the other workers (best effort: it is only a cache)."""
    path = _shared_file(key)
    if path is None:
        return
    try:
        write_bytes(path, pixels.tobytes())
    except OSError:
        pass


_FIGURE: _Overview | None = None


def overview_png(title: str, kin: pd.DataFrame, sims: dict[str, SimResult], guard: float) -> bytes:
    """PNG bytes of the overview (figure and backgrounds are reused across calls in one process)."""
    global _FIGURE
    if _FIGURE is None:
        _FIGURE = _Overview()
    return _FIGURE.render(title, kin, sims, guard)


def write_overview(target: Path, title: str, kin: pd.DataFrame, sims: dict[str, SimResult], guard: float) -> None:
    write_bytes(target, overview_png(title, kin, sims, guard))


def warm_up() -> None:
    """Build the figure, draw the background a run of the default rig needs, and load the model's kernels.

    ``pdr run`` calls this in its forkserver, before any worker is forked, so
    every worker starts with a ready figure, loaded fonts, the background of a
    typical run (the paper's rig, 24.95 s) and the compiled simulation kernels
    of both ways of validation (closed loop and replay of a logged command),
    instead of paying for them on its first run (numba loads each kernel from
    its cache, or compiles it when the cache is cold: seconds, once per worker).
    Matplotlib with Agg starts no threads: safe to fork.
    """
    from pipeline.config import default_config
    from pipeline.model.simulate import simulate
    from pipeline.validate.compare import simulate_both

    spec = default_config().plant_spec()
    sim = simulate(spec, duration=24.95)
    # A measured current carries the ACS712's noise (one 26 mA ADC step, sigma): its peaks, hence
    # the current axis, are higher than the model's.
    noise = 5.0 / 1024 / 0.185 * np.random.default_rng(0).standard_normal(len(sim.t))
    kin = pd.DataFrame({"t_s": sim.t, "theta_rad": sim.theta, "omega_rad_s": sim.omega,
                        "current_a": sim.current_measured + noise, "dir": sim.dir})
    overview_png("warm-up", kin, simulate_both(spec, kin), spec.guard_rad)
