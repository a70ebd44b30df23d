"""``nespm tune``'s trials build their realizations once (``simulate(reuse=...)``): the scores are
bit-identical to building them per trial, for every trial and filter kind (a property of the code,
so exact equality)."""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.tuning.objective import trial_statistics


@pytest.mark.parametrize("name", ["ekf", "ukf-nespm", "sh-ekf"])
def test_reused_inputs_are_bit_identical(name):
    spec = validate(Spec(tracks=(5, 6), runs=3, filters=(name,), dvl="synthetic", window="0:40"))
    reuse: dict = {}
    for v in ({"acc_noise_scale": 2.0}, {"r_scale_dvl": 0.5}, {"acc_noise_scale": 2.0}):
        a = trial_statistics(spec, name, v)
        b = trial_statistics(spec, name, v, reuse)
        assert a["rmse"] == b["rmse"] and a["anees6_tracks"] == b["anees6_tracks"]
        for k in a["anees"]:
            assert np.array_equal(a["anees"][k], b["anees"][k], equal_nan=True)
        for k in a["anis"]:
            assert np.array_equal(a["anis"][k], b["anis"][k], equal_nan=True)
    assert len(reuse) == 2  # one entry per track, built on the first trial
