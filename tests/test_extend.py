"""Extending a finished ``mc`` folder with more runs, and what its manifest records.

``mc --runs N`` on a folder holding fewer runs computes only the new runs (finished chunk
files are not touched) and ends with exactly the metrics of a fresh N-run experiment;
fewer runs than the folder holds are refused with one line. The manifest records the
filter configuration the filters actually used (DVL std, lever arm) and the run blocks.
"""
from __future__ import annotations

import json

import pandas as pd
import pytest

from conftest import nespm

FAST = ["--tracks", "5", "--filters", "ins,ekf", "--chunk-size", "2", "--no-progress"]


def _mc(short_data_dir, out, *extra):
    rc, stdout, stderr = nespm("mc", *FAST, "--data-dir", short_data_dir, "--out", out, *extra)
    assert rc == 0, stderr
    return pd.read_parquet(out / "metrics.parquet").drop(columns="seconds")


def _mtimes(d):
    return {p.name: p.stat().st_mtime_ns for p in (d / "chunks").glob("*.parquet")}


@pytest.fixture(scope="module")
def extended(short_data_dir, tmp_path_factory):
    """A 3-run folder extended to 5 runs, and a fresh 5-run folder."""
    base = tmp_path_factory.mktemp("extend")
    ext, fresh = base / "ext", base / "fresh"
    _mc(short_data_dir, ext, "--runs", "3")
    before = _mtimes(ext)
    grown = _mc(short_data_dir, ext, "--runs", "5")
    after = _mtimes(ext)
    return dict(ext=ext, fresh=_mc(short_data_dir, fresh, "--runs", "5"), grown=grown, before=before, after=after)


def test_extension_equals_fresh_experiment(extended):
    pd.testing.assert_frame_equal(extended["grown"], extended["fresh"], check_exact=True)
    assert sorted(extended["grown"]["run"].unique()) == [0, 1, 2, 3, 4]


def test_extension_computes_only_new_runs(extended):
    before, after = extended["before"], extended["after"]
    assert all(after[k] == v for k, v in before.items())  # no finished chunk rewritten
    new = sorted(set(after) - set(before))
    # runs 3-4 are one new chunk starting at run 3 (the old block's last chunk held run 2 alone)
    assert new == sorted(f"{kind}-5-{f}-000003.parquet" for kind in ("metrics", "series") for f in ("ekf", "ins"))


def test_manifest_records_blocks_and_resolved_filter(extended):
    m = json.loads((extended["ext"] / "manifest.json").read_text())
    assert m["run_blocks"] == [[0, 3], [3, 5]]
    assert m["options"]["runs"] == 5
    fc = m["filter_config"]["all"]
    assert fc["dvl_std"] == 0.1  # recorded DVL: the filter's R is 0.1 m/s, not the dataclass default 0.02
    assert fc["lever_arm"] == [0.0, 0.0, 0.0]


def test_fewer_runs_refused_names_the_count(short_data_dir, extended):
    rc, _, stderr = nespm("mc", *FAST, "--data-dir", short_data_dir, "--runs", "2", "--out", extended["ext"])
    assert rc == 2
    line = stderr.strip()
    assert len(line.splitlines()) == 1 and "holds 5 runs" in line and "--runs 5 or more" in line


def test_manifest_records_lever_arm_and_synthetic_std(short_data_dir, tmp_path):
    out = tmp_path / "syn"
    rc, _, stderr = nespm("mc", "--tracks", "5", "--filters", "ekf", "--runs", "1", "--no-progress",
                          "--data-dir", short_data_dir, "--dvl", "synthetic", "--dvl-lever-arm", "-1.6", "0", "0",
                          "--out", out)
    assert rc == 0, stderr
    fc = json.loads((out / "manifest.json").read_text())["filter_config"]["all"]
    assert fc["dvl_std"] == 0.02 and fc["lever_arm"] == [-1.6, 0.0, 0.0]
