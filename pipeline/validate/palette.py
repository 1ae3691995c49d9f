"""The colours of the Rerun recordings: each must read on the viewer's dark and light schemes.

The viewer follows the system's (or the browser's) colour scheme, and a
recording cannot choose it: a plot's background is near black (13, 13, 13) in
the dark scheme and near white in the light one.  A line in white or in a
pale tint vanishes on the light scheme, a dark one on the dark scheme; every
colour here is a mid tone whose relative luminance lies between ~0.12 and
~0.30, which gives a contrast ratio (WCAG 2) of at least 3:1 against both
black and white (``contrast_ratio``; the viewer test measures it on
screenshots of both schemes).

Each role has a colour of its own, so no two legend entries look alike:
guards and guard crossings, the measurement and the logged switches.
"""

from __future__ import annotations

RGB = {
    "measured": (118, 118, 118),          # neutral grey: the data, under no model's colour
    "closed_loop": (222, 100, 0),         # orange
    "replay": (0, 128, 230),              # blue
    "guard": (205, 40, 70),               # red
    "guard_crossing": (190, 40, 190),     # magenta
    "switch_logged": (40, 150, 40),       # green
}
# Discovery's models: the base one as the closed loop's orange, the augmented one as the replay's blue.
DISCOVERY_RGB = {"measured": RGB["measured"], "base model": RGB["closed_loop"], "augmented model": RGB["replay"]}
# The schemes' extremes a colour must stand out from: a dark plot's background and a light one's.
SCHEME_BACKGROUNDS = {"dark": (13, 13, 13), "light": (255, 255, 255)}


def relative_luminance(rgb: tuple[int, int, int]) -> float:
    """WCAG 2 relative luminance of an sRGB colour (0 black .. 1 white)."""

    def linear(c: int) -> float:
        s = c / 255.0
        return s / 12.92 if s <= 0.04045 else ((s + 0.055) / 1.055) ** 2.4

    r, g, b = (linear(c) for c in rgb[:3])
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def contrast_ratio(a: tuple[int, int, int], b: tuple[int, int, int]) -> float:
    """WCAG 2 contrast ratio between two colours, 1 (same) .. 21 (black on white)."""
    la, lb = sorted((relative_luminance(a), relative_luminance(b)), reverse=True)
    return (la + 0.05) / (lb + 0.05)
