"""Studies that grow (issue 25 item 5): more filters, a smoothed filter, or a new filter's options on a
finished folder compute only what is new; finished chunk files are never touched; a study never shrinks."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from conftest import assert_one_error_line, cli

pytestmark = pytest.mark.usefixtures("no_env_data_dir")
# the first 60 s of embedded track 1: what a growing study computes does not depend on the track's length
BASE = ["--tracks", "1", "--runs", "4", "--chunk-size", "2", "--no-progress", "--jobs", "1", "--window", "0:60"]


def _chunks(folder: Path) -> dict[str, tuple[int, bytes]]:
    return {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in (folder / "chunks").glob("*.parquet")}


def test_adding_filters_computes_only_them(tmp_path, capsys):
    out = tmp_path / "study"
    rc, _, err = cli(capsys, "mc", "--filters", "ekf,ukf", *BASE, "--out", out)
    assert rc == 0, err
    before = _chunks(out)
    assert len(before) == 2 * 2 * 2  # filters x chunks x (metrics, series)
    rc, _, err = cli(capsys, "mc", "--filters", "ekf,ukf,iekf", "--smooth", "ekf", *BASE, "--out", out)
    assert rc == 0, err
    after = _chunks(out)
    assert {k: v for k, v in after.items() if k in before} == before  # same bytes, same mtimes
    assert sorted(set(after) - set(before)) == sorted(
        f"{kind}-1-{f}-{first:06d}.parquet" for kind in ("metrics", "series") for f in ("iekf", "ekf-rts")
        for first in (0, 2))
    grown = pd.read_parquet(out / "metrics.parquet")
    assert sorted(grown["filter"].unique()) == ["ekf", "ekf-rts", "iekf", "ukf"]
    # the same numbers as one study with every filter from the start
    rc, _, err = cli(capsys, "mc", "--filters", "ekf,ukf,iekf", "--smooth", "ekf", *BASE, "--out", tmp_path / "once")
    assert rc == 0, err
    once = pd.read_parquet(tmp_path / "once" / "metrics.parquet")
    key = ["track", "filter", "run"]
    cols = ["vrmse", "mrmse", "nees", "hpe_rms", "nis_dvl"]
    pd.testing.assert_frame_equal(grown.sort_values(key)[cols].reset_index(drop=True),
                                  once.sort_values(key)[cols].reset_index(drop=True))
    epochs = pd.read_parquet(out / "epochs.parquet")
    assert sorted(epochs["filter"].unique()) == ["ekf", "ekf-rts", "iekf", "ukf"]
    mf = json.loads((out / "manifest.json").read_text())
    assert mf["options"]["filters"] == ["ekf", "ukf", "iekf"] and mf["identity"] == 2


def test_a_study_does_not_shrink_nor_change_a_filter_it_holds(tmp_path, capsys):
    out = tmp_path / "study"
    rc, _, err = cli(capsys, "mc", "--filters", "ekf,ukf", "--filter-option", "ukf.alpha=0.5", *BASE, "--out", out)
    assert rc == 0, err
    rc, o, err = cli(capsys, "mc", "--filters", "ekf", *BASE, "--out", out)
    assert_one_error_line(rc, o, err, "holds --filters ukf", "new --out")
    rc, o, err = cli(capsys, "mc", "--filters", "ekf,ukf", "--filter-option", "ukf.alpha=0.7", *BASE, "--out", out)
    assert_one_error_line(rc, o, err, "filter ukf made with other --filter-option")
    # a new filter with its own options may join
    rc, _, err = cli(capsys, "mc", "--filters", "ekf,ukf,ukf-nespm", "--filter-option", "ukf.alpha=0.5",
                     "--filter-option", "ukf-nespm.alpha=0.5", *BASE, "--out", out)
    assert rc == 0, err
    # any other option is still another experiment
    rc, o, err = cli(capsys, "mc", "--filters", "ekf,ukf,ukf-nespm", "--filter-option", "ukf.alpha=0.5",
                     "--filter-option", "ukf-nespm.alpha=0.5", "--seed", "3", *BASE, "--out", out)
    assert_one_error_line(rc, o, err, "differs in: seed")


def test_a_folder_made_before_growth_grows_in_runs_only(tmp_path, capsys):
    """A manifest without ``identity`` (made before studies could grow): its chunks' identity leaves
    out the runs only, so it takes more runs but not more filters."""
    out = tmp_path / "old"
    rc, _, err = cli(capsys, "mc", "--filters", "ekf", *BASE, "--out", out)
    assert rc == 0, err
    mf = json.loads((out / "manifest.json").read_text())
    del mf["identity"]
    (out / "manifest.json").write_text(json.dumps(mf))
    rc, o, err = cli(capsys, "mc", "--filters", "ekf,ukf", *BASE, "--out", out)
    assert_one_error_line(rc, o, err, "differs in: filters")
