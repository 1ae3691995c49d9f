"""The live view of a capture without an encoder column: no angle drawn (NaN), not an angle of 0."""

import numpy as np

from pipeline.config import resolve_config
from pipeline.record.decode import LineDecoder


def test_no_encoder_column_gives_no_angle_and_the_current(tmp_path):
    (tmp_path / "rig.toml").write_text('[columns]\ncounts = ""\n')
    samples = LineDecoder(resolve_config([tmp_path / "rig.toml"])).feed(
        [(0, b"t_ms,adc,dir\n0,512,0\n50,530,1\n100,540,1\n")])
    assert np.isnan(samples.theta_rad).all() and len(samples.theta_rad) == 3
    np.testing.assert_allclose(samples.current_a, (np.array([512, 530, 540]) * 5.0 / 1024 - 2.5) / 0.185)
    assert samples.dir.tolist() == [0, 1, 1]
