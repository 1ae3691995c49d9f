"""The discovery report's figures and table say what became of each candidate: one adopted per round."""

import io
import json

import numpy as np
import pytest
from PIL import Image

from pipeline.discover.candidates import parameter_of
from pipeline.discover.report import (OUTCOME_COLORS, candidates_figure, candidates_png, markdown, outcomes,
                                     score_limit)
from pipeline.discover.stage import discover, discovery_json
from pipeline.model.effects import make_effect
from tests.discover.synthetic import rig_kinematics


@pytest.fixture(scope="module")
def backlash_discovery(tmp_path_factory):
    kin, cfg, csv = rig_kinematics((make_effect("backlash", {parameter_of("backlash"): 0.08}),), seed=11,
                                   work=tmp_path_factory.mktemp("backlash"))
    d = discover(kin, cfg, "rec")
    return d, json.loads(json.dumps(discovery_json(d, str(csv)), default=float))


def test_one_candidate_adopted_per_round_the_others_named_for_what_they_are(backlash_discovery):
    d, doc = backlash_discovery
    fates = outcomes(d)
    assert len(fates) == len(doc["candidates"])
    assert [e.name for e in d.effects] == ["backlash"]
    for round_ in {c["round"] for c in doc["candidates"]}:
        idx = [i for i, c in enumerate(doc["candidates"]) if c["round"] == round_]
        adopted = [i for i in idx if fates[i].startswith("adopted")]
        passing = [i for i in idx if all(doc["candidates"][i].get("checks", {"scan": False}).values())]
        assert len(adopted) == (1 if passing else 0)
        assert [i for i in idx if doc["candidates"][i]["accepted"]] == adopted
        best = max(passing, key=lambda i: doc["candidates"][i]["heldout_nll_gain"], default=None)
        assert adopted == ([best] if passing else [])           # the most held-out likelihood of those that pass
        for i in passing:
            assert fates[i] == ("adopted" if i == best else "passed, not chosen")
    assert fates.count("adopted") == len(d.effects)
    md = markdown(d, doc)
    assert "none (accepted)" not in md
    rows = [line for line in md.splitlines() if line.startswith("| 1 | `")]
    assert sum(line.endswith("| adopted |") for line in rows) == 1
    assert next(line for line in rows if line.endswith("| adopted |")).startswith("| 1 | `backlash`")
    for line, c in zip(rows, [c for c in doc["candidates"] if c["round"] == 1]):
        if not c.get("screened_out") and not all(c["checks"].values()):
            failed = [k for k, ok in c["checks"].items() if not ok]
            assert f"rejected: failed {', '.join(failed)}" in line


def test_candidates_png_paints_only_the_adopted_bars_green(backlash_discovery):
    d, _doc = backlash_discovery
    with Image.open(io.BytesIO(candidates_png(d))) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=int)
    green = np.all(np.abs(rgb - (44, 160, 44)) <= 3, axis=2)           # tab:green
    rows = np.flatnonzero(green.sum(axis=1) > 100)                   # bar rows (the legend patch is short)
    bars = np.count_nonzero(np.diff(rows) > 1) + 1 if len(rows) else 0
    assert bars == outcomes(d).count("adopted") == 1
    assert OUTCOME_COLORS["adopted"] == "tab:green"


def test_candidates_figure_one_labelled_bar_per_candidate_on_axes_fitted_to_the_scores(backlash_discovery):
    """Every round's panel holds one bar per candidate (none left empty by a 0..1 axis when its scores
    are ~0), each named with what became of it and why; rejected and screened out look different."""
    d, doc = backlash_discovery
    fig = candidates_figure(d)
    fates = outcomes(d)
    styles = {}
    first = 0
    for ax, rnd in zip(fig.axes, d.selection.rounds):
        scores = [max(a.score, 0.0) for a in rnd]
        bars = ax.patches
        assert len(bars) == len(rnd)
        lo, hi = ax.get_xlim()
        assert lo == 0.0 and hi == score_limit(scores) >= max(scores)
        assert hi <= max(0.01, 2.3 * max(scores))                           # fitted to the round's best
        assert all(b.get_width() >= 0.005 * hi for b in bars)                # every bar shows
        labels = [t.get_text() for t in ax.get_yticklabels()]
        shown = dict(zip((t.get_position()[1] for t in ax.get_yticklabels()), labels))
        for bar, fate, c in zip(bars, fates[first:first + len(rnd)], doc["candidates"][first:]):
            label = shown[bar.get_y() + bar.get_height() / 2]
            assert label.startswith(c["name"] + " - ")
            if fate == "rejected":
                assert "rejected: failed " + next(k for k, ok in c["checks"].items() if not ok) in label
            if fate == "screened out":
                assert "screened out" in label
            styles.setdefault(fate, set()).add((bar.get_facecolor(), bar.get_hatch()))
        first += len(rnd)
    assert len(fig.axes) == len(d.selection.rounds)
    assert {"rejected", "screened out"} <= set(styles) and not styles["rejected"] & styles["screened out"]


def test_the_base_models_residual_shows_where_the_augmented_one_lies_on_it(backlash_discovery):
    """The current's residual barely changes with backlash added: the base model's pale orange band
    still shows around the augmented model's blue line."""
    from pipeline.discover.report import residuals_png

    d, _doc = backlash_discovery
    with Image.open(io.BytesIO(residuals_png(d))) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=int)
    band = np.all(np.abs(rgb - (255, 185, 122)) <= 12, axis=2)       # tab:orange at alpha 0.55 on white
    current_panel = band[2 * rgb.shape[0] // 3:]
    assert current_panel.sum() > 1000


def _figures(out):
    return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.suffix == ".png"}


def test_every_output_is_written_and_a_rerun_gives_the_same_bytes(backlash_discovery, tmp_path):
    from pipeline.discover.report import write_outputs

    d, doc = backlash_discovery
    first = write_outputs(tmp_path / "first", d, doc, rrd=False)
    write_outputs(tmp_path / "again", d, doc, rrd=False)
    assert set(first) == {"json", "toml", "markdown", "signals_png", "residuals_png", "localisation_png",
                          "candidates_png"}
    assert all(p.is_file() and p.stat().st_size > 0 for p in first.values())
    assert len(_figures(tmp_path / "first")) == 4
    assert _figures(tmp_path / "again") == _figures(tmp_path / "first")


def test_no_figure_parses_mathtext(backlash_discovery, monkeypatch):
    """Tick labels are plain numbers ("0.1", "1", "10"): mathtext parsing was half the localisation figure."""
    from matplotlib import mathtext

    from pipeline.discover.report import localisation_png, residuals_png, signals_png

    def refuse(*args, **kwargs):
        raise AssertionError("mathtext parsed")

    monkeypatch.setattr(mathtext.MathTextParser, "parse", refuse)
    d, _doc = backlash_discovery
    for draw in (signals_png, residuals_png, candidates_png, localisation_png):
        with Image.open(io.BytesIO(draw(d))) as im:
            assert im.size[0] > 500
