"""The Python API (nespm_cli.api, docs/api.md) gives the CLI's numbers for the same options."""
from __future__ import annotations

import json

import pandas as pd
import pytest

import nespm_cli.api as nespm
from conftest import cli

pytestmark = pytest.mark.usefixtures("no_env_data_dir")
COLS = ["track", "filter", "run", "vrmse", "mrmse", "nees", "hpe_rms", "nis_dvl", "diverged"]
#: The first 60 s of embedded track 1: the API and the CLI must agree on any window, and the
#: whole 400 s track only multiplies the cost (~6x).
WINDOW = "0:60"


@pytest.mark.parametrize("cli_args, spec_kw", [
    # the heading-only misalignment: the filter's P0 follows the corruption in validate, not in the CLI
    (["--heading-deg", "5", "--filters", "ekf,ukf"],
     dict(filters=("ekf", "ukf"), corruption=nespm.CorruptionConfig(heading_deg=5.0))),
    (["--state", "15", "--sensors", "dvl,depth,fix", "--sensor-option", "fix.interval=20", "--pos-h-std", "2",
      "--filters", "ekf", "--smooth", "ekf"],
     dict(filters=("ekf",), filter_config=nespm.FilterConfig(state="15"), sensors=("dvl", "depth", "fix"),
          sensor_options=(("fix", "interval", "20"),), corruption=nespm.CorruptionConfig(pos_h_std=2.0),
          smooth=("ekf",))),
])
def test_api_and_cli_give_identical_metrics(tmp_path, capsys, cli_args, spec_kw):
    rc, _, err = cli(capsys, "mc", "--tracks", "1", "--runs", "3", "--no-progress", "--jobs", "1", "--window", WINDOW,
                     *cli_args, "--out", tmp_path / "cli")
    assert rc == 0, err
    api = nespm.run_mc(nespm.Spec(tracks=(1,), runs=3, data_dir=None, window=WINDOW, **spec_kw), tmp_path / "api",
                       jobs=1, progress=False)
    from_cli = nespm.load(tmp_path / "cli")
    pd.testing.assert_frame_equal(api[COLS].reset_index(drop=True), from_cli.metrics[COLS])
    # the manifests hold the same experiment
    a = json.loads((tmp_path / "api" / "manifest.json").read_text())
    assert a["options"] == from_cli.manifest["options"]
    assert from_cli.epochs is not None and len(from_cli.epochs) > 0


def test_load_refuses_a_folder_without_results(tmp_path):
    with pytest.raises(nespm.NespmError, match="metrics.parquet"):
        nespm.load(tmp_path)


def test_report_tables_are_the_reports_numbers(tmp_path, capsys):
    rc, _, err = cli(capsys, "mc", "--tracks", "1", "--runs", "4", "--filters", "ekf,ukf", "--no-progress",
                     "--window", WINDOW, "--jobs", "1", "--out", tmp_path / "f")
    assert rc == 0, err
    rc, _, err = cli(capsys, "report", tmp_path / "f", "--n-boot", "200")
    assert rc == 0, err
    tables = nespm.report_tables(tmp_path / "f", n_boot=200)
    assert set(tables) == {"filters", "tracks", "horizontal", "verdict", "comparisons", "all_runs", "nees", "consistency",
                           "efficiency"}
    text = (tmp_path / "f" / "report.md").read_text()
    f = tables["filters"].set_index("filter")
    from nespm_cli.reports.markdown import fmt
    for name in ("ekf", "ukf"):  # the track-averaged VRMSE as the report prints it
        assert f"| {fmt(f.loc[name, 'vrmse'])} |" in text
    best = tables["verdict"].set_index("metric").loc["vrmse", "best"]
    assert f"`{best}`" in text.split("## Verdict")[1].split("## ")[0]
