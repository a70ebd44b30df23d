"""``dvl_used`` is per run and epoch: a dropped DVL sample (``dvl.dropout``) is not used in that run
(engine.FilterOutput.dvl_used (R, N); the series chunks per run; epochs.parquet: in any run)."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from nespm_cli.experiments.spec import Spec

RUNS = 6
DROPOUT = ("dvl", "dropout", "0.3")


@pytest.fixture(autouse=True)
def embedded(monkeypatch):
    monkeypatch.delenv("NESPM_DATA_DIR", raising=False)


def spec() -> Spec:
    from nespm_cli.experiments.spec import validate

    return validate(Spec(tracks=(5,), runs=RUNS, dvl="synthetic", filters=("ekf",), window="0:60",
                         sensor_options=(DROPOUT,)))


def test_dvl_used_counts_the_applied_samples():
    from nespm_cli.experiments.mc import simulate

    res, truth, _ = simulate(spec(), 5, np.arange(RUNS))
    out = res["ekf"][0]
    used = out.sensors["dvl"].used  # (R, K): the DVL at the GT epochs, K = N
    N = len(truth.epoch_index)
    assert out.dvl_used.shape == (RUNS, N) and used.shape == (RUNS, N)
    np.testing.assert_array_equal(out.dvl_used, used)  # per run and epoch, exactly the applied samples
    offered = RUNS * (N - 1)
    share = out.dvl_used.sum() / offered
    print("dvl_used", int(out.dvl_used.sum()), "of", offered)
    # 30 % dropout: 4 binomial sigmas around 0.7 (the old per-epoch flag read 1.0 here)
    assert abs(share - 0.7) < 4 * np.sqrt(0.21 / offered)
    assert not out.dvl_used[:, 0].any()


def test_series_per_run_and_epochs_any_run(tmp_path):
    import nespm_cli.api as nespm
    from nespm_cli.experiments.mc import simulate

    out = tmp_path / "mc"
    nespm.run_mc(spec(), out, progress=False)
    series = pd.concat([pd.read_parquet(p) for p in sorted((out / "chunks").glob("series-*.parquet"))])
    res, _, _ = simulate(spec(), 5, np.arange(RUNS))
    used = res["ekf"][0].sensors["dvl"].used
    s = series.sort_values(["run", "epoch"])
    np.testing.assert_array_equal(s["dvl_used"].to_numpy().reshape(used.shape), used)
    e = pd.read_parquet(out / "epochs.parquet").sort_values("epoch")
    np.testing.assert_array_equal(e["dvl_used"].to_numpy(), used.any(axis=0))
