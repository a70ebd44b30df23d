"""``nespm train`` and the adaptive filters through ``nespm mc`` / ``run`` / ``report``.

Cost: training is 2 realizations of one track for 1 epoch (a few seconds); the Monte Carlo
runs on 30 s cuts of embedded tracks written to a temporary data folder.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from nespm_cli.learn.noise_model import load_weights
from nespm_cli.data.tracks import write_akit

from conftest import assert_one_error_line, cli, short_track

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    d = tmp_path_factory.mktemp("train")
    out = d / "w.npz"
    from nespm_cli.cli import main

    rc = main(["train", "--tracks", "1", "--test-tracks", "5", "--runs", "2", "--epochs", "1", "--out", str(out),
               "--no-progress"])
    return rc, out


def test_train_writes_weights_plot_and_spearman(trained):
    rc, out = trained
    assert rc == 0
    assert out.is_file() and out.with_suffix(".png").is_file()
    acc, gyro, meta = load_weights(str(out))
    assert meta["config"]["train_tracks"] == [1] and meta["config"]["test_tracks"] == [5]
    assert meta["config"]["runs"] == 2
    for s in ("acc", "gyro"):
        assert -1.0 <= meta["test"][s]["spearman"] <= 1.0


def test_train_bad_input_is_one_line(capsys, tmp_path):
    assert_one_error_line(*cli(capsys, "train", "--tracks", "1", "--out", tmp_path / "w.txt"), "--out", ".npz")
    assert_one_error_line(*cli(capsys, "train", "--tracks", "99", "--out", tmp_path / "w.npz"), "--tracks", "99")
    assert not (tmp_path / "w.npz").exists()


@pytest.fixture(scope="module")
def short_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("short")
    write_akit(short_track(5, epochs=41), d)
    return d


def test_mc_runs_every_adaptive_filter_and_report_shows_the_papers_tables(capsys, short_dir, tmp_path):
    out = tmp_path / "mc"
    rc, so, err = cli(capsys, "mc", "--data-dir", short_dir, "--tracks", "5", "--runs", "3",
                      "--filters", "ukf,anekf,anukf,anukf-nespm", "--schedule", "dynamic", "--dvl", "synthetic",
                      "--no-progress", "--out", out)
    assert rc == 0, err
    m = pd.read_parquet(out / "metrics.parquet")
    assert sorted(m["filter"].unique()) == ["anekf", "anukf", "anukf-nespm", "ukf"]
    assert not m["diverged"].any()
    assert m.loc[m["filter"] == "ukf", "q_factor_acc"].isna().all()
    ad = m[m["filter"] != "ukf"]
    # the three adaptive filters share one network pass: identical factors per run
    f = ad.pivot(index="run", columns="filter", values="q_factor_acc")
    assert np.array_equal(f["anekf"].to_numpy(), f["anukf"].to_numpy())
    assert ((ad["q_factor_acc"] > 0.25) & (ad["q_factor_acc"] < 24)).all()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["options"]["weights"] is None  # the packaged default
    rc, so, err = cli(capsys, "report", out, "--n-boot", "50")
    assert rc == 0, err
    text = (out / "report.md").read_text()
    assert "**anukf.md Table I**" in text and "**ukf-nespm.md Table I**" in text
    assert "0.0922" in text and "0.073" in text


def test_run_with_own_weights_and_bad_weights(capsys, short_dir, trained, tmp_path):
    _, w = trained
    rc, so, err = cli(capsys, "run", "--data-dir", short_dir, "--track", "5", "--filter", "anukf",
                      "--weights", w, "--schedule", "dynamic", "--json")
    assert rc == 0, err
    summary = json.loads(so)
    assert summary["filter"] == "anukf" and np.isfinite(summary["vrmse"])
    assert_one_error_line(*cli(capsys, "mc", "--data-dir", short_dir, "--tracks", "5", "--runs", "1",
                               "--filters", "anukf", "--weights", tmp_path / "none.npz", "--out", tmp_path / "x"),
                          "--weights", "none.npz")
    assert not (tmp_path / "x").exists()
    assert_one_error_line(*cli(capsys, "mc", "--data-dir", short_dir, "--tracks", "5", "--runs", "1",
                               "--filters", "anukf", "--adaptive-bias", "both", "--out", tmp_path / "y"),
                          "--adaptive-bias")
    assert_one_error_line(*cli(capsys, "mc", "--data-dir", short_dir, "--tracks", "5", "--runs", "1",
                               "--filters", "anukf", "--tau-a", "-1", "--out", tmp_path / "z"), "--tau-a")
