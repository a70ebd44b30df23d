"""``nespm corrupt``: every corruption option of mc, the same draws as mc, no silent overwrite."""
from __future__ import annotations

import numpy as np
import pandas as pd

from conftest import nespm
from nespm_cli.data.corruption import CorruptionConfig, draw
from nespm_cli.data.embedded import embedded_track


def test_corrupt_takes_mc_corruption_options_and_matches_draw(tmp_path):
    out = tmp_path / "real"
    rc, stdout, stderr = nespm("corrupt", "--tracks", "5", "--runs", "4", "--seed", "3", "--misalignment-deg", "10",
                               "--heading-deg", "30", "--acc-bias", "0.1", "--vel-h-std", "0.5", "--out", out)
    assert rc == 0, stderr
    df = pd.read_parquet(out / "realizations.parquet")
    cfg = CorruptionConfig(misalignment_deg=10.0, heading_deg=30.0, acc_bias=0.1, vel_h_std=0.5)
    real = draw(3, 5, np.arange(4), embedded_track(5).duration, cfg)  # what mc --misalignment-deg 10 ... draws for track 5
    np.testing.assert_array_equal(df["dpsi0_x"].to_numpy(), real.dpsi0[:, 0])
    np.testing.assert_array_equal(df["dpsi0_z"].to_numpy(), real.dpsi0[:, 2])
    np.testing.assert_array_equal(df["ba_x"].to_numpy(), real.b_a[:, 0])
    np.testing.assert_array_equal(df["dv0_n"].to_numpy(), real.dv0[:, 0])
    # 10 deg per axis, 30 deg heading: the drawn angles are of that size (4 draws: within 4 sigma)
    assert np.all(np.abs(np.degrees(df["dpsi0_x"])) < 40) and np.abs(np.degrees(df["dpsi0_z"])).max() > 1


def test_corrupt_same_options_is_a_no_op_and_other_options_are_refused(tmp_path):
    out = tmp_path / "real"
    args = ["corrupt", "--tracks", "5", "--runs", "2", "--seed", "1", "--out", out]
    assert nespm(*args)[0] == 0
    before = (out / "realizations.parquet").read_bytes()
    mtime = (out / "realizations.parquet").stat().st_mtime_ns
    rc, stdout, stderr = nespm(*args)
    assert rc == 0 and "already holds these realizations" in stdout
    assert (out / "realizations.parquet").stat().st_mtime_ns == mtime
    rc, stdout, stderr = nespm(*args, "--acc-noise", "0.06")
    assert rc == 2
    line = stderr.strip()
    assert len(line.splitlines()) == 1 and "already holds realizations" in line and "corruption" in line
    assert (out / "realizations.parquet").read_bytes() == before


def test_corrupt_refuses_a_folder_with_unknown_realizations(tmp_path):
    out = tmp_path / "real"
    out.mkdir()
    (out / "realizations.parquet").write_bytes(b"not ours")
    rc, _, stderr = nespm("corrupt", "--tracks", "5", "--runs", "2", "--out", out)
    assert rc == 2 and "no readable realizations.json" in stderr
    assert (out / "realizations.parquet").read_bytes() == b"not ours"
