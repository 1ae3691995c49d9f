"""What lands on disk: Parquet and MCAP read back by their own libraries, determinism, the CLI, kills."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import NonSeekingReader, make_reader

from pipeline.config import default_config
from pipeline.errors import PdrError
from pipeline.ingest.stage import ingest_recording
from pipeline.ingest.mcap_bulk import write_mcap
from pipeline.ingest.write import CHANNEL_GROUPS, GUARDS_TOPIC, log_time_ns, mcap_channels
from pipeline.runs import load_config, load_signals
from pipeline.schemas import load_schema
from tests.ingest.helpers import CLEAN, ingest

PDR = str(Path(sys.executable).parent / "pdr")


def _recording(tmp_path: Path, data: bytes = CLEAN, name: str = "rec") -> Path:
    raw = tmp_path / "raw"
    raw.mkdir(exist_ok=True)
    path = raw / f"{name}.csv"
    path.write_bytes(data)
    return path


def _read_mcap(path: Path):
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        messages = {}
        for schema, channel, message in reader.iter_messages():
            messages.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
        schemas = {ch.topic: json.loads(summary.schemas[ch.schema_id].data) for ch in summary.channels.values()}
        encodings = {ch.topic: (ch.message_encoding, summary.schemas[ch.schema_id].encoding)
                     for ch in summary.channels.values()}
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    return messages, schemas, encodings, metadata, summary


def test_parquet_round_trip_values_units_schema(tmp_path):
    csv = _recording(tmp_path)
    (csv.parent / "rig.toml").write_text("[encoder]\ncounts_per_rev = 1000.0\n")
    result = ingest_recording(csv, tmp_path / "processed")
    paths = result.runs[0]
    table = pq.read_table(paths.signals)
    schema = load_schema("signals")
    for f in table.schema:
        col = schema.column(f.name)
        assert f.metadata[b"unit"].decode() == col.unit
        assert f.type == col.arrow_type
    df = load_signals(paths)
    assert df.equals(result.tables["rec"])
    np.testing.assert_allclose(df["theta_rad"], df["counts"] * 2 * np.pi / 1000.0)
    cfg = load_config(paths)
    assert cfg.encoder.counts_per_rev == 1000.0
    stored = json.loads(paths.rig_config.read_text())
    assert stored["sources"]["encoder.counts_per_rev"] == str(csv.parent / "rig.toml")
    report = json.loads(paths.ingest_report.read_text())
    assert report["sources"]["encoder.counts_per_rev"] == str(csv.parent / "rig.toml")
    assert report["run"] == "rec" and len(report["sha256"]) == 64


def test_mcap_round_trip_values_schemas_metadata(tmp_path):
    result = ingest_recording(_recording(tmp_path), tmp_path / "processed")
    paths, df = result.runs[0], result.tables["rec"]
    messages, schemas, encodings, metadata, summary = _read_mcap(paths.mcap)
    assert sorted(messages) == sorted([*CHANNEL_GROUPS, GUARDS_TOPIC])
    expected_ns = np.round(df["t_s"].to_numpy() * 1e9).astype(np.uint64)
    for topic, names in CHANNEL_GROUPS.items():
        msgs = messages[topic]
        assert [t for t, _ in msgs] == expected_ns.tolist()
        for name in names:
            assert [m[name] for _, m in msgs] == df[name].tolist()
        assert schemas[topic] == load_schema("signals", default_config()).json_schema(list(names), title="pdr." + topic.strip("/"))
        assert encodings[topic] == ("json", "jsonschema")
        for name in names:
            unit = load_schema("signals").column(name).unit
            assert schemas[topic]["properties"][name]["description"].endswith(f"[{unit}]")
    assert schemas["/encoder"]["properties"]["theta_rad"]["description"].endswith("[rad]")
    assert json.loads(metadata["rig_config"]["config"]) == default_config().to_dict()
    assert metadata["recording"]["sha256"] == result.report["sha256"]
    assert summary.statistics.message_count == 4 * len(df)
    guard = default_config().controller.guard_rad                     # a channel Foxglove can plot
    assert [t for t, _ in messages[GUARDS_TOPIC]] == expected_ns.tolist()
    assert {(m["lower_rad"], m["upper_rad"]) for _, m in messages[GUARDS_TOPIC]} == {(-guard, guard)}


def test_mcap_many_chunks_read_back_in_order(tmp_path):
    n = 3000
    t = np.arange(n) * 50
    body = "\n".join(f"{a},{a % 977 - 400},{a % 1024},{(a // 500) % 3 - 1}" for a in t)
    runs, _ = ingest(("t_ms,counts,adc,dir\n" + body + "\n").encode())
    df = runs[0].signals
    path = tmp_path / "small_chunks.mcap"
    with open(path, "wb") as fh:
        write_mcap(fh, mcap_channels(df, default_config()), log_time_ns(df["t_s"].to_numpy()), {}, chunk_bytes=4096)
    messages, _, _, _, summary = _read_mcap(path)
    assert summary.statistics.chunk_count > 30
    assert [m["counts"] for _, m in messages["/encoder"]] == (t % 977 - 400).tolist()
    assert [m["mode"] for _, m in messages["/command"]] == df["mode"].tolist()
    assert [m["current_a"] for _, m in messages["/current"]] == df["current_a"].tolist()


def test_mcap_of_one_block_built_inline_is_the_threaded_writers_file(tmp_path, monkeypatch):
    """A file of one block reuses its size probe's records and builds its chunks without builder
    threads: the same bytes as the threaded path (forced by probing fewer rows), read back in order."""
    import io

    from pipeline.ingest import mcap_bulk

    n = 700
    t = np.arange(n) * 50
    body = "\n".join(f"{a},{a % 977 - 400},{a % 1024},{(a // 500) % 3 - 1}" for a in t)
    df = ingest(("t_ms,counts,adc,dir\n" + body + "\n").encode())[0][0].signals
    files = []
    for probe_rows in (mcap_bulk.PROBE_ROWS, 64):
        monkeypatch.setattr(mcap_bulk, "PROBE_ROWS", probe_rows)
        out = io.BytesIO()
        write_mcap(out, mcap_channels(df, default_config()), log_time_ns(df["t_s"].to_numpy()), {"m": {"k": "v"}})
        files.append(out.getvalue())
    assert files[0] == files[1]
    path = tmp_path / "one_block.mcap"
    path.write_bytes(files[0])
    messages, _, _, _, summary = _read_mcap(path)
    assert summary.statistics.chunk_count == len(messages) == len(mcap_channels(df, default_config()))
    assert [m["counts"] for _, m in messages["/encoder"]] == (t % 977 - 400).tolist()


def test_mcap_linear_scan_matches_indexed_read(tmp_path):
    """A reader that ignores the summary (streams every record, checks every CRC) sees the same messages."""
    result = ingest_recording(_recording(tmp_path, CLEAN + CLEAN), tmp_path / "processed")
    for paths in result.runs:
        indexed, *_ = _read_mcap(paths.mcap)
        linear: dict = {}
        with open(paths.mcap, "rb") as fh:
            for _, channel, message in NonSeekingReader(fh, validate_crcs=True).iter_messages():
                linear.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
        assert linear == indexed


def test_channels_for_columns_not_logged_are_absent(tmp_path):
    csv = _recording(tmp_path, b"t_ms,counts\n0,0\n50,1\n100,3\n")
    (csv.parent / "rec.toml").write_text('[columns]\nadc = ""\ndir = ""\n')
    result = ingest_recording(csv, tmp_path / "processed")
    messages, schemas, *_ = _read_mcap(result.runs[0].mcap)
    assert sorted(messages) == ["/encoder", GUARDS_TOPIC]
    assert set(schemas["/encoder"]["properties"]) == {"t_s", "counts", "theta_rad"}


def test_rerun_gives_identical_bytes_and_raw_untouched(tmp_path):
    csv = _recording(tmp_path, CLEAN + CLEAN)
    raw_before = csv.read_bytes()
    first = ingest_recording(csv, tmp_path / "p1")
    snapshot = {p: p.read_bytes() for r in first.runs for p in r.root.iterdir()}
    ingest_recording(csv, tmp_path / "p1")
    ingest_recording(csv, tmp_path / "p2")
    assert len(snapshot) == 8
    for p, data in snapshot.items():
        assert p.read_bytes() == data
        assert (tmp_path / "p2" / p.parent.name / p.name).read_bytes() == data
    assert csv.read_bytes() == raw_before


def test_cli_ingests_and_prints_summary(tmp_path):
    csv = _recording(tmp_path)
    out = subprocess.run([PDR, "ingest", str(csv), "--processed", str(tmp_path / "processed")],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "10 rows kept, 0 quarantined" in out.stdout
    assert (tmp_path / "processed" / "rec" / "rec.mcap").is_file()


REFUSALS = [
    (b"", None, "empty file"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00" * 20, None, "binary or non-UTF-8"),
    (b"time,enc\n1,2\n", None, "no recognisable columns"),
    (CLEAN + b"garbage\n" * 8, None, "too many unreadable rows"),
    (CLEAN.replace(b"300,30", b"30,30").replace(b"350,55", b"35,55"), None, "time goes back"),
    (CLEAN, "[encoder]\ncpr = 3\n", "key 'encoder.cpr': unknown key"),
    (CLEAN, "[encoder]\ncounts_per_rev = \"many\"\n", "expected a number"),
    (CLEAN, "[current_sensor]\nsensitivity_v_per_a = -0.185\n", "expected a positive number"),
]


@pytest.mark.parametrize("data, toml, message", REFUSALS)
def test_refusals_write_nothing(tmp_path, data, toml, message):
    csv = _recording(tmp_path, data)
    if toml:
        (csv.parent / "rec.toml").write_text(toml)
    with pytest.raises(PdrError, match=re.escape(message)) as err:
        ingest_recording(csv, tmp_path / "processed")
    assert "\n" not in str(err.value) and str(csv.parent) in str(err.value)
    assert not (tmp_path / "processed").exists()


@pytest.mark.parametrize("data, toml, message", [REFUSALS[0], REFUSALS[4], REFUSALS[5]])
def test_cli_refusals_one_line_nonzero(tmp_path, data, toml, message):
    csv = _recording(tmp_path, data)
    if toml:
        (csv.parent / "rec.toml").write_text(toml)
    out = subprocess.run([PDR, "ingest", str(csv), "--processed", str(tmp_path / "processed")],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pdr: error: ") and message in lines[0]
    # the command holds processed/'s lock (created with the folder); nothing else is written
    assert [p.name for p in (tmp_path / "processed").iterdir()] == [".pdr.lock"]


def _big_capture(n: int, offset: int) -> bytes:
    t = np.arange(n) * 5
    counts = (t // 7 + offset) % 5000
    return ("t_ms,counts,adc,dir\n" + "\n".join(f"{a},{c},{a % 1024},1" for a, c in zip(t, counts)) + "\n").encode()


@pytest.mark.slow
def test_killed_run_leaves_old_or_new_files_never_torn(tmp_path):
    csv = _recording(tmp_path, _big_capture(120_000, 0), name="big")
    processed = tmp_path / "processed"
    ingest_recording(csv, processed)
    old = {p.name: p.read_bytes() for p in (processed / "big").iterdir()}
    csv.write_bytes(_big_capture(120_000, 1))
    ingest_recording(csv, tmp_path / "reference")
    new = {p.name: p.read_bytes() for p in (tmp_path / "reference" / "big").iterdir()}
    assert all(old[k] != new[k] for k in ("signals.parquet", "big.mcap"))
    code = ("import sys; from pathlib import Path; from pipeline.ingest.stage import ingest_recording; "
            "ingest_recording(Path(sys.argv[1]), Path(sys.argv[2]))")
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", code, str(csv), str(tmp_path / "timed")], check=True)
    full = time.perf_counter() - start              # kill at fractions of a whole run, on any machine
    for fraction in (0.5, 0.7, 0.9):
        proc = subprocess.Popen([sys.executable, "-c", code, str(csv), str(processed)])
        time.sleep(fraction * full)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        files = {p.name: p.read_bytes() for p in (processed / "big").iterdir() if not p.name.endswith(".tmp")}
        assert set(files) == set(old)
        for name, data in files.items():
            assert data in (old[name], new[name]), name
    ingest_recording(csv, processed)
    assert not [p for p in (processed / "big").iterdir() if p.name.endswith(".tmp")]
    assert {p.name: p.read_bytes() for p in (processed / "big").iterdir()} == new
