"""The t = 0 rule (docs/report.md): every summary of the reports is over the GT epochs after t = 0; the
papers' every-epoch values stand only beside the published numbers. Each summary is computed here by
hand from the per-run sums (or the per-epoch table) with and without epoch 0: the two differ, and the
report and the tables show the one without."""
from __future__ import annotations

import math

import pandas as pd
import pytest

from nespm_cli.experiments.spec import Spec


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Track 5, 60 s, 6 runs, EKF and UKF on the synthetic DVL (the bound is known)."""
    import nespm_cli.api as nespm

    out = tmp_path_factory.mktemp("t0") / "mc"
    nespm.run_mc(Spec(tracks=(5,), runs=6, dvl="synthetic", filters=("ekf", "ukf"), window="0:60"), out,
                 progress=False)
    return out


def by_hand(m: pd.DataFrame, f: str, sse: str, n: str) -> float:
    """Eq 50 of filter ``f`` over its runs: sqrt(sum(sse) / sum(n))."""
    d = m[m["filter"] == f]
    return math.sqrt(d[sse].sum() / d[n].sum())


def test_tables_are_over_the_epochs_after_t0(folder):
    from nespm_cli.reports.tables import filter_table, horizontal_table, track_table

    m = pd.read_parquet(folder / "metrics.parquet")
    for f in ("ekf", "ukf"):
        post, every = by_hand(m, f, "sse_vel_post", "n_post"), by_hand(m, f, "sse_vel", "n_samples")
        assert abs(post / every - 1) > 0.01  # the initial error moves the summary
        tt = track_table(m).set_index("filter")
        assert tt.loc[f, "vrmse"] == pytest.approx(post, rel=1e-12)
        assert tt.loc[f, "mrmse"] == pytest.approx(by_hand(m, f, "sse_att_post", "n_post"), rel=1e-12)
        assert filter_table(m, "ukf", n_boot=0).set_index("filter").loc[f, "vrmse"] == pytest.approx(post, rel=1e-12)
        papers = filter_table(m, "ukf", n_boot=0, with_t0=True).set_index("filter")
        assert papers.loc[f, "vrmse"] == pytest.approx(every, rel=1e-12)  # the published tables' definition
        ht = horizontal_table(m)
        row = ht[(ht["filter"] == f) & ht["track"].isna()].iloc[0]
        assert row["hpe_rms"] == pytest.approx(by_hand(m, f, "sse_hpe_post", "n_post"), rel=1e-12)


def test_the_report_shows_the_summary_without_t0(folder):
    from nespm_cli.reports.markdown import fmt
    from nespm_cli.reports.mc import write_mc_report

    m = pd.read_parquet(folder / "metrics.parquet")
    text = write_mc_report(folder, n_boot=50).read_text()
    main = text.split("## Track-averaged results")[1].split("\n## ")[0]
    row = next(line for line in main.splitlines() if line.startswith("| ekf |"))
    cells = [c.strip() for c in row.split("|")[1:-1]]
    post, every = by_hand(m, "ekf", "sse_vel_post", "n_post"), by_hand(m, "ekf", "sse_vel", "n_samples")
    assert fmt(post) != fmt(every)
    assert cells[1] == fmt(post)
    per_track = text.split("## Per-track results")[1].split("\n## ")[0]
    assert f"| 5 | ekf | {fmt(post)} |" in per_track


def test_compare_and_sweep_tables_follow_the_rule(folder):
    from nespm_cli.reports.cases import case_table, load_cases
    from nespm_cli.reports.sweep_tables import sweep_table

    m = pd.read_parquet(folder / "metrics.parquet")
    post = by_hand(m, "ekf", "sse_vel_post", "n_post")
    cases = case_table(load_cases([folder, folder], ["a", "b"]))
    row = cases[(cases["case"] == "a") & (cases["filter"] == "ekf")].iloc[0]
    assert row["vrmse"] == pytest.approx(post, rel=1e-12)
    assert row["hpe_rms"] == pytest.approx(by_hand(m, "ekf", "sse_hpe_post", "n_post"), rel=1e-12)
    sweep = pd.concat([m.assign(param="acc_noise_scale", value=v) for v in (1.0, 2.0)], ignore_index=True)
    st = sweep_table(sweep, n_boot=20)
    got = st[(st["filter"] == "ekf") & (st["value"] == 2.0)].iloc[0]
    assert got["vrmse"] == pytest.approx(post, rel=1e-12)
    assert got["vrmse_lo"] <= got["vrmse"] <= got["vrmse_hi"]


def test_efficiency_leaves_out_epoch_0(folder):
    from nespm_cli.experiments.pcrb_table import efficiency

    e = pd.read_parquet(folder / "epochs.parquet")
    g = e[e["filter"] == "ekf"].sort_values("epoch")
    ms = (g["vel_err_mean"] ** 2 + g["vel_err_std"] ** 2).to_numpy()
    pb = (g["pcrb_dvN"] + g["pcrb_dvE"] + g["pcrb_dvD"]).to_numpy()
    after, every = math.sqrt(ms[1:].mean() / pb[1:].mean()), math.sqrt(ms.mean() / pb.mean())
    assert abs(after / every - 1) > 0.02  # epoch 0 holds the prior: a large share of the bound's mean
    vel = efficiency(e).set_index(["filter", "block"]).loc[("ekf", "vel")]
    assert vel["efficiency"] == pytest.approx(after, rel=1e-12) and vel["window"] == "t > 0"
    assert vel["epochs"] == len(g) - 1
    # the frame without epoch 0 gives the same number: nothing of epoch 0 is in it
    again = efficiency(e[e["epoch"] > 0]).set_index(["filter", "block"])
    assert again.loc[("ekf", "vel"), "efficiency"] == pytest.approx(after, rel=1e-12)


def test_mean_nees_and_vertical_rms_leave_out_epoch_0(folder):
    """The mean NEES and the vertical RMS: each run's twin over the epochs after t = 0 (``nees_post``,
    ``vert_rms_post``) is what the tables, the verdict and compare show; the every-epoch columns differ."""
    from nespm_cli.reports.cases import case_table, load_cases
    from nespm_cli.reports.tables import filter_table, track_table

    m = pd.read_parquet(folder / "metrics.parquet")
    e = pd.read_parquet(folder / "epochs.parquet")
    for f in ("ekf", "ukf"):
        d = m[m["filter"] == f]
        post, every = float(d["nees_post"].mean()), float(d["nees"].mean())
        assert abs(post / every - 1) > 1e-3  # epoch 0 moves the mean
        g = e[e["filter"] == f].sort_values("epoch")
        assert post == pytest.approx(g["nees_mean"].to_numpy()[1:].mean(), rel=1e-9)  # by hand: epochs > 0
        assert track_table(m).set_index("filter").loc[f, "nees"] == pytest.approx(post, rel=1e-12)
        assert filter_table(m, "ukf", n_boot=0).set_index("filter").loc[f, "nees"] == pytest.approx(post, rel=1e-12)
        assert filter_table(m, "ukf", n_boot=0, with_t0=True).set_index("filter").loc[f, "nees"] == pytest.approx(
            every, rel=1e-12)  # beside a published table: every epoch
        vpost = math.sqrt((d["vert_rms_post"] ** 2).mean())
        vevery = math.sqrt((d["vert_rms"] ** 2).mean())
        assert abs(vpost / vevery - 1) > 1e-3
        cases = case_table(load_cases([folder, folder], ["a", "b"]))
        row = cases[cases["case"] == "a"].set_index("filter").loc[f]
        assert row["vert_rms"] == pytest.approx(vpost, rel=1e-12)


def test_the_report_shows_the_mean_nees_without_t0(folder):
    from nespm_cli.reports.markdown import fmt
    from nespm_cli.reports.mc import write_mc_report

    m = pd.read_parquet(folder / "metrics.parquet")
    text = write_mc_report(folder, n_boot=20).read_text()
    main = text.split("## Track-averaged results")[1].split("\n## ")[0]
    row = next(line for line in main.splitlines() if line.startswith("| ekf |"))
    cells = [c.strip() for c in row.split("|")[1:-1]]
    d = m[m["filter"] == "ekf"]
    assert cells[7] == fmt(float(d["nees_post"].mean()), ".2f")
    print("mean NEES after t = 0", d["nees_post"].mean(), "with t = 0", d["nees"].mean())
