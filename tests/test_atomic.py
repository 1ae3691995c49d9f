"""Atomic outputs: the old file or the new one, never a torn one, and no temporary left behind."""

import os
from pathlib import Path

import pytest

from pipeline.io import atomic
from pipeline.io.atomic import atomic_path, write_bytes, write_json


def _temps(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.name.endswith(".tmp")]


def test_write_bytes_creates_parents_replaces_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "a" / "b" / "out.bin"
    write_bytes(target, b"first")
    write_bytes(target, b"second")
    assert target.read_bytes() == b"second"
    assert _temps(target.parent) == []


def test_permissions_are_those_of_a_plain_open(tmp_path):
    plain = tmp_path / "plain"
    plain.write_bytes(b"x")
    write_bytes(tmp_path / "atomic", b"x")
    with atomic_path(tmp_path / "via_path") as tmp:
        tmp.write_bytes(b"x")
    mode = plain.stat().st_mode & 0o777
    assert (tmp_path / "atomic").stat().st_mode & 0o777 == mode
    assert (tmp_path / "via_path").stat().st_mode & 0o777 == mode


def test_large_payload_is_written_whole(tmp_path):
    data = os.urandom(5_000_000)
    write_bytes(tmp_path / "big", data)
    assert (tmp_path / "big").read_bytes() == data


def test_failure_inside_keeps_the_previous_file(tmp_path):
    target = tmp_path / "out.json"
    write_json(target, {"v": 1})
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half a fi")
            raise RuntimeError("killed halfway")
    assert target.read_text() == '{\n  "v": 1\n}\n'
    assert _temps(tmp_path) == []


def test_unserialisable_json_keeps_the_previous_file(tmp_path):
    target = tmp_path / "out.json"
    write_json(target, {"v": 1})
    with pytest.raises(TypeError):
        write_json(target, {"v": object()})
    assert target.read_text() == '{\n  "v": 1\n}\n'
    assert _temps(tmp_path) == []


def test_a_stale_temporary_of_the_same_name_is_skipped_not_overwritten(tmp_path, monkeypatch):
    target = tmp_path / "out.bin"
    monkeypatch.setattr(atomic, "_serial", iter(range(5)))
    stale = tmp_path / f".out.bin.{os.getpid()}.0.tmp"
    stale.write_bytes(b"left by a killed run")
    write_bytes(target, b"new")
    assert target.read_bytes() == b"new"
    assert stale.read_bytes() == b"left by a killed run"
