"""Each serial artefact appears when asked and never when not; none of them changes the physics."""

from __future__ import annotations

import re
from collections import Counter

import numpy as np
import pytest

from pipeline.config import resolve_config
from pipeline.rig.recording import RigSetup, make_recording
from pipeline.rig.serial import Artefacts, ide_prefix
from tests.rig.csvread import IDE, as_row

IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

# artefact name -> (Artefacts fields, the signatures it must show)
CASES = {
    "ide": ({"ide_prefix": "classic"}, {"ide"}),
    "ide2": ({"ide_prefix": "ide2"}, {"ide"}),
    "crlf": ({"crlf": True}, {"crlf"}),
    "bom": ({"bom": True}, {"bom"}),
    "comments": ({"comments": 3}, {"comments"}),
    "blank": ({"blank_lines": 3}, {"blank"}),
    "partial": ({"partial_first_line": True}, {"partial"}),
    "garbled": ({"garbled": 6}, {"garbled"}),
    "dropped": ({"dropped": 4}, {"dropped"}),
    "reset": ({"reset_after_s": 3.0}, {"reset"}),
    "no-header": ({"header": False}, {"no-header"}),
    "no-dir": ({"dir_column": False}, {"no-dir"}),
    "columns": ({"column_names": ("time", "enc", "i_raw", "mode")}, {"columns"}),
    "micros": ({"time_unit": "us"}, {"micros"}),
}


def setup_with(**fields) -> RigSetup:
    return RigSetup(duration_s=6.0, artefacts=Artefacts(**fields))


@pytest.fixture(scope="module")
def base():
    return make_recording(setup_with(), seed=5)


@pytest.fixture(scope="module")
def recordings():
    return {name: make_recording(setup_with(**fields), seed=5) for name, (fields, _) in CASES.items()}


def signatures(rec) -> set[str]:
    """Every artefact visible in a recording, read from the bytes (and the truth, for dropped lines)."""
    found: set[str] = set()
    text = rec.csv_bytes.decode("utf-8")
    if text.startswith("\ufeff"):
        found.add("bom")
        text = text[1:]
    if "\r" in text:
        found.add("crlf")
    physical = text.replace("\r\n", "\n").split("\n")
    assert physical[-1] == "", "the capture ends with a newline"
    physical = physical[:-1]
    if any(IDE.match(ln) for ln in physical):
        found.add("ide")
    lines = [IDE.sub("", ln) for ln in physical]
    width = Counter(ln.count(",") + 1 for ln in lines if "," in ln).most_common(1)[0][0]
    if width == 3:
        found.add("no-dir")
    headers = [i for i, ln in enumerate(lines) if ln.count(",") + 1 == width and all(IDENT.match(f) for f in ln.split(","))]
    if not headers:
        found.add("no-header")
    elif any(lines[i] != ",".join(("t_ms", "counts", "adc", "dir")[:width]) for i in headers):
        found.add("columns")
    if any(ln.startswith("#") for ln in lines):
        found.add("comments")
    if any(ln == "" for ln in lines):
        found.add("blank")
    malformed = [i for i, ln in enumerate(lines)
                 if i not in headers and ln and not ln.startswith("#") and as_row(ln, width) is None]
    if 0 in malformed:
        found.add("partial")
    if any(i > 0 for i in malformed):
        found.add("garbled")
    times = [as_row(ln, width)[0] for i, ln in enumerate(lines) if i not in malformed and as_row(ln, width)]
    if len(headers) > 1 or any(b < a for a, b in zip(times, times[1:])):
        found.add("reset")
    if np.median(np.diff(times)) > 1000:
        found.add("micros")
    if (rec.truth["status"] == "dropped").any():
        found.add("dropped")
    return found


def test_plain_recording_has_no_artefact(base):
    assert signatures(base) == set()
    assert base.truth_meta["artefacts"]["injected"] == []
    assert (base.truth["status"] == "ok").all()
    assert "[columns]" not in base.toml_text


@pytest.mark.parametrize("name", list(CASES))
def test_each_artefact_appears_alone(recordings, name):
    assert signatures(recordings[name]) == CASES[name][1]


@pytest.mark.parametrize("name", list(CASES))
def test_artefacts_never_change_the_physics_or_sensors(base, recordings, name):
    rec = recordings[name]
    for col in ("theta_rad", "current_a", "dir", "adc"):
        if name != "reset":          # a reset changes what happens after it
            assert np.array_equal(rec.truth[col].to_numpy(), base.truth[col].to_numpy()), col
    assert np.array_equal(rec.truth["adc"].to_numpy()[:40], base.truth["adc"].to_numpy()[:40])


def test_injected_lines_are_where_the_log_says(recordings):
    lines = [IDE.sub("", ln) for ln in recordings["comments"].csv_bytes.decode().split("\n")[:-1]]
    comments = [i["line"] for i in recordings["comments"].truth_meta["artefacts"]["injected"]]
    assert len(comments) == 3 and all(lines[n - 1].startswith("#") for n in comments)
    rec = recordings["garbled"]
    lines = rec.csv_bytes.decode().split("\n")[:-1]
    garbled = [i for i in rec.truth_meta["artefacts"]["injected"] if i["kind"].startswith("garbled")]
    assert len(garbled) == 6
    for g in garbled:
        assert as_row(lines[g["line"] - 1]) is None
    ok = rec.truth[rec.truth["status"] == "ok"]
    assert len(ok) >= len(rec.truth) - 12                       # a merged line costs two samples
    for row in ok.itertuples():
        assert as_row(lines[row.line - 1]) == [row.t_ms, row.counts, row.adc, row.dir]


def test_dropped_lines_are_missing_and_listed(base, recordings):
    rec = recordings["dropped"]
    dropped = rec.truth_meta["lines_dropped"]
    assert len(dropped) == 4 and (rec.truth.loc[dropped, "line"] == 0).all()
    assert rec.truth_meta["n_lines"] == base.truth_meta["n_lines"] - 4
    kept = rec.truth[rec.truth["status"] == "ok"]
    assert set(kept["t_ms"]).isdisjoint(set(rec.truth.loc[dropped, "t_ms"]))


def test_reset_restarts_millis_and_counts(recordings):
    rec = recordings["reset"]
    t = rec.truth
    seg2 = t[t["segment"] == 2]
    assert t["segment"].max() == 2 and len(seg2) > 20
    assert seg2["t_ms"].iloc[0] < 10 and seg2["counts"].iloc[0] == 0
    assert seg2["dir"].iloc[0] == 0                              # the sketch's pre-roll again
    lines = rec.csv_bytes.decode().split("\n")[:-1]
    assert [i for i, ln in enumerate(lines) if ln == "t_ms,counts,adc,dir"] == [0, int(seg2["line"].iloc[0]) - 2]
    meta = rec.truth_meta["segments"]
    assert meta[1]["t_start_s"] > meta[0]["t_start_s"] + 60.0    # the rig sat unpowered and came to rest
    assert abs(meta[1]["theta_ref_rad"]) < 0.01


def test_ide_prefix_styles():
    wall = 18 * 3600 + 2 * 60 + 3.521
    assert ide_prefix(wall, "classic") == "18:02:03.521 -> "
    assert ide_prefix(wall, "ide2") == "18:2:3.521 -> "


@pytest.mark.parametrize("name, style", [("ide", "classic"), ("ide2", "ide2")])
def test_every_line_carries_its_style_of_prefix(recordings, name, style):
    for ln in recordings[name].csv_bytes.decode().split("\n")[:-1]:
        m = re.match(r"^(\d+):(\d+):(\d+)\.(\d{3}) -> ", ln)
        assert m, ln
        h, mi, s, ms = (int(g) for g in m.groups())
        assert m.group(0) == ide_prefix(h * 3600 + mi * 60 + s + ms / 1000, style)


@pytest.mark.parametrize("name, expected", [
    ("columns", {"t_ms": "time", "counts": "enc", "adc": "i_raw", "dir": "mode", "time_unit": "ms"}),
    ("no-dir", {"t_ms": "t_ms", "counts": "counts", "adc": "adc", "dir": "", "time_unit": "ms"}),
    ("micros", {"t_ms": "t_ms", "counts": "counts", "adc": "adc", "dir": "dir", "time_unit": "us"}),
])
def test_dialects_write_matching_columns_table(recordings, tmp_path, name, expected):
    path = tmp_path / "rig.toml"
    path.write_text(recordings[name].toml_text)
    columns = resolve_config([path]).columns
    assert {k: getattr(columns, k) for k in expected} == expected


def test_micros_are_millis_times_1000_plus_sub_ms(recordings):
    t = recordings["micros"].truth
    assert np.all(t["t_raw"] // 1000 == t["t_ms"])
