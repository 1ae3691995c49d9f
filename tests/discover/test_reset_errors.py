"""After a board reset the counter restarts wherever the pinion is: discovery fits that counter zero, and
every error it reports is of the model as fitted, the zero included (issue 31: ``mse_after.theta`` was
the square of the fitted zero)."""

from pipeline.derive.stage import derive_run
from pipeline.discover.stage import discover_run
from pipeline.ingest.stage import ingest_recording
from pipeline.rig.recording import RigSetup, make_recording, write_recording
from pipeline.rig.serial import Artefacts


def test_the_errors_after_a_reset_are_of_the_fitted_counter_zero(tmp_path):
    rec = make_recording(RigSetup(duration_s=30.0, artefacts=Artefacts(reset_after_s=10.0, reset_gap_s=2.0)), seed=3)
    zero = rec.truth_meta["segments"][1]["theta_ref_rad"]
    assert abs(zero) > 0.02                                        # the count restarted off the springs' rest
    write_recording(rec, tmp_path / "raw", "reset")
    _, after = ingest_recording(tmp_path / "raw" / "reset.csv", tmp_path / "processed").runs
    derive_run(after)
    d, doc = discover_run(after)
    assert doc["verdict"] == "none", doc["effects"]
    fitted = d.meas.x0(d.meas.spec(d.effects), d.selection.command_after).angle_offset
    assert abs(fitted + zero) < 0.1 * abs(zero)                    # the zero is fitted (counts from theta_ref) ...
    for errors in (doc["mse_before"], doc["mse_after"]):       # replay: the logged command, decided in the counter's frame
        assert errors["theta"] < 1e-4 * zero ** 2, errors          # ... and the errors are taken with it
