"""The recordings' colours read on both of the viewer's schemes and tell the legend's entries apart."""

import itertools

import pytest

from pipeline.validate.palette import RGB, SCHEME_BACKGROUNDS, contrast_ratio
from pipeline.validate.rerun_phase import AXIS_COLORS, GUARD_LABEL_RGB


@pytest.mark.parametrize("scheme", sorted(SCHEME_BACKGROUNDS))
def test_every_colour_stands_out_from_both_schemes_backgrounds(scheme):
    background = SCHEME_BACKGROUNDS[scheme]
    for name, rgb in [*RGB.items(), *zip(("axis I", "axis omega", "axis theta"), AXIS_COLORS),
                      ("guard label", GUARD_LABEL_RGB)]:
        assert contrast_ratio(rgb, background) >= 3.0, (scheme, name, rgb)


def test_no_two_roles_share_a_colour():
    """Guards and guard crossings, the measurement and the logged switches: each its own colour."""
    for (a, ra), (b, rb) in itertools.combinations(RGB.items(), 2):
        assert max(abs(x - y) for x, y in zip(ra, rb)) >= 60, (a, b)


def test_the_contrast_ratio_is_wcag_s():
    assert contrast_ratio((0, 0, 0), (255, 255, 255)) == pytest.approx(21.0)
    assert contrast_ratio((118, 118, 118), (118, 118, 118)) == 1.0
    assert contrast_ratio((230, 230, 230), (255, 255, 255)) < 1.3          # the former measured white
