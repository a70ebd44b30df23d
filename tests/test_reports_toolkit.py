"""The reports toolkit (nespm_cli.reports.stats / markdown / results / dispatch): one function per
equation, one resampler for every bootstrap."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nespm_cli.experiments import metrics as eqs
from nespm_cli.reports import stats
from nespm_cli.reports.dispatch import experiment_of
from nespm_cli.reports.markdown import md_table


def test_rmse_is_eq50_of_experiments_metrics() -> None:
    sse = np.array([3.0, 5.0, 7.0])
    n = np.array([10.0, 20.0, 30.0])
    assert stats.rmse(sse, n) == eqs.rmse(sse, n) == pytest.approx(math.sqrt(15 / 60))
    assert math.isnan(stats.rmse([], []))
    counts = np.array([[3.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 2.0, 1.0]])
    got = stats.rmse(sse, n, counts)
    want = [eqs.rmse(np.repeat(sse, c.astype(int)), np.repeat(n, c.astype(int))) for c in counts]
    np.testing.assert_allclose(got, want, rtol=1e-15)


def test_track_average_eq51_scalar_and_replicates() -> None:
    assert stats.track_average([3.0, 4.0]) == pytest.approx(math.sqrt(12.5))
    assert isinstance(stats.track_average([3.0, 4.0]), float)
    assert math.isnan(stats.track_average([]))
    reps = stats.track_average([np.array([3.0, 1.0]), np.array([4.0, 1.0])])
    np.testing.assert_allclose(reps, [math.sqrt(12.5), 1.0])


def test_resample_counts_is_indexing_with_replacement() -> None:
    counts = stats.resample_counts(7, 50, np.random.default_rng(3))
    idx = np.random.default_rng(3).integers(0, 7, size=(50, 7))
    assert counts.shape == (50, 7) and np.all(counts.sum(axis=1) == 7)
    for c, i in zip(counts, idx):
        np.testing.assert_array_equal(c, np.bincount(i, minlength=7))


def test_percentile_ci_nan_unless_finite_and_per_column() -> None:
    reps = np.arange(101, dtype=float)
    assert stats.percentile_ci(reps) == (2.5, 97.5)
    assert all(math.isnan(v) for v in stats.percentile_ci(np.array([1.0, np.nan])))
    lo, hi = stats.percentile_ci(np.c_[reps, reps * 2, np.r_[reps[:-1], np.inf]], axis=0)
    np.testing.assert_allclose(lo[:2], [2.5, 5.0])
    np.testing.assert_allclose(hi[:2], [97.5, 195.0])
    assert math.isnan(lo[2]) and math.isnan(hi[2])


def test_nees_check_words() -> None:
    lo, hi = eqs.nees_band(6, 20)
    assert stats.nees_check(6.0, 20) == (lo, hi, "consistent")
    assert stats.nees_check(hi + 1, 20)[2] == "overconfident"
    assert stats.nees_check(lo - 1, 20)[2] == "conservative"
    assert stats.nees_check(math.nan, 20)[2] == "—"


def test_improvement_and_wilson() -> None:
    assert stats.improvement(0.1172, 0.0922) == pytest.approx(21.33, abs=0.01)
    assert stats.wilson_interval(0, 10)[0] == 0.0 and stats.wilson_interval(10, 10)[1] == 1.0
    assert all(math.isnan(v) for v in stats.wilson_interval(0, 0))


def test_md_table() -> None:
    assert md_table(["a", "b"], [[1, 2]]) == "| a | b |\n| --- | --- |\n| 1 | 2 |"


def test_experiment_of(tmp_path: Path) -> None:
    pd.DataFrame({"param": ["x"], "value": [1.0]}).to_parquet(tmp_path / "metrics.parquet")
    assert experiment_of(tmp_path) == "sweep"
    (tmp_path / "manifest.json").write_text(json.dumps({"experiment": "gp-ukf"}))
    assert experiment_of(tmp_path) == "gp-ukf"
    assert experiment_of(tmp_path / "missing") == "mc"
