"""examples/example_bag.py and examples/example-bag.toml: the README's ``nespm import`` line from a fresh clone.

The script writes a ROS 1 bag from embedded track 1, ``nespm import`` reads it with the example spec, and
``nespm mc`` runs on the imported track with its recorded depth and fixes; the imported GT equals the
embedded track's over the written span.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, nespm

from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.tracks import load_track

pytest.importorskip("rosbags")

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

SCRIPT = REPO / "examples" / "example_bag.py"
SPEC = REPO / "examples" / "example-bag.toml"


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """The README sequence: the script (as a user runs it), then ``nespm import`` in-process."""
    root = tmp_path_factory.mktemp("example-bag")
    bag, data = root / "ex.bag", root / "bag-tracks"
    run = subprocess.run([sys.executable, str(SCRIPT), str(bag)], capture_output=True, text=True, cwd=REPO,
                         timeout=300)
    assert run.returncode == 0, (run.stdout, run.stderr)
    rc, so, se = nespm("import", bag, "--spec", SPEC, "--out", data)
    assert rc == 0, (so, se)
    return bag, data, so, se


def test_import_runs_and_writes_track_1(imported):
    bag, data, so, se = imported
    assert "track 1 from" in so and "warning" not in se, (so, se)
    assert (data / "Trajectory1" / "GT_trajectory1.csv").exists()
    assert tomllib.loads(SPEC.read_text())["track"] == 1


def test_spec_matches_the_script():
    """The spec's origin and hydrostatic constants are the ones the script wrote the bag with."""
    ns: dict = {"__name__": "example_bag"}
    exec(compile(SCRIPT.read_text(), str(SCRIPT), "exec"), ns)  # its constants, without running main
    spec = tomllib.loads(SPEC.read_text())
    o = spec["origin"]
    assert (o["lat_deg"], o["lon_deg"], o["alt_m"]) == ns["ORIGIN_DEG"]
    d = spec["depth"]
    assert (d["density"], d["atmospheric"], d["gravity"]) == (ns["RHO"], ns["P_ATM"], ns["G"])
    assert len(SCRIPT.read_text().splitlines()) <= 200


def test_imported_gt_equals_the_embedded_track(imported):
    _, data, _, _ = imported
    tr = load_track(1, data, warnings="error")
    src = embedded_track(1)
    n = len(tr.t)
    assert 60 <= tr.t[-1] <= 120 and n > 50
    assert np.abs(tr.t - src.t[:n]).max() <= 1e-9  # stamps are the times rounded to ns
    assert np.abs(tr.pos[:, :2] - src.pos[:n, :2]).max() <= 1e-9  # [rad]
    assert np.abs(tr.pos[:, 2] - src.pos[:n, 2]).max() <= 1e-9  # [m]
    assert np.abs(tr.v_n - src.v_n[:n]).max() <= 1e-9
    d_euler = (tr.euler - src.euler[:n] + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(d_euler).max() <= 1e-9
    assert np.abs(tr.dvl - src.dvl[:n]).max() <= 1e-9
    t_d, z_d = tr.channels["depth"]
    assert np.abs(t_d - src.t[:n]).max() <= 1e-9 and np.abs(z_d[:, 0] + src.pos[:n, 2]).max() <= 1e-9
    assert tr.imu is not None and tr.imu[0, 0] <= tr.t[0] and tr.imu[-1, 0] >= tr.t[-1]


def test_mc_runs_on_the_imported_track(imported, tmp_path, monkeypatch):
    _, data, _, _ = imported
    monkeypatch.setenv("NESPM_DATA_DIR", "")
    rc, so, se = nespm("mc", "--data-dir", data, "--tracks", 1, "--runs", 2, "--filters", "ekf", "--state", "15",
                       "--sensors", "dvl,depth,fix", "--sensor-option", "depth.source=recorded",
                       "--sensor-option", "fix.source=recorded", "--out", tmp_path / "bag-mc", "--no-progress")
    assert rc == 0, (so, se)
    assert (tmp_path / "bag-mc" / "metrics.parquet").exists()
