"""A 15-state study with depth and fixes read end to end: the Run line names the layout and the sensors, the
report prints vertical RMS, CEP and every sensor's NIS consistency, the RTS floor stands in its own row, and
metrics.parquet holds the posterior sums the verdict uses (the t = 0 rule)."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.reports.stats import paired_improvement, posterior_view


@pytest.fixture(scope="module")
def study(tmp_path_factory, short_data_dir):
    out = tmp_path_factory.mktemp("s15") / "f"
    rc, _, err = nespm("mc", "--data-dir", short_data_dir, "--tracks", "5", "--runs", "3", "--state", "15",
                       "--sensors", "dvl,depth,fix", "--filters", "ekf", "--smooth", "ekf", "--no-progress",
                       "--out", out)
    assert rc == 0, err
    rc, _, err = nespm("report", out, "--n-boot", "100")
    assert rc == 0, err
    return out, (out / "report.md").read_text(encoding="utf-8")


def test_posterior_sums_leave_out_t0(study):
    out, _ = study
    m = pd.read_parquet(out / "metrics.parquet")
    ep = pd.read_parquet(out / "epochs.parquet")
    assert (m["n_post"] == m["n_samples"] - 1).all()
    assert (m["sse_vel_post"] <= m["sse_vel"]).all() and (m["sse_hpe_post"] <= m["sse_hpe"]).all()
    # what the posterior leaves out is the first epoch's squared error: its mean over the runs is the epoch
    # table's mean velocity error at epoch 0 (the error norm of each run, squared)
    first = m["sse_vel"] - m["sse_vel_post"]
    e0 = ep[(ep["filter"] == "ekf") & (ep["epoch"] == 0)]
    assert np.sqrt(first[m["filter"] == "ekf"]).mean() == pytest.approx(float(e0["vel_err_mean"].iloc[0]), rel=1e-9)
    # the floor's improvement over every epoch and after t = 0 differ: the rule matters
    papers = paired_improvement(m, "ekf", "ekf-rts")["vrmse"]
    post = paired_improvement(posterior_view(m), "ekf", "ekf-rts")["vrmse"]
    assert np.isfinite(papers) and np.isfinite(post) and papers != post


def test_the_report_of_a_15_state_study(study):
    _, text = study
    run = next(line for line in text.splitlines() if line.startswith("**Run:**"))
    assert "error state 15" in run and "sensors dvl (recorded), depth (synthetic), fix (synthetic)" in run
    assert "Errors are posterior" in text  # the t = 0 rule: the main tables too, said in their caption
    assert "as everywhere in this report, is over the epochs after t = 0" in text
    main = text.split("## Track-averaged results")[1].split("\n## ")[0]
    floor = next(line for line in main.splitlines() if line.startswith("| ekf-rts (RTS smoother floor) |"))
    assert [c.strip() for c in floor.split("|")[1:-1]][2:4] == ["—", "—"]  # its value, no "Imprv."
    horiz = text.split("## Horizontal position error")[1].split("\n## ")[0]
    assert "vertical RMS [m]" in horiz and "CEP50 [m]" in horiz
    cons = text.split("## Consistency per block and sensor")[1].split("\n## ")[0]
    for item in ("| ekf | position | ANEES |", "| ekf | dvl NIS | ANIS |", "| ekf | depth NIS | ANIS |",
                 "| ekf | fix NIS | ANIS |"):
        assert item in cons, item
    verdict = text.split("## Verdict")[1].split("\n## ")[0]
    assert "| consistency (worst block or sensor" in verdict and "lost: best, runner-up" in verdict
    assert "## Every run counted" not in text  # no run lost


def test_consistent_share_is_checked(study):
    out, _ = study
    assert_one_error_line(*nespm("report", out, "--consistent-share", "0"), "--consistent-share")
