"""The 3-D phase portrait (current, omega, theta) with the guard planes: the paper's Figs. 7 and 8.

The three axes differ by an order of magnitude (0.5 A, 10 rad/s, 1.2 rad), so
the data stay in SI units under ``<origin>/scaled``, whose ``Transform3D``
scale maps each axis's extent to +/-1.  The scale sits on a child of the
view's origin: the viewer takes the origin's own transform as its reference
frame and applies only the transforms below it.  The guard planes are then
squares 2 x 2 at theta = +/- theta_g / extent, and the camera saved in the
blueprint (``CAMERA``) sees the unit cube whatever the run.

What is drawn in the unit frame (beside ``scaled``, not under it): the axis
arrows along three edges, their units and extents beside them, a legend of
coloured labels above the cube's centre, and the guard planes' labels beside
the angle axis; labels are centred on their points, placed where even a narrow
view (discovery's two portraits) does not cut them.  The guard planes are
translucent with their outline drawn, so the overshoot past a guard shows.
"""

from __future__ import annotations

import numpy as np

AXES = (("current I", "A"), ("omega w", "rad/s"), ("theta", "rad"))
# Mid tones, like ``palette.RGB``: the view's background and its labels' boxes follow the viewer's scheme.
AXIS_COLORS = ((180, 130, 0), (40, 150, 40), (70, 110, 230))
# Translucent, with their outline drawn: the overshoot beyond a guard, the part worth seeing, shows
# through the plane.
GUARD_PLANE_RGBA = (230, 60, 60, 56)
# The guards' labels a rose beside the planes' red: a mid tone that reads on both schemes, and not
# the planes' own colour, by which the viewer test finds the planes on its screenshots.
GUARD_LABEL_RGB = (200, 60, 95)
# Eye of the saved view, in the unit frame: above the (I > 0, omega < 0) corner, looking at the
# centre, near enough that the unit cube and its labels fill the view.
CAMERA = {"position": (2.5, -3.0, 1.85), "look_target": (0.0, 0.0, 0.05), "eye_up": (0.0, 0.0, 1.0)}
# The axis arrows lie on edges of the cube's outline as seen from ``CAMERA`` (the edges through the
# nearest and the farthest corner are seen inside the cube, over the curves): I and theta from the
# (-1, -1, -1) corner, omega along the right-hand bottom edge.  Labels past the tips of omega and
# theta; the current's tip is the lowest point of the view, so its label sits under its middle.
ARROW_ORIGINS = ((-1.0, -1.0, -1.0), (1.0, -1.0, -1.0), (-1.0, -1.0, -1.0))
LABEL_PLACES = ((0.0, -1.3, -1.1), (1.1, 1.15, -1.0), (-1.0, -1.0, 1.15))


def _packed(rgba) -> np.ndarray:
    rgba = [tuple(c) + (255,) * (4 - len(c)) for c in rgba]
    return np.array([(r << 24) | (g << 16) | (b << 8) | a for r, g, b, a in rgba], dtype=np.uint32)


def extents(strips: dict[str, np.ndarray], guard: float) -> np.ndarray:
    """Half-width of each axis (I, omega, theta): the largest |value| of any strip, 5 % margin,
    never below (0.05 A, 0.5 rad/s, theta_g) so a run at rest still gets a readable cube."""
    floor = np.array([0.05, 0.5, guard])
    peaks = [np.nanmax(np.abs(xyz), axis=0) for xyz in strips.values() if len(xyz)]
    return np.maximum(floor, np.max(peaks, axis=0) if peaks else floor) * 1.05


def finite_rows(xyz: np.ndarray) -> np.ndarray:
    return xyz[np.isfinite(xyz).all(axis=1)]


def log_phase_portrait(rec, origin: str, strips: dict[str, tuple[np.ndarray, tuple, float]], guard: float) -> np.ndarray:
    """Log the portrait under ``origin``: ``strips`` maps a label to (N x 3 array of I, omega, theta;
    RGB colour; line width in UI points), listed in the legend in that order.  Returns the extents."""
    import rerun as rr

    ext = extents({k: v[0] for k, v in strips.items()}, guard)
    rec.log(origin, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(f"{origin}/scaled", rr.Transform3D(scale=(1.0 / ext).tolist()), static=True)
    for label, (xyz, color, width) in strips.items():
        rec.log(f"{origin}/scaled/{slug(label)}", rr.LineStrips3D(
            [finite_rows(xyz)], colors=_packed([color]), radii=rr.Radius.ui_points(width)), static=True)
    rec.log(f"{origin}/scaled/guard_planes", rr.Boxes3D(
        centers=[[0.0, 0.0, guard], [0.0, 0.0, -guard]], half_sizes=[[ext[0], ext[1], ext[2] * 0.003]] * 2,
        colors=_packed([GUARD_PLANE_RGBA] * 2), fill_mode="TransparentFillMajorWireframe"), static=True)
    g = guard / ext[2]
    rec.log(f"{origin}/guard_labels", rr.Points3D(
        [[-1.0, -1.0, g], [-1.0, -1.0, -g]], radii=rr.Radius.ui_points(0.0), colors=_packed([GUARD_LABEL_RGB] * 2),
        labels=[f"guard +{guard:.3f} rad", f"guard -{guard:.3f} rad"], show_labels=True),
        static=True)
    starts = np.array(ARROW_ORIGINS)
    rec.log(f"{origin}/axes", rr.Arrows3D(vectors=(2.0 * np.eye(3)).tolist(), origins=starts.tolist(),
                                          colors=_packed(AXIS_COLORS), radii=rr.Radius.ui_points(1.5)), static=True)
    rec.log(f"{origin}/axis_labels", rr.Points3D(   # clear of the curves and of the guards' labels
        list(LABEL_PLACES), radii=rr.Radius.ui_points(0.0), colors=_packed(AXIS_COLORS),
        labels=[f"{n} [{u}], \u00b1{e:.3g}" for (n, u), e in zip(AXES, ext)], show_labels=True), static=True)
    names = list(strips)
    rec.log(f"{origin}/legend", rr.Points3D(
        [[0.0, 0.0, 1.4 + 0.22 * (len(names) - 1 - i)] for i in range(len(names))],
        radii=rr.Radius.ui_points(4.0), colors=_packed([strips[n][1] for n in names]), labels=names,
        show_labels=True), static=True)
    return ext


def slug(label: str) -> str:
    """An entity name for a label: 'closed loop = replay' -> 'closed_loop_replay'."""
    return "_".join("".join(c if c.isalnum() else " " for c in label).split())
