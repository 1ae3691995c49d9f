"""`pdr validate` and `pdr view` as a user calls them."""

import json

from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.errors import PdrError
from tests.validate.synthetic import synthetic_run


def test_validate_command_writes_outputs_and_summary(tmp_path):
    processed = tmp_path / "processed"
    paths = synthetic_run(processed, "bench")
    model = tmp_path / "model.toml"
    model.write_text("[effects]\nviscous_friction = { b = 1e-4 }\n")
    result = CliRunner().invoke(app, ["validate", "bench", "--processed", str(processed), "--model", str(model),
                                      "--no-rrd", "--no-png"])
    assert result.exit_code == 0, result.output
    assert "bench: replay MSE theta" in result.output
    assert json.loads(paths.validation.read_text())["model"]["source"] == str(model)
    assert not paths.rrd.exists() and not paths.overview_png.exists()
    assert (processed / "summary.csv").read_text().splitlines()[1].startswith("bench,")


def test_unknown_run_and_missing_recording_are_refused(tmp_path):
    result = CliRunner().invoke(app, ["validate", "nothing", "--processed", str(tmp_path)])
    # several recordings may be given: each failure is one line, the exit status non-zero at the end
    assert result.exit_code == 2 and "pdr: error: nothing: expected a processed run folder" in result.output
    result = CliRunner().invoke(app, ["view", "nothing", "--processed", str(tmp_path)])
    assert isinstance(result.exception, PdrError)
    assert "nothing.rrd: no Rerun recording" in str(result.exception)
