"""Raw folders as a hostile new user makes them: good recordings beside bad entries, and the checks every
hostile case must pass (no traceback, each good recording's outputs as when processed alone, raw/ unchanged)."""

from __future__ import annotations

import functools
import hashlib
import os
import stat
import sys
from pathlib import Path

from pipeline.rig.recording import RigSetup, make_recording
from tests.ingest.test_realdata import REAL as REALDATA  # noqa: F401  (one place names tests/data/realdata)

PDR = str(Path(sys.executable).with_name("pdr"))
CODE = "pinned"               # stamps must not see the source tree being edited while the tests run
# outputs compared byte for byte; the .rrd (Rerun) and overview.png are checked for presence only
COMPARED = (".parquet", ".json", ".mcap")




@functools.lru_cache(maxsize=None)
def good_csv(seed: int) -> bytes:
    """A short clean virtual-rig capture (6 s: three guard switches), the same bytes for the same seed."""
    return make_recording(RigSetup(duration_s=6.0), seed=seed).csv_bytes


def rows(data: bytes) -> tuple[bytes, list[bytes]]:
    """Header line and data lines of a capture."""
    header, *body = data.splitlines(keepends=True)
    return header, body


def with_line_repeated(data: bytes, k: int) -> bytes:
    """The capture with its ``k``-th data line sent twice, as a serial buffer retransmits it."""
    header, body = rows(data)
    return header + b"".join(body[:k + 1] + body[k:])


def with_count_glitch(data: bytes, k: int) -> bytes:
    """The ``k``-th data line's count with an extra digit appended (serial noise: 1302 -> 13022)."""
    header, body = rows(data)
    t, counts, *rest = body[k].split(b",")
    body[k] = b",".join([t, counts + b"2", *rest])
    return header + b"".join(body)


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry of a folder as it is on disk (kind, bytes or link target), without opening anything but
    regular files: the raw folder must come out of every hostile case exactly as it went in."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            st = os.lstat(path)
            rel = os.fsencode(path.relative_to(folder))
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(path))
            elif stat.S_ISREG(st.st_mode):
                out[rel] = ("file", hashlib.sha256(path.read_bytes()).hexdigest(), st.st_mtime_ns)
            else:
                out[rel] = (stat.S_IFMT(st.st_mode),)
    return out


def run_outputs(processed: Path, run: str) -> dict[str, bytes]:
    """The byte-compared outputs of one run, by file name (the stamp without its code version)."""
    import json

    root = processed / run
    files = {p.name: p.read_bytes() for p in root.iterdir() if p.suffix in COMPARED}
    stamp = json.loads(files["stamp.json"])         # the code version: pinned in-process, computed by `pdr`
    files["stamp.json"] = json.dumps({k: v for k, v in stamp.items() if k not in ("code_version", "key")}).encode()
    for p in (root / f"{run}.rrd", root / "overview.png"):
        assert p.is_file(), p
    return files


class Workspace:
    """One raw folder path reused by every case (the reports and stamps name it, so outputs compare byte
    for byte), and each good recording's outputs when processed alone from it, made once."""

    def __init__(self, base: Path) -> None:
        self.base, self.raw = base, base / "raw"
        self._alone: dict[int, dict[str, bytes]] = {}
        self._n = 0

    def fresh_raw(self) -> Path:
        """The raw folder, emptied (a FIFO or a link inside is removed, never opened)."""
        import shutil
        if self.raw.exists():
            shutil.rmtree(self.raw)
        self.raw.mkdir(parents=True)
        return self.raw

    def processed(self) -> Path:
        self._n += 1
        return self.base / f"processed{self._n}"

    def alone(self, seed: int) -> dict[str, bytes]:
        """``good<seed>``'s outputs when its recording is the only entry of the raw folder."""
        if seed not in self._alone:
            from pipeline.run import run_pipeline
            (self.fresh_raw() / f"good{seed}.csv").write_bytes(good_csv(seed))
            out = self.processed()
            report = run_pipeline(self.raw, out, jobs=1, code=CODE)
            assert [r["status"] for r in report.ran] == ["ok"], report.ran
            self._alone[seed] = run_outputs(out, f"good{seed}")
        return self._alone[seed]

    def assert_as_alone(self, processed: Path, seed: int) -> None:
        """``good<seed>``'s outputs in ``processed`` are byte for byte those of processing it alone."""
        got, want = run_outputs(processed, f"good{seed}"), self.alone(seed)
        assert sorted(got) == sorted(want), seed
        for name in want:
            assert got[name] == want[name], f"good{seed}/{name} differs from processing the recording alone"


def no_traceback(*texts: str) -> None:
    for text in texts:
        assert "Traceback" not in text and "internal error" not in text, text


def pdr_run(raw: Path, processed: Path, memory_kb: int | None = None) -> tuple[str, int]:
    """``pdr run -j 1`` as a user runs it (optionally under an address-space limit, ``ulimit -v``):
    its whole output, checked to hold no traceback, and its exit status."""
    import subprocess

    cmd = [PDR, "run", "--raw", str(raw), "--processed", str(processed), "-j", "1"]
    if memory_kb is not None:
        cmd = ["bash", "-c", f'ulimit -v {int(memory_kb)} && exec "$@"', "_", *cmd]
    out = subprocess.run(cmd, capture_output=True, timeout=180)
    text = out.stdout.decode() + out.stderr.decode()
    no_traceback(text)
    return text, out.returncode
