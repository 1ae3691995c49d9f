"""Issue 31's names and sizes: a raw folder whose entries are named to break a terminal, a table, a dataset
reader or a file browser, and files too big or too empty to read, beside good recordings: each bad entry
is refused in one printable line that names it, every good recording is processed, raw/ is unchanged."""

from __future__ import annotations

import os
import unicodedata

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.names import name_problem, printable
from tests.hostile.folders import good_csv, no_traceback, pdr_run, snapshot

NFC, NFD = unicodedata.normalize("NFC", "café"), unicodedata.normalize("NFD", "café")
NAMED = {
    # entry -> what its FAILED line says (the entry's name printed escaped)
    "esc\x1b[31mred\x1b[0m.csv": "the control character \\x1b",
    "a\nb.csv": "the control character \\n",
    "tab\there.csv": "the control character \\t",
    "x%2Fy.csv": "holds '%'",
    ".csv": "the name before '.csv' is empty",
    "..csv": "starts with '.'",
    f"{NFC}.csv": f"collides with {NFD}.csv",
}


def test_names_that_break_a_terminal_a_table_or_a_dataset_are_refused_in_one_printable_line(workspace):
    raw = workspace.fresh_raw()
    (raw / "good0.csv").write_bytes(good_csv(0))
    (raw / f"{NFD}.csv").write_bytes(good_csv(1))           # the first of the twins is a recording
    for name in NAMED:
        (raw / name).write_bytes(good_csv(0))
    before = snapshot(raw)
    processed = workspace.processed()
    text, code = pdr_run(raw, processed)
    assert code == 1, text
    assert "\x1b[31m" not in text and "\t" not in text      # no escape code reaches the terminal
    failed = {line.split(": ", 1)[0][len("FAILED "):]: line for line in text.splitlines()
              if line.startswith("FAILED ")}
    assert len(failed) == len(NAMED), failed                 # a newline in a name splits no line
    for name, says in NAMED.items():
        assert says in failed[printable(name)], (name, failed)
    assert sorted(p.name for p in processed.iterdir() if not p.name.startswith(".")) == [
        NFD, "dataset", "good0", "summary.csv"]
    import pyarrow.dataset as ds
    runs = ds.dataset(processed / "dataset" / "kinematics", partitioning="hive").to_table(columns=["run"])
    assert sorted(set(runs.column("run").to_pylist())) == sorted([NFD, "good0"])
    assert snapshot(raw) == before


@pytest.mark.parametrize("stem, says", [
    ("ok-name_1.2", None), ("café", None), ("\u202eevil", "the control character \\u202e"),
    ("run\r", "the control character \\r"), ("50%", "holds '%'"), ("...", "starts with '.'"),
])
def test_the_naming_rule_in_one_place(stem, says):
    problem = name_problem(stem)
    assert (problem is None) if says is None else (says in problem), problem


def test_same_stem_inputs_to_ingest_are_refused_naming_both(tmp_path):
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "x.csv").write_bytes(good_csv(0 if folder == "a" else 1))
    a, b = tmp_path / "a" / "x.csv", tmp_path / "b" / "x.csv"
    res = CliRunner().invoke(app, ["ingest", str(a), str(b), "--processed", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 2
    no_traceback(res.output)
    lines = [ln for ln in res.output.splitlines() if ln.startswith("pdr: error: ")]
    assert len(lines) == 1 and str(b) in lines[0] and str(a) in lines[0], res.output
    report = (tmp_path / "out" / "x" / "ingest_report.json").read_text()
    assert str(a) in report and str(b) not in report          # the first one's outputs, not overwritten


def test_mixed_line_endings_are_read_as_lines(tmp_path):
    header, *body = good_csv(0).splitlines()
    mixed = header + b"\r\n" + b"".join(ln + (b"\r\n", b"\n", b"\r")[k % 3] for k, ln in enumerate(body))
    (tmp_path / "mixed.csv").write_bytes(mixed)
    res = CliRunner().invoke(app, ["ingest", str(tmp_path / "mixed.csv"), "--processed", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    import json
    report = json.loads((tmp_path / "out" / "mixed" / "ingest_report.json").read_text())
    assert report["rows"] == {"read": len(body), "kept": len(body), "quarantined": 0}


def test_a_sparse_4_gib_and_1_gib_file_of_zeros_are_refused_unread_and_the_good_one_is_processed(workspace):
    raw = workspace.fresh_raw()
    (raw / "good0.csv").write_bytes(good_csv(0))
    for name, size in (("huge.csv", 4 << 30), ("gig.csv", 1 << 30), ("zeros.csv", 1 << 20)):
        with open(raw / name, "wb") as fh:
            fh.truncate(size)               # sparse: no disk used, no byte written
    before = _stats(raw)                    # not snapshot(): that would read the 5 GiB whole
    processed = workspace.processed()
    # under a 6 GB address-space limit (as issue 31 ran it): reading either file whole fails, refusing costs nothing
    text, code = pdr_run(raw, processed, memory_kb=6_000_000)
    assert code == 1, text
    assert "FAILED huge.csv: raw entry refused: 4096 MiB, expected a recording of at most 256 MiB" in text
    assert "FAILED gig.csv: raw entry refused: 1024 MiB, expected a recording of at most 256 MiB" in text
    assert "FAILED zeros.csv: raw entry refused: binary content" in text
    assert (processed / "good0" / "validation.json").is_file()
    assert _stats(raw) == before
    assert os.stat(raw / "huge.csv").st_blocks == 0           # still sparse: nothing was written into it


def _stats(folder) -> dict[str, tuple[int, int, int]]:
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns, p.stat().st_blocks) for p in folder.iterdir()}
