"""nespm sweep: paired realizations across values and filters, schema, resume, bad input."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import cli
from nespm_cli.cli import main
from nespm_cli.data.corruption import draw
from nespm_cli.experiments.spec import Spec, couple_filter
from nespm_cli.filters import FilterConfig
from nespm_cli.experiments.sweep import PARAMS, sweep_cells

BASE = ["--tracks", "5", "--runs", "2", "--chunk-size", "2", "--jobs", "2", "--no-progress"]


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "s"
    rc = main(["sweep", "--param", "misalignment-deg", "--values", "0.01,10", "--filters", "ins,ekf",
               *BASE, "--out", str(out)])
    assert rc == 0
    return out


def test_sweep_rows_and_columns(sweep_dir):
    m = pd.read_parquet(sweep_dir / "metrics.parquet")
    assert len(m) == 2 * 2 * 2  # values x filters x runs
    assert set(m["param"]) == {"misalignment-deg"}
    assert sorted(m["value"].unique()) == [0.01, 10.0]
    assert not m.duplicated(["value", "track", "filter", "run"]).any()
    e = pd.read_parquet(sweep_dir / "epochs.parquet")
    assert len(e) == 2 * 2 * 400 and {"param", "value"} <= set(e.columns)


def test_sweep_cell_equals_mc_with_that_value(sweep_dir, tmp_path, capsys):
    """A sweep value is exactly the mc experiment with that option: same realization, same numbers."""
    rc, _, err = cli(capsys, "mc", "--misalignment-deg", "10", "--filters", "ins,ekf", *BASE, "--out", tmp_path / "m")
    assert rc == 0, err
    m = pd.read_parquet(tmp_path / "m" / "metrics.parquet").drop(columns="seconds")
    s = pd.read_parquet(sweep_dir / "metrics.parquet")
    s = s[s["value"] == 10.0].drop(columns=["param", "value", "seconds"]).reset_index(drop=True)
    pd.testing.assert_frame_equal(s, m)


def test_paired_draws_across_values():
    """The same standard normals are scaled by each value: draws / value agree to 1e-15."""
    spec = Spec(tracks=(5,), runs=4, filters=("ekf",))
    cells = sweep_cells(spec, "acc-bias", [0.03, 0.3, 3.0])
    scaled = [draw(0, 5, np.arange(4), 400.0, c.spec.corruption).b_a / v for c, v in zip(cells, [0.03, 0.3, 3.0])]
    np.testing.assert_allclose(scaled[0], scaled[1], rtol=1e-15)
    np.testing.assert_allclose(scaled[0], scaled[2], rtol=1e-15)
    # and the filter is told the new std (P0 follows the corruption)
    assert cells[2].spec.filter_config.p0_acc_bias == 3.0
    # heading-only sweep changes the yaw axis alone
    h = sweep_cells(spec, "heading-deg", [5.0])[0].spec
    assert h.filter_config.p0_att_deg == (0.01, 0.01, 5.0)


def test_sweep_resume_recomputes_only_missing(sweep_dir, capsys):
    chunks = sweep_dir / "chunks"
    victim = sorted(chunks.glob("metrics-v01-*-ekf-*.parquet"))[0]
    series = chunks / victim.name.replace("metrics-", "series-")
    others = {p: p.stat().st_mtime_ns for p in chunks.glob("*.parquet") if p not in (victim, series)}
    before = pd.read_parquet(sweep_dir / "metrics.parquet").drop(columns="seconds")
    victim.unlink()
    series.unlink()
    rc = main(["sweep", "--param", "misalignment-deg", "--values", "0.01,10", "--filters", "ins,ekf",
               *BASE, "--out", str(sweep_dir)])
    assert rc == 0
    assert victim.exists()
    assert all(p.stat().st_mtime_ns == t for p, t in others.items())
    after = pd.read_parquet(sweep_dir / "metrics.parquet").drop(columns="seconds")
    pd.testing.assert_frame_equal(before, after)


@pytest.mark.parametrize("args,needle", [
    (["--param", "bogus", "--values", "1"], "--param"),
    (["--param", "misalignment-deg", "--values", "1,x"], "--values"),
    (["--param", "misalignment-deg", "--values", "0,1"], "positive"),
    (["--param", "misalignment-deg", "--values", "1,1"], "--values"),
    (["--param", "dvl-noise", "--values", "0.02"], "--dvl synthetic"),
    (["--param", "outage-length", "--values", "300"], "--outage"),
])
def test_bad_sweep_options(capsys, tmp_path, args, needle):
    rc, out, err = cli(capsys, "sweep", *args, *BASE, "--out", tmp_path / "x")
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("nespm: error:") and needle in lines[0], err
    assert not (tmp_path / "x").exists()


def test_every_param_applies():
    spec = Spec(tracks=(5,), runs=1, dvl="synthetic", filter_config=couple_filter(FilterConfig(), Spec().corruption))
    for name, p in PARAMS.items():
        s = p.apply(spec, 0.5)
        assert s != spec, name
