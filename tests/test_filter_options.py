"""Filter options (issue 25 item 4): --filter-option NAME.KEY=VALUE and [filters.NAME] tables, passed to
the filter, recorded in the manifest, part of the experiment's identity, sweepable; the API gives the
CLI's numbers."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from conftest import assert_one_error_line, cli
from nespm_cli.experiments.mc import run_mc
from nespm_cli.experiments.spec import Spec, validate

pytestmark = pytest.mark.usefixtures("no_env_data_dir")
PLUGIN = str(Path(__file__).resolve().parents[1] / "examples" / "ckf_filter.py")
BASE = ["--tracks", "1", "--runs", "3", "--no-progress", "--jobs", "1"]


def _vrmse(folder) -> dict:
    m = pd.read_parquet(Path(folder) / "metrics.parquet")
    return m.groupby("filter")["vrmse"].apply(list).to_dict()


def test_plugin_option_reaches_the_filter_and_the_manifest(tmp_path, capsys):
    out = {}
    for q in ("1", "4"):
        out[q] = tmp_path / f"q{q}"
        rc, _, err = cli(capsys, "mc", "--filter-plugin", PLUGIN, "--filters", "ekf,ckf-example",
                         "--filter-option", f"ckf-example.q_scale={q}", *BASE, "--out", out[q])
        assert rc == 0, err
    a, b = _vrmse(out["1"]), _vrmse(out["4"])
    assert a["ekf"] == b["ekf"]  # the other filter: untouched, bit for bit
    assert all(abs(x - y) > 1e-4 for x, y in zip(a["ckf-example"], b["ckf-example"]))  # Q x4 changes every run
    mf = json.loads((out["4"] / "manifest.json").read_text())
    assert mf["options"]["filter_options"] == [["ckf-example", "q_scale", 4.0]]
    # the default value gives the plugin's default numbers, and a changed value never resumes into a folder
    rc, _, err = cli(capsys, "mc", "--filter-plugin", PLUGIN, "--filters", "ekf,ckf-example",
                     "--filter-option", "ckf-example.q_scale=2", *BASE, "--out", out["4"])
    assert_one_error_line(rc, "", err, "filter ckf-example made with other --filter-option values")


def test_api_and_cli_give_the_same_numbers_and_a_config_table_the_same_as_the_flag(tmp_path, capsys):
    cfg = tmp_path / "study.toml"
    cfg.write_text('[filters.ukf]\nalpha = 0.5\n\n[filters.ukf-nespm]\n')  # the tables name the filters too
    rc, _, err = cli(capsys, "mc", "--config", cfg, *BASE, "--out", tmp_path / "c")
    assert rc == 0, err
    rc, _, err = cli(capsys, "mc", "--filters", "ukf,ukf-nespm", "--filter-option", "ukf.alpha=0.5", *BASE,
                     "--out", tmp_path / "f")
    assert rc == 0, err
    api = run_mc(validate(Spec(tracks=(1,), runs=3, filters=("ukf", "ukf-nespm"), data_dir=None,
                               filter_options=(("ukf", "alpha", "0.5"),))), tmp_path / "a", jobs=1, progress=False)
    cfg_m, flag_m = (pd.read_parquet(tmp_path / d / "metrics.parquet") for d in ("c", "f"))
    cols = ["vrmse", "mrmse", "nees", "hpe_rms"]
    pd.testing.assert_frame_equal(cfg_m[cols], flag_m[cols])
    pd.testing.assert_frame_equal(api[cols].reset_index(drop=True), flag_m[cols])
    # alpha for ukf alone: ukf-nespm keeps the default, ukf differs from its default-alpha numbers
    rc, _, err = cli(capsys, "mc", "--filters", "ukf,ukf-nespm", *BASE, "--out", tmp_path / "d")
    default = pd.read_parquet(tmp_path / "d" / "metrics.parquet")
    same = flag_m["filter"] == "ukf-nespm"
    pd.testing.assert_frame_equal(flag_m.loc[same, cols], default.loc[same, cols])
    assert (flag_m.loc[~same, "nees"].to_numpy() != default.loc[~same, "nees"].to_numpy()).all()


def test_sweep_over_a_plugin_option_equals_mc_with_that_value(tmp_path, capsys):
    rc, _, err = cli(capsys, "sweep", "--param", "ckf-example.q_scale", "--values", "1,4", "--filter-plugin", PLUGIN,
                     "--filters", "ckf-example", *BASE, "--out", tmp_path / "s")
    assert rc == 0, err
    rc, _, err = cli(capsys, "mc", "--filter-plugin", PLUGIN, "--filters", "ckf-example",
                     "--filter-option", "ckf-example.q_scale=4", *BASE, "--out", tmp_path / "m")
    assert rc == 0, err
    s = pd.read_parquet(tmp_path / "s" / "metrics.parquet")
    m = pd.read_parquet(tmp_path / "m" / "metrics.parquet")
    assert s.loc[s["value"] == 4.0, "vrmse"].tolist() == m["vrmse"].tolist()


@pytest.mark.parametrize("option, words", [
    ("ekf.alpha=0.5", "ekf takes no options"),
    ("ukf.alpha=abc", "expected a float"),
    ("ckf.alpha=0.1", "ckf is not in --filters"),
    ("ukf.gain=1", "ukf takes alpha, beta, kappa"),
    ("ukf-alpha", "expected NAME.KEY=VALUE"),
])
def test_bad_filter_options_in_one_line(tmp_path, capsys, option, words):
    rc, out, err = cli(capsys, "mc", "--filters", "ekf,ukf", "--filter-option", option, *BASE, "--out", tmp_path / "x")
    assert_one_error_line(rc, out, err, words)
    assert not (tmp_path / "x").exists()
