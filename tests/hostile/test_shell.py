"""The command's shell under hostile use: folders nested in each other, closed output streams, signals,
a ``--cluster`` that is not a dask scheduler, and the network."""

from __future__ import annotations

import pytest

from pipeline.errors import PdrError
from pipeline.run import run_pipeline
from tests.hostile.folders import CODE, good_csv, snapshot


@pytest.mark.parametrize("inside", [".", "out", "a/b", "./out/../out2"])
def test_an_output_folder_in_the_raw_folder_is_refused_and_nothing_is_written(tmp_path, inside):
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "good0.csv").write_bytes(good_csv(0))
    before = snapshot(raw)
    with pytest.raises(PdrError, match="the output folder (is the raw folder|is inside the raw folder)") as err:
        run_pipeline(raw, raw / inside, jobs=1, code=CODE)
    assert "\n" not in str(err.value) and "--processed" in str(err.value)
    assert snapshot(raw) == before


def test_a_raw_folder_in_the_output_folder_is_refused(tmp_path):
    processed = tmp_path / "processed"
    raw = processed / "raw"
    raw.mkdir(parents=True)
    (raw / "good0.csv").write_bytes(good_csv(0))
    (tmp_path / "link").symlink_to(raw)             # the same folder through a link is seen through
    for given in (raw, tmp_path / "link"):
        with pytest.raises(PdrError, match="the raw folder is inside the output folder"):
            run_pipeline(given, processed, jobs=1, code=CODE)
    assert sorted(p.name for p in processed.iterdir()) == ["raw"]
