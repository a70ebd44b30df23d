"""The numbers of the real-data job that guards every refactor.

``nespm mc --tracks 5 6 --runs 8 --seed 3 --filters ekf,ukf,ukf-nespm,anekf,anukf,anukf-nespm``
on the real Snapir tracks (synthesized IMU, recorded DVL, packaged ProcessNet weights) must
give the metrics recorded in ``tests/data/real-mc-tracks5-6-runs8-seed3.csv`` to 1e-12
relative. The file was first written by commit 2541d01; it was rewritten with issue 15 (the
compiled time loop), when the navigation cycle's products became BLAS-free elementwise sums
and the meridian radius lost its ``pow``: one-ulp changes that moved the EKF/UKF by <= 1e-13
relative, the adaptive EKF/UKF by <= 5e-10 and the NESPM filters by <= 2e-6 (sse_att; their
mean weighs round-off by ~4e4). ``--kernels numba`` and ``--kernels numpy`` give these numbers
to 2e-13. A change of these numbers must be explained in the commit that changes the file.
Costs about 10 s compiled (78 s with the NumPy reference) on 2 cores; skipped without the real data.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import nespm

REFERENCE = Path(__file__).parent / "data" / "real-mc-tracks5-6-runs8-seed3.csv"
COLUMNS = ["vrmse", "mrmse", "nees", "sse_vel", "sse_att", "max_vel_err", "max_att_err", "q_factor_acc",
           "q_factor_gyro"]


@pytest.mark.slow
def test_real_mc_metrics_unchanged(real_data_dir, tmp_path, no_env_data_dir):
    out = tmp_path / "real8"
    rc, _, stderr = nespm("mc", "--tracks", "5", "6", "--runs", "8", "--seed", "3", "--filters",
                          "ekf,ukf,ukf-nespm,anekf,anukf,anukf-nespm", "--data-dir", real_data_dir,
                          "--no-progress", "--out", out)
    assert rc == 0, stderr
    got = pd.read_parquet(out / "metrics.parquet").sort_values(["track", "filter", "run"]).reset_index(drop=True)
    ref = pd.read_csv(REFERENCE).sort_values(["track", "filter", "run"]).reset_index(drop=True)
    assert len(got) == len(ref) == 96
    pd.testing.assert_frame_equal(got[["track", "filter", "run"]], ref[["track", "filter", "run"]])
    assert not got["diverged"].any() and not ref["diverged"].any()
    for c in COLUMNS:
        a, b = got[c].to_numpy(float), ref[c].to_numpy(float)
        both_nan = np.isnan(a) & np.isnan(b)
        rel = np.abs(a - b) / np.maximum(np.abs(b), 1e-300)
        assert np.all(both_nan | (rel <= 1e-12)), (c, float(np.nanmax(rel)))
