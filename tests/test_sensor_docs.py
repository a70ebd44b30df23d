"""docs/sensors.md's complete minimal sensor (an LBL range), extracted from the page and run as a user
would: it loads, measures the range to a beacon placed by the track's origin (``TrackInfo``), runs in
``mc`` with consistent NIS, and the manifest records its dimension so reports need no plugin."""
from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest
from scipy.stats import chi2

from conftest import REPO, nespm

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

DOC = REPO / "docs" / "sensors.md"


def doc_plugin() -> str:
    """The first ``python`` block under "### A complete minimal sensor"."""
    text = DOC.read_text()
    section = text[text.index("### A complete minimal sensor"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    path = tmp_path_factory.mktemp("doc") / "lbl_range.py"
    path.write_text(doc_plugin())
    return path


def test_the_doc_plugin_measures_from_the_track_origin(plugin):
    from nespm_cli.experiments.spec import Spec, track_inputs, validate
    from nespm_cli.experiments.suite import sensor_suite
    from nespm_cli.filters import FilterConfig
    from nespm_cli.sensors.channels import track_info, truth_at

    spec = validate(Spec(tracks=(5,), runs=1, filters=("ekf",), sensors=("dvl", "lbl-range"),
                         sensor_plugins=(str(plugin),), filter_config=FilterConfig(state="15")))
    sensor = sensor_suite(spec)[1]
    track, truth = track_inputs(spec, 5)
    info = track_info(truth, 5)
    e0 = truth.epoch_index[0]
    assert info.start == float(track.t[0]) and np.array_equal(info.origin, truth.pos[e0])
    at0 = truth_at(truth, np.array([e0]), np.zeros(1), info)
    r0 = float(sensor.true_values(at0)[0, 0])
    # the beacon is (200, 100, 50) m NED from the origin: the range at t = 0 is its norm, to the
    # small-distance approximation of ned_offset about the beacon (N/E scales at a latitude 200 m off)
    expect = float(np.linalg.norm([200.0, 100.0, 50.0]))
    assert abs(r0 - expect) < 1e-4 * expect, r0


def test_the_doc_plugin_runs_consistently_and_records_its_dim(plugin, tmp_path):
    out = tmp_path / "lbl"
    args = ["mc", "--sensor-plugin", plugin, "--state", "15", "--sensors", "dvl,lbl-range", "--dvl", "synthetic",
            "--tracks", "5", "--runs", "4", "--window", "0:120", "--filters", "ekf,ukf", "--no-progress"]
    rc, _, err = nespm(*args, "--out", out)
    assert rc == 0, err
    m = pd.read_parquet(out / "metrics.parquet")
    # new sensor objects per chunk, the origin per track: 2-run chunks give the same numbers
    rc, _, err = nespm(*args, "--jobs", "1", "--chunk-size", "2", "--out", tmp_path / "split")
    assert rc == 0, err
    split = pd.read_parquet(tmp_path / "split" / "metrics.parquet")
    key = ["filter", "run"]
    a, b = m.sort_values(key).reset_index(drop=True), split.sort_values(key).reset_index(drop=True)
    assert np.array_equal(a["nis_lbl-range"].to_numpy(), b["nis_lbl-range"].to_numpy())
    assert not m["diverged"].any()
    k = 4 * 59  # ranges every 2 s over the 0-119 s window (t = 2 .. 118), 4 runs
    lo, hi = chi2.ppf(0.005, k) / k, chi2.ppf(0.995, k) / k
    for f, g in m.groupby("filter"):
        assert lo < g["nis_lbl-range"].mean() < hi, (f, g["nis_lbl-range"].mean(), lo, hi)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sensors"]["all"]["lbl-range"]["dim"] == 1
    assert manifest["sensors"]["all"]["dvl"]["dim"] == 3


def test_reports_read_a_sensors_dim_from_the_manifest_without_its_plugin():
    from nespm_cli.experiments.suite import recorded_dim
    from nespm_cli.reports.results import sensor_dims

    manifest = {"sensors": {"a": {"ghost": {"dim": 4}}, "b": {"ghost": {"dim": 4}, "other": {"dim": 2}}}}
    assert sensor_dims(manifest, ["ghost", "other"]) == {"ghost": 4, "other": 2}  # "ghost" is registered nowhere
    assert recorded_dim({"sensors": {"a": {"ghost": {"dim": 4}}, "b": {"ghost": {"dim": 2}}}}, "ghost") is None
    assert recorded_dim({"sensors": {"a": {"ghost": {}}}}, "ghost") is None
