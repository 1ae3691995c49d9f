"""The sketch's settings and the rig TOML its comment gives agree, and that TOML is a valid rig file:
a lab that copies both gets a pipeline that models the rig the sketch runs."""

from pathlib import Path

from pipeline.config import resolve_config
from tests.firmware import sketch


def test_the_sketchs_toml_is_a_rig_file_that_matches_its_settings(tmp_path: Path):
    path = tmp_path / "logger.toml"
    path.write_text(sketch.toml_text(), encoding="utf-8")
    cfg = resolve_config([path])
    assert cfg.sources["controller.period_s"] != "default" and cfg.sources["controller.guard_rad"] != "default"
    assert cfg.controller.period_s * 1000 == sketch.number("PERIOD_MS")
    assert cfg.encoder.counts_per_rev == sketch.number("COUNTS_PER_REV")
    assert sketch.guard_counts(cfg.controller.guard_rad, cfg.encoder.counts_per_rev) == sketch.number("GUARD_COUNTS")
    assert cfg.current_sensor.zero_v == "auto"         # the lead-in's rows at rest give it


def test_a_line_fits_the_period_at_the_baud_rate():
    """The longest line (every field at its widest) takes under a fifth of the period at the baud rate."""
    longest = len("4294967295,-2147483648,1023,-1\n")
    seconds = longest * 10 / sketch.number("BAUD")            # 8N1: ten bits a byte
    assert seconds < 0.2 * sketch.number("PERIOD_MS") / 1000


def test_rig_md_gives_the_sketchs_toml():
    """docs/RIG.md shows the TOML to put beside the recordings: the sketch's own, word for word."""
    doc = (sketch.SKETCH_DIR.parents[1] / "docs" / "RIG.md").read_text(encoding="utf-8")
    section = doc[doc.index("## The matching TOML"):]
    shown = section[section.index("```toml\n") + len("```toml\n"):section.index("```\n", section.index("```toml"))]
    assert shown == sketch.toml_text()
