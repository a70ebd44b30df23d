"""Adaptive-R EKFs on a x4 DVL-noise step (issue 40 must-hold): each filter's per-segment NIS returns within
20 % of its expectation (3, the DVL's dimension) within the time docs/filters.md states.

Scenario: embedded track 5 (400 s), synthetic DVL with ``noise_schedule=step:0=1,200=4``, 16 runs. The NIS
of each DVL update from the filter's own innovation and S; its mean over the runs in 10-s segments.
Measured (4 x 32 runs and these 16): the segment means stay within 20 % of 3 from +20-30 s (``iae-ekf``),
+60-70 s (``vb-ekf``) and +70-150 s (``sh-ekf``) after the step on; the documented times (``BACK_S``)
are the largest measured plus one segment. Before the step the mean NIS is 3.07-3.20 (iae, sh) and
2.85-2.92 (vb).
"""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import Spec, validate

T_STEP, SEG = 200.0, 10.0
#: seconds after the step from which the segment-mean NIS stays within 20 % of 3 (docs/filters.md)
BACK_S = {"iae-ekf": 40.0, "vb-ekf": 80.0, "sh-ekf": 160.0}


@pytest.fixture(scope="module")
def segments():
    import os

    os.environ.pop("NESPM_DATA_DIR", None)
    spec = validate(Spec(tracks=(5,), runs=16, filters=tuple(BACK_S), dvl="synthetic",
                         sensor_options=(("dvl", "noise_schedule", "step:0=1,200=4"),)))
    res = simulate(spec, 5, np.arange(16))[0]
    out = {}
    for name in BACK_S:
        rec = res[name][0].sensors["dvl"]
        used = rec.used
        S = np.where(used[..., None, None], rec.S, np.eye(3))
        nu = np.where(used[..., None], rec.nu, 0.0)
        nis = np.where(used, np.einsum("rki,rki->rk", nu, np.linalg.solve(S, nu[..., None])[..., 0]), np.nan)
        starts = np.arange(0.0, rec.t[-1] - SEG + 1e-9, SEG)
        out[name] = (starts, np.array([np.nanmean(nis[:, (rec.t >= a) & (rec.t < a + SEG)]) for a in starts]))
    return out


@pytest.mark.parametrize("name", list(BACK_S))
def test_nis_returns_within_the_documented_time(segments, name):
    starts, mean = segments[name]
    after = starts >= T_STEP + BACK_S[name]
    assert after.sum() >= 4
    assert (np.abs(mean[after] / 3.0 - 1.0) <= 0.2).all(), (name, np.round(mean, 2))
    assert mean[starts == T_STEP][0] > 1.2 * 3.0  # the step is seen: the first segment after it is off
    before = (starts >= 100.0) & (starts < T_STEP)
    assert (np.abs(mean[before] / 3.0 - 1.0) <= 0.2).all(), (name, np.round(mean, 2))
