"""Robust updates' counts in the results (issue 40 item 4): ``rejected_<sensor>``, ``applied_<sensor>``,
``downweighted_<sensor>`` per run (metrics.sensor_rejections) and the report's table
(reports/robust_counts.py). Track 5, 0-60 s, 8 runs, synthetic DVL with 5 % outliers of 10x its std."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from nespm_cli.experiments.spec import Spec
from nespm_cli.experiments.suite import sensor_suite

RUNS = 8
OUTLIERS = ("dvl", "outliers", "0.05:10")


@pytest.fixture(autouse=True)
def embedded(monkeypatch):
    monkeypatch.delenv("NESPM_DATA_DIR", raising=False)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    import os

    import nespm_cli.api as nespm

    os.environ.pop("NESPM_DATA_DIR", None)
    out = tmp_path_factory.mktemp("robust") / "mc"
    spec = Spec(tracks=(5,), runs=RUNS, dvl="synthetic", filters=("ekf", "ukf"), window="0:60",
                sensor_options=(OUTLIERS,), filter_options=(("ekf", "robust", "gate"),))
    nespm.run_mc(spec, out, progress=False)
    return out, spec


def test_rejected_counts_are_the_injected_outliers(folder):
    """Per run, the gate's rejected count is the injected outliers within its false-alarm rate (1 − gate_prob of
    the good samples, 4 binomial sigmas) and a miss or two. A run whose first offered sample is an outlier is left
    out: under P0 that outlier is undetectable and corrupts the run (filters/robust.py; measured with seed 0: run
    3, its outlier at 1 s accepted, then 6 good samples rejected)."""
    from nespm_cli.experiments.spec import validate

    out, spec = folder
    m = pd.read_parquet(out / "metrics.parquet")
    spec = validate(spec)
    dvl = next(s for s in sensor_suite(spec) if s.name == "dvl")
    e = pd.read_parquet(out / "epochs.parquet")
    t = np.sort(e[e["filter"] == "ekf"]["t"].to_numpy())  # the DVL at the GT epochs; t = 0 is never offered
    mask = dvl.outlier_draws(t, spec.seed, 5, np.arange(RUNS))[1][:, 1:]
    ekf = m[m["filter"] == "ekf"].sort_values("run")
    rejected, applied = ekf["rejected_dvl"].to_numpy(), ekf["applied_dvl"].to_numpy()
    np.testing.assert_array_equal(rejected + applied, mask.shape[1])  # every sample is rejected or applied
    keep = ~mask[:, 0]
    injected, good = int(mask[keep].sum()), int((~mask[keep]).sum())
    false_alarms = 0.001 * good + 4 * np.sqrt(0.001 * good)
    print("injected", injected, "rejected", int(rejected[keep].sum()), "good", good, "runs", int(keep.sum()))
    assert keep.sum() >= RUNS - 2 and injected >= 10
    assert injected - 2 <= rejected[keep].sum() <= injected + false_alarms
    other = m[m["filter"] == "ukf"]
    assert (other["rejected_dvl"] == 0).all() and (other["downweighted_dvl"] == 0).all()
    assert int(other["applied_dvl"].sum()) == mask.size  # the plain filter applies every sample


def test_the_report_table_shows_each_filters_counts(folder):
    from nespm_cli.reports.robust_counts import rejection_md, rejection_table

    out, _ = folder
    m = pd.read_parquet(out / "metrics.parquet")
    t = rejection_table(m).set_index("filter")
    assert t.loc["ekf", "rejected"] == m.loc[m["filter"] == "ekf", "rejected_dvl"].sum()
    assert t.loc["ukf", "rejected"] == 0
    text = rejection_md(m, json.loads((out / "manifest.json").read_text()))
    assert f"| ekf | dvl (outliers: 0.05:10) | {RUNS} | {t.loc['ekf', 'rejected']} | {t.loc['ekf', 'applied']} |" in text
    assert rejection_md(m.drop(columns=[c for c in m.columns if c.startswith(("rejected_", "applied_"))])) == ""
