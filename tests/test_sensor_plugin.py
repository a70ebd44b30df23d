"""The sensor plugin example (examples/usbl_sensor.py), run as a user would from docs/sensors.md.

It imports only the public sensor API; ``mc --sensor-plugin`` runs it in two loky workers and on
a local Dask cluster with the same numbers bit for bit; its fixes are consistent (mean NIS within
the χ² band of 3 dof per fix) and the plugin's file is hashed into the manifest.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import chi2

from conftest import REPO, nespm
from nespm_cli.sensors.registry import get_sensor, load_plugin, sensor_names

USBL = REPO / "examples" / "usbl_sensor.py"
ARGS = ["--sensor-plugin", str(USBL), "--state", "15", "--sensors", "dvl,usbl", "--dvl", "synthetic",
        "--tracks", "5", "--runs", "4", "--chunk-size", "2", "--filters", "ekf,ukf", "--window", "0:120",
        "--no-progress"]

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


def test_usbl_example_uses_only_the_public_api():
    src = USBL.read_text()
    imports = sorted(ln.split()[1] for ln in src.splitlines() if ln.startswith(("from nespm_cli", "import nespm_cli")))
    assert imports == ["nespm_cli.sensors", "nespm_cli.sensors.fix"]
    load_plugin(USBL)
    assert "usbl" in sensor_names() and get_sensor("usbl").dim == 3


@pytest.fixture(scope="module")
def loky(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("usbl") / "loky"
    with pytest.MonkeyPatch.context() as mp:  # the embedded tracks, whatever the shell's $NESPM_DATA_DIR
        mp.delenv("NESPM_DATA_DIR", raising=False)
        rc, _, err = nespm("mc", *ARGS, "--jobs", "2", "--out", str(out))
    assert rc == 0, err
    return out


def test_usbl_runs_in_workers_and_is_consistent(loky):
    m = pd.read_parquet(loky / "metrics.parquet")
    assert len(m) == 8 and not m["diverged"].any()
    nis = m["nis_usbl"].to_numpy()
    k = 4 * 23  # fixes per filter: every 5 s over 120 s (t = 5 .. 115), 4 runs
    lo, hi = chi2.ppf(0.005, 3 * k) / k, chi2.ppf(0.995, 3 * k) / k
    for f, g in m.groupby("filter"):
        assert lo < g["nis_usbl"].mean() < hi, (f, g["nis_usbl"].mean(), lo, hi)
    assert np.isfinite(nis).all()
    manifest = json.loads((loky / "manifest.json").read_text())
    assert str(USBL.resolve()) in manifest["inputs"]
    assert list(manifest["sensors"]["all"]) == ["dvl", "usbl"]
    assert manifest["sensors"]["all"]["usbl"]["range_ppm"] == 10_000.0


def test_usbl_on_dask_gives_the_loky_numbers(loky, tmp_path):
    pytest.importorskip("distributed")
    out = tmp_path / "dask"
    rc, _, err = nespm("mc", *ARGS, "--jobs", "2", "--backend", "dask", "--out", str(out))
    assert rc == 0, err
    a, b = pd.read_parquet(loky / "metrics.parquet"), pd.read_parquet(out / "metrics.parquet")
    for col in ("vrmse", "hpe_rms", "nis_usbl", "nis_dvl"):
        assert np.array_equal(a[col].to_numpy(), b[col].to_numpy()), col
