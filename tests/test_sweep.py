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
    (["--param", "fix-interval", "--values", "10"], "fix is not in --sensors"),
    (["--param", "fix.intervl", "--values", "10", "--state", "15", "--sensors", "dvl,fix"], "fix.intervl"),
    (["--param", "fix-interval", "--values", "0,10", "--state", "15", "--sensors", "dvl,fix"], "positive"),
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


def test_sensor_parameter_sweep_is_paired_and_recorded(tmp_path, capsys, no_env_data_dir):
    """--param fix-interval: each value's sensor options in the manifest; the fix noise of a run is the
    same stream at every interval (the first draws agree), so the values are paired; the fix NIS and
    the horizontal error respond (fixes every 10 s: smaller RMS HPE than every 300 s, same runs)."""
    import json

    from nespm_cli.sensors.channels import build_channel

    out = tmp_path / "s"
    rc, _, err = cli(capsys, "sweep", "--param", "fix-interval", "--values", "10,300", "--tracks", "1", "--runs", "4",
                     "--filters", "ekf", "--state", "15", "--sensors", "dvl,depth,fix", "--no-progress",
                     "--out", out)
    assert rc == 0, err
    mf = json.loads((out / "manifest.json").read_text())
    assert [mf["sensors"][k]["fix"]["interval"] for k in ("v00-", "v01-")] == [10.0, 300.0]
    m = pd.read_parquet(out / "metrics.parquet")
    piv = m.pivot(index="run", columns="value", values="hpe_rms")
    assert (piv[10.0] < piv[300.0]).all(), piv
    # paired: the same normals scaled by each fix std
    from nespm_cli.experiments.spec import track_inputs, validate
    from nespm_cli.experiments.suite import sensor_suite

    cells = sweep_cells(Spec(tracks=(1,), runs=2, filters=("ekf",), sensors=("dvl", "fix"), data_dir=None,
                             filter_config=FilterConfig(state="15")), "fix-std", [1.0, 3.0])
    noise = []
    for cell in cells:
        spec = validate(cell.spec)
        track, truth = track_inputs(spec, 1)
        fix = [sn for sn in sensor_suite(spec) if sn.name == "fix"][0]
        ch, clean = (build_channel(fix, track, truth, spec.seed, 1, np.arange(2), c) for c in (False, True))
        noise.append(ch.z - clean.z)
    np.testing.assert_allclose(noise[1] / 3.0, noise[0], rtol=1e-9, atol=1e-15)


def test_beam_loss_length_sweeps_the_window_of_the_lost_beams():
    spec = Spec(tracks=(5,), runs=2, filters=("ekf",), sensors=("dvl-beams",), filter_config=FilterConfig(state="15"),
                sensor_options=(("dvl-beams", "beam_outage", "3,4@100:110"),))
    cells = sweep_cells(spec, "beam-loss-length", [30.0, 90.0])
    got = [dict(((o[0], o[1]), o[2]) for o in c.spec.sensor_options)[("dvl-beams", "beam_outage")] for c in cells]
    assert got == ["3,4@100:130", "3,4@100:190"]
    with pytest.raises(Exception, match="dvl-beams is not in --sensors"):
        sweep_cells(Spec(tracks=(5,), runs=2, filters=("ekf",)), "beam-loss-length", [30.0])
