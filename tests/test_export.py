"""``nespm export``: a finished folder's tables as CSV or a MATLAB .mat, with the same numbers."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.io import loadmat

from conftest import assert_one_error_line, nespm


@pytest.fixture(scope="module")
def folder(tmp_path_factory, short_data_dir) -> Path:
    out = tmp_path_factory.mktemp("export") / "mc"
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "--runs", "3", "--filters",
                       "ins,ekf", "--out", str(out), "--no-progress", "--jobs", "1")
    assert rc == 0, err
    return out


def test_csv_holds_the_parquet_numbers_bit_for_bit(folder, tmp_path):
    rc, out, err = nespm("export", str(folder), "--out", str(tmp_path / "csv"), "--series")
    assert rc == 0, err
    for name in ("metrics", "epochs"):
        a = pd.read_parquet(folder / f"{name}.parquet")
        b = pd.read_csv(tmp_path / "csv" / f"{name}.csv")
        assert list(a.columns) == list(b.columns) and len(a) == len(b)
        for c in a.columns:
            if pd.api.types.is_float_dtype(a[c]):
                np.testing.assert_array_equal(a[c].to_numpy(), b[c].to_numpy(float))  # %.17g: exact
    s = pd.read_csv(tmp_path / "csv" / "series.csv")
    assert len(s) == 3 * len(pd.read_parquet(folder / "epochs.parquet"))  # (filter, epoch) rows x 3 runs


def test_mat_loads_with_the_same_numbers(folder, tmp_path):
    rc, out, err = nespm("export", str(folder), "--format", "mat", "--out", str(tmp_path))
    assert rc == 0, err
    m = loadmat(tmp_path / "mc.mat", squeeze_me=True, struct_as_record=False)
    a = pd.read_parquet(folder / "metrics.parquet")
    np.testing.assert_array_equal(m["metrics"].vrmse, a["vrmse"].to_numpy())
    assert list(m["metrics"].filter) == a["filter"].tolist()
    np.testing.assert_array_equal(m["epochs"].vel_err_mean, pd.read_parquet(folder / "epochs.parquet")["vel_err_mean"])


def test_export_refusals_are_one_line(folder, tmp_path):
    assert_one_error_line(*nespm("export", str(tmp_path / "nothing")), "no metrics.parquet")
    assert_one_error_line(*nespm("export", str(folder), "--format", "xlsx", "--out", str(tmp_path / "x")), "--format")
    rc, _, err = nespm("export", str(folder), "--out", str(tmp_path / "y"))
    assert rc == 0, err
    assert_one_error_line(*nespm("export", str(folder), "--out", str(tmp_path / "y")), "exists", "--overwrite")
    assert nespm("export", str(folder), "--out", str(tmp_path / "y"), "--overwrite")[0] == 0
