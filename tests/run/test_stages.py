"""What pdr run does ahead in its own process while the workers start (ingest, then derive) gives the
outputs a worker gives doing every stage itself."""

import shutil
from pathlib import Path

from pipeline.run.stages import derive_ahead, ingest_ahead, process_chunk
from pipeline.run.stamp import stamp_for
from tests.cluster.helpers import CODE, make_raw


def _outputs(processed: Path) -> dict[str, bytes]:
    """Every output but the .rrd (Rerun's write time is in it) and the stamps (checked apart)."""
    return {p.relative_to(processed).as_posix(): p.read_bytes() for p in sorted(processed.rglob("*"))
            if p.is_file() and p.suffix != ".rrd" and p.name != "stamp.json"}


def test_stages_done_ahead_give_the_outputs_of_a_worker_doing_them(tmp_path):
    raw = tmp_path / "raw"
    make_raw(raw, 2)
    items = [(csv, stamp_for(csv, CODE)) for csv in sorted(raw.glob("*.csv"))]
    alone = process_chunk(items, tmp_path / "alone")

    ahead_dir = tmp_path / "ahead"
    ahead = {csv.name: ingest_ahead(csv, ahead_dir) for csv, _stamp in items}
    derive_ahead(ahead["r001.csv"], ahead_dir)                  # r000 ingested ahead only
    assert "derived" not in ahead["r000.csv"] and ahead["r001.csv"]["derived"]["cpu_s"] > 0
    done = process_chunk(items, ahead_dir, ahead)

    assert [r["status"] for r in alone + done] == ["ok"] * 4
    assert done[1]["timing_s"]["derive"] == ahead["r001.csv"]["derived"]["wall_s"]
    assert _outputs(tmp_path / "alone") == _outputs(ahead_dir)
    for run in ("r000", "r001"):
        assert (ahead_dir / run / "stamp.json").read_bytes() == (tmp_path / "alone" / run / "stamp.json").read_bytes()


def test_a_derive_that_fails_ahead_is_done_again_by_the_worker_which_reports_it(tmp_path):
    raw = tmp_path / "raw"
    make_raw(raw, 1)
    csv = raw / "r000.csv"
    processed = tmp_path / "processed"
    info = ingest_ahead(csv, processed)
    shutil.copy(processed / "r000" / "rig.json", tmp_path / "rig.json")
    (processed / "r000" / "signals.parquet").write_bytes(b"torn")
    derive_ahead(info, processed)
    assert "derived" not in info
    [result] = process_chunk([(csv, stamp_for(csv, CODE))], processed, {csv.name: info})
    assert result["status"] == "failed" and result["error"].startswith("derive: ")
    assert "signals.parquet" in result["error"]


def test_the_workers_shared_folder_is_removed_after_and_optional(monkeypatch):
    import tempfile

    from pipeline.run.runner import _shared_folder

    with _shared_folder() as folder:
        (folder / "background.rgba").write_bytes(b"x")
    assert not folder.exists()

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(tempfile, "mkdtemp", full)
    with _shared_folder() as folder:                      # the workers then draw their own backgrounds
        assert folder is None
