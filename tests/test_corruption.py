"""The dynamic schedule's IMU errors (nespm_cli.data.corruption.imu_errors), both bias modes.

The noise part is rebuilt from the documented streams, so the bias part is checked exactly.
"""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.data.corruption import (STREAM_ACC, STREAM_GYRO, CorruptionConfig, draw, imu_errors, segment_index,
                                  stream)
from nespm_cli.errors import NespmError

T = np.arange(0, 60.0 + 1e-9, 0.01)  # 60 s of 100 Hz samples: 3 segments of 20 s


@pytest.mark.parametrize("mode", ["run", "segment"])
def test_dynamic_bias_modes(mode):
    cfg = CorruptionConfig(schedule="dynamic", dynamic_bias=mode)
    real = draw(3, 5, np.arange(4), float(T[-1]), cfg)
    e_f, e_w = imu_errors(real, T)
    seg = segment_index(T[1:] - T[0], cfg.segment_s, real.acc_factors.shape[1])
    assert real.acc_factors.shape == (4, 3) and len(np.unique(seg)) == 3
    for i, r in enumerate(real.runs):
        n_f = stream(3, 5, int(r), STREAM_ACC).standard_normal((len(T) - 1, 3))
        n_w = stream(3, 5, int(r), STREAM_GYRO).standard_normal((len(T) - 1, 3))
        fa, fg = real.acc_factors[i, seg][:, None], real.gyro_factors[i, seg][:, None]
        bias_f = e_f[i] - fa * cfg.acc_noise * n_f
        bias_w = e_w[i] - fg * cfg.gyro_noise * n_w
        if mode == "run":  # held at the first segment's factor for the whole track
            want_f = np.broadcast_to(real.acc_factors[i, 0] * real.b_a[i], bias_f.shape)
            want_w = np.broadcast_to(real.gyro_factors[i, 0] * real.b_g[i], bias_w.shape)
        else:  # steps with every segment's factor
            want_f, want_w = fa * real.b_a[i], fg * real.b_g[i]
        # exact but for the rounding of one addition and one subtraction
        np.testing.assert_allclose(bias_f, want_f, rtol=0, atol=4 * np.finfo(float).eps * np.abs(e_f[i]).max())
        np.testing.assert_allclose(bias_w, want_w, rtol=0, atol=4 * np.finfo(float).eps * np.abs(e_w[i]).max())


def test_constant_schedule_ignores_the_bias_mode():
    a = imu_errors(draw(0, 5, np.arange(2), 60.0, CorruptionConfig(dynamic_bias="run")), T)
    b = imu_errors(draw(0, 5, np.arange(2), 60.0, CorruptionConfig(dynamic_bias="segment")), T)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_bad_bias_mode_is_an_error():
    with pytest.raises(NespmError, match="--dynamic-bias"):
        CorruptionConfig(dynamic_bias="sometimes")
