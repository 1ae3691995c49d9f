"""The compiled plain reader (``plain_kernel``) reads exactly what the general path reads, or declines.

For any capture: either ``read_int_rows`` declines, or the general path (``parse_capture``)
reads the same file as one clean segment with the same values and line numbers; and a capture
of valid integer rows in time order is never declined.  Likewise ``read_plain_signals``
(``signal_rows``): either it declines, or ``read_capture`` through it gives the general path's
signals tables bit for bit and the same report (or the same refusal), over random rigs; and a
capture whose rows all keep the range rules is never declined.  Both ways of cutting the body
(one piece, two halves on two threads) are held to this.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.bench_ingest import make_capture
from pipeline.config import default_config
from pipeline.ingest import plain
from pipeline.ingest.parse import LOGICAL, format_line, parse_capture
from pipeline.ingest.plain_kernel import read_int_rows
from pipeline.ingest.stage import read_capture

CFG = default_config()
NAMES = ["t_ms", "counts", "adc", "dir"]

row = st.fixed_dictionaries({
    "t_raw": st.integers(0, 2**32 - 1).map(float),
    "counts": st.integers(-(2**40), 2**40),
    "adc": st.integers(0, 1023),
    "dir": st.sampled_from([-1, 0, 1]),
})
# near misses of a row: what Arrow or int() would take but the grammar may not, and plain garbage
near_miss = st.one_of(
    st.text(alphabet="0123456789,-+. \t\re", min_size=0, max_size=24),
    st.sampled_from(["+5,1,2,3", " 5,1,2,3", "5,1,2,3 ", "1.5,1,2,3", "1e3,1,2,3", "nan,1,2,3", "-0,1,2,3",
                     "5,,2,3", "5,1,2", "5,1,2,3,4", "5,1,2,3,", "1234567890123456,1,2,3",
                     "5,1234567890123456789,2,3", "5,-123456789012345678,2,3", "5,1,2,3\r\r", "5,1\r2,3"]),
)


def _general(data: bytes):
    """The general path's single clean segment, or None when it reads the file any other way."""
    try:
        parsed = parse_capture(data, CFG.columns, "k.csv")
    except Exception:           # noqa: BLE001  (a refusal: the kernel must have declined)
        return None
    if len(parsed.segments) != 1 or parsed.quarantined or parsed.segments[0].quarantined or parsed.blank_lines \
            or parsed.comment_lines or parsed.notes:
        return None
    return parsed.segments[0]


def _kernel(data: bytes, split_min_bytes: int):
    lay = plain.plain_layout(data, CFG.columns, "k.csv")
    if lay is None or lay.body_start == len(data):
        return lay, None
    return lay, read_int_rows(memoryview(data)[lay.body_start:], lay.width, lay.layout["t_raw"], split_min_bytes)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(row.map(lambda r: format_line(r, dict(zip(["t_raw", "counts", "adc", "dir"], range(4))), 4)),
                          near_miss), min_size=1, max_size=30),
       st.booleans(), st.sampled_from(["\n", "\r\n"]), st.sampled_from([0, 1 << 30]))
def test_kernel_reads_what_the_general_path_reads_or_declines(lines, header, eol, split_min_bytes):
    data = (((",".join(NAMES) + eol) if header else "") + eol.join(lines) + eol).encode()
    lay, out = _kernel(data, split_min_bytes)
    if out is None:
        return
    seg = _general(data)
    assert seg is not None, data
    assert seg.layout == lay.layout and seg.width == lay.width
    assert seg.line.tolist() == list(range(lay.first_line, lay.first_line + out.shape[1]))
    for logical, j in lay.layout.items():
        expected = seg.values[logical]
        got = out[j].astype(np.float64) if logical == "t_raw" else out[j]
        assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected)), logical


@settings(max_examples=100, deadline=None)
@given(st.lists(row, min_size=1, max_size=60), st.booleans(), st.sampled_from(["\n", "\r\n"]),
       st.sampled_from([2, 3, 4]), st.sampled_from([0, 1 << 30]))
def test_kernel_takes_every_valid_capture_in_time_order(rows, header, eol, width, split_min_bytes):
    layout = dict(zip(["t_raw", "counts", "adc", "dir"][:width], range(width)))
    rows = sorted(rows, key=lambda r: r["t_raw"])
    data = (((",".join(NAMES[:width]) + eol) if header else "") +
            eol.join(format_line(r, layout, width) for r in rows) + eol).encode()
    lay, out = _kernel(data, split_min_bytes)
    assert out is not None
    assert out[lay.layout["counts"]].tolist() == [r["counts"] for r in rows]
    assert out[lay.layout["t_raw"]].tolist() == [int(r["t_raw"]) for r in rows]


@pytest.mark.parametrize("body", [
    b"5,1,2,3\n4,1,2,3\n",                    # time goes back
    b"5,1,2,3\n\n6,1,2,3\n",                  # blank line
    b"5,1,2,3\r6,1,2,3\n",                    # stray carriage return
    b"5.5,1,2,3\n6,1,2,3\n",                  # decimal time: the Arrow reader's case
    b"+5,1,2,3\n6,1,2,3\n", b"5, 1,2,3\n6,1,2,3\n", b"5,1,2,3\n6,1,2,-\n",
])
def test_kernel_declines_what_it_does_not_read_alike(body):
    data = b"t_ms,counts,adc,dir\n" + body
    assert _kernel(data, 0)[1] is None


def test_halves_meeting_out_of_time_order_are_declined():
    first, second = b"10,1,2,3\n" * 8, b"9,1,2,3\n" * 9       # the cut falls between the two blocks
    assert read_int_rows(memoryview(first + second), 4, 0, 0) is None
    assert read_int_rows(memoryview(first + first), 4, 0, 0).shape == (4, 16)


def test_large_capture_gives_the_same_tables_through_the_kernel_and_through_arrow(monkeypatch):
    data = make_capture(300_000)                               # 5.4 MB: above KERNEL_MIN_BYTES
    assert len(data) >= plain.KERNEL_MIN_BYTES
    lay = plain.plain_layout(data, CFG.columns, "big.csv")
    compiled = plain.read_plain_rows(data, lay)
    monkeypatch.setattr(plain, "KERNEL_MIN_BYTES", len(data) + 1)
    arrow = plain.read_plain_rows(data, lay)
    assert list(compiled) == list(arrow)
    for k in arrow:
        assert compiled[k].dtype == arrow[k].dtype and np.array_equal(compiled[k], arrow[k])
    by_arrow = read_capture(data, CFG, "big.csv", "big").runs[0].signals
    monkeypatch.undo()
    assert read_capture(data, CFG, "big.csv", "big").runs[0].signals.equals(by_arrow)


def test_small_captures_do_not_import_numba(tmp_path):
    """``pdr run`` ingests small recordings in its main process: they must not pay numba's import and start."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys, pathlib; from pipeline.ingest.stage import ingest_recording; "
            f"ingest_recording(pathlib.Path({str(tmp_path / 'rec.csv')!r}), pathlib.Path({str(tmp_path / 'out')!r})); "
            "print('numba' in sys.modules)")
    (tmp_path / "rec.csv").write_bytes(make_capture(20_000))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2])
    assert res.stdout.strip().splitlines()[-1] == "False"
    assert (tmp_path / "out" / "rec" / "rec.mcap").is_file()


# ------------------------------------------------------------------ signal_rows: the signals columns themselves

def _rig(counts_per_rev, vref, steps, sensitivity, zero_v, unit, columns):
    import dataclasses
    cs = dataclasses.replace(CFG.current_sensor, adc_vref=vref, adc_steps=steps, sensitivity_v_per_a=sensitivity,
                             zero_v=zero_v)
    return dataclasses.replace(CFG, encoder=dataclasses.replace(CFG.encoder, counts_per_rev=counts_per_rev),
                               current_sensor=cs, columns=dataclasses.replace(CFG.columns, time_unit=unit, **columns))


rigs = st.builds(_rig, st.floats(0.5, 1e5), st.floats(0.1, 12.0), st.sampled_from([256, 1024, 4096]),
                 st.floats(0.01, 1.0), st.one_of(st.floats(0.0, 5.0), st.just("auto")),
                 st.sampled_from(["ms", "us", "s"]),
                 st.sampled_from([{}, {"dir": ""}, {"adc": ""}, {"adc": "", "dir": ""}]))
# rows in range, then a few values changed to what the range rules quarantine (or just keep), and times
# that may go back or pass a counter's wrap
edits = st.lists(st.tuples(st.integers(0, 39), st.one_of(
    st.tuples(st.just("adc"), st.sampled_from([-1, 0, 255, 256, 1023, 1024, 4095, 4096])),
    st.tuples(st.just("dir"), st.sampled_from([-2, 2])),
    st.tuples(st.just("counts"), st.sampled_from([-(10**18) + 1, 10**18 - 1, 2**53 + 1, -(2**53) - 1])),
    st.tuples(st.just("t_raw"), st.sampled_from([0.0, 2.0**32 - 1, 2.0**32, 10.0**15 - 1])))), max_size=2)


def _capture(rows, cfg, header, eol, sort) -> bytes:
    """The rows as a capture with the columns ``cfg`` logs, in docs/FORMAT.md order."""
    c = cfg.columns
    logged = [(k, n) for k, n in zip(LOGICAL, (c.t_ms, c.counts, c.adc, c.dir)) if n]
    layout = {k: j for j, (k, _) in enumerate(logged)}
    rows = sorted(rows, key=lambda r: r["t_raw"]) if sort else rows
    return (((",".join(n for _, n in logged) + eol) if header else "")
            + "".join(format_line(r, layout, len(logged)) + eol for r in rows)).encode()


def _outcome(fn):
    try:
        cap = fn()
    except Exception as err:            # noqa: BLE001  (a refusal: both ways must refuse alike)
        return type(err).__name__ + ": " + str(err)
    from pipeline.ingest.stage import capture_report
    return cap.runs, json.dumps(capture_report(cap), sort_keys=True)


def _same_bits(a, b) -> None:
    assert list(a.columns) == list(b.columns)
    for c in a.columns:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), c


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(row, min_size=1, max_size=40), edits, rigs, st.booleans(), st.sampled_from(["\n", "\r\n"]),
       st.booleans(), st.sampled_from([0, 1 << 30]))
def test_signal_rows_give_the_general_paths_tables_and_report_or_decline(rows, changes, cfg, header, eol, sort,
                                                                         split_min_bytes):
    from pipeline.ingest import plain_kernel, stage
    rows = [r | {"adc": r["adc"] % cfg.current_sensor.adc_steps} for r in rows]
    for i, (key, value) in changes:
        rows[i % len(rows)] = rows[i % len(rows)] | {key: value}
    data = _capture(rows, cfg, header, eol, sort)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plain, "KERNEL_MIN_BYTES", 0)
        mp.setattr(plain_kernel, "SPLIT_MIN_BYTES", split_min_bytes)
        taken = plain.read_plain_signals(data, cfg, "k.csv") is not None
        fast = _outcome(lambda: read_capture(data, cfg, "k.csv", "k"))
        mp.setattr(stage, "read_plain_signals", lambda *a: None)
        general = _outcome(lambda: read_capture(data, cfg, "k.csv", "k"))
    if isinstance(general, str) or isinstance(fast, str):
        assert fast == general
        return
    assert fast[1] == general[1]
    assert [r.name for r in fast[0]] == [r.name for r in general[0]]
    for a, b in zip(fast[0], general[0]):
        _same_bits(a.signals, b.signals)
    if taken:                           # what the kernel takes is one clean segment
        report = json.loads(general[1])
        assert report["rows"]["quarantined"] == 0 and len(report["segments"]) == 1


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(row, min_size=2, max_size=40), rigs, st.booleans(), st.sampled_from(["\n", "\r\n"]),
       st.sampled_from([0, 1 << 30]))
def test_signal_rows_take_every_capture_in_range_and_time_order(rows, cfg, header, eol, split_min_bytes):
    """... except those with a repeated time or an impossible encoder jump, which the general path cleans."""
    import numpy as np

    from pipeline.ingest import plain_kernel
    from pipeline.ingest.plausible import needs_cleaning
    steps = cfg.current_sensor.adc_steps
    rows = [r | {"adc": r["adc"] % steps} for r in rows]
    data = _capture(rows, cfg, header, eol, sort=True)
    ordered = sorted(rows, key=lambda r: r["t_raw"])
    dirty = needs_cleaning(np.array([r["t_raw"] for r in ordered]), np.array([r["counts"] for r in ordered]),
                           cfg.columns.time_unit, cfg)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plain_kernel, "SPLIT_MIN_BYTES", split_min_bytes)
        mp.setattr(plain, "KERNEL_MIN_BYTES", 0)
        assert (plain.read_plain_signals(data, cfg, "k.csv") is not None) == (not dirty)


def test_large_capture_gives_the_same_signals_through_signal_rows(monkeypatch):
    from pipeline.ingest import stage
    data = make_capture(300_000)
    fast = read_capture(data, CFG, "big.csv", "big")
    assert plain.read_plain_signals(data, CFG, "big.csv") is not None
    monkeypatch.setattr(stage, "read_plain_signals", lambda *a: None)
    _same_bits(fast.runs[0].signals, read_capture(data, CFG, "big.csv", "big").runs[0].signals)


@pytest.mark.parametrize("last, taken", [
    ("4294967295,5,1023,1", True), ("4294967296,5,1023,1", False),     # millis: the counter's range
    ("60,5,1024,1", False), ("60,5,0,-1", True), ("60,5,-1,0", False),  # adc in 0..1023
    ("60,5,9,2", False), ("60,5,9,-2", False),                          # dir in -1..1
    ("60,999999999999999999,9,0", True), ("60,-999999999999999999,9,0", True),
    ("60,1000000000000000000,9,0", False), ("40,5,9,0", False),         # 19 digits; time going back
    ("60,999999999999999999,9,0|0", False), ("50,5,9,0", False),        # a jump no motor makes; time repeated
])
def test_signal_rows_decline_at_the_range_rules_edges(last, taken):
    # the first row's count near the last's, unless "|0" asks for 0 (an 18-digit jump within 10 ms)
    last, _, first = last.partition("|")
    count = last.split(",")[1]
    first = first or (count[:-1] + "0" if len(count) > 3 else "0")
    data = f"t_ms,counts,adc,dir\n50,{first},511,0\n{last}\n".encode()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plain, "KERNEL_MIN_BYTES", 0)
        assert (plain.read_plain_signals(data, CFG, "k.csv") is not None) == taken
