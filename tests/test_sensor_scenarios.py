"""Sensor noise scenarios (issue 40 item 1; nespm_cli/sensors/scenario.py): a noise schedule on a
sensor's white noise std and an outlier model, drawn from the sensor's own sub-streams.

Must hold: a factor of 1 everywhere and no outliers give today's numbers bit for bit; adding a
schedule or outliers moves no other draw (IMU, initial errors, another sensor, the DVL's own white
noise, which the schedule only multiplies); runs are jobs-invariant; the manifest records both keys;
bad values are one line and exit 2.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.experiments.mc import realization_inputs, simulate
from nespm_cli.experiments.spec import Spec, track_inputs, validate
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.filters import FilterConfig
from nespm_cli.sensors.channels import build_channel
from nespm_cli.sensors.scenario import outlier_errors, parse_outliers

RUNS = np.arange(4)


@pytest.fixture(autouse=True)
def embedded(monkeypatch):
    """The embedded tracks, whatever the shell's $NESPM_DATA_DIR."""
    monkeypatch.delenv("NESPM_DATA_DIR", raising=False)


def spec_with(*options, sensors=("dvl",), state="12") -> Spec:
    """Track 5, 0-60 s, synthetic DVL (a 0.01 m/s bias per run, so its draws follow the noise's)."""
    return validate(Spec(tracks=(5,), runs=len(RUNS), filters=("ekf",), window="0:60", dvl="synthetic",
                         sensors=sensors, filter_config=FilterConfig(state=state),
                         sensor_options=(("dvl", "bias", "0.01"),) + tuple(options)))


def channels(spec: Spec, clean: bool = False, runs: np.ndarray = RUNS) -> dict:
    track, truth = track_inputs(spec, 5)
    return {s.name: build_channel(s, track, truth, spec.seed, 5, runs, clean) for s in sensor_suite(spec)}


def dvl_of(spec: Spec):
    return next(s for s in sensor_suite(spec) if s.name == "dvl")


@pytest.mark.parametrize("option", [("dvl", "noise_schedule", "step:0=1"), ("dvl", "noise_schedule", "ramp:0=1,60=1"),
                                    ("dvl", "noise_schedule", "dynamic:20:1:1"), ("dvl", "outliers", "0:10")])
def test_factor_one_and_no_outliers_are_todays_numbers(option):
    base, same = spec_with(), spec_with(option)
    a, b = channels(base)["dvl"], channels(same)["dvl"]
    assert np.array_equal(a.z, b.z) and np.array_equal(a.ok, b.ok)
    if option[1] == "noise_schedule":
        ra, rb = simulate(base, 5, RUNS)[0]["ekf"], simulate(same, 5, RUNS)[0]["ekf"]
        assert np.array_equal(ra[1].vel, rb[1].vel) and np.array_equal(ra[0].P, rb[0].P)


def test_a_x4_step_multiplies_the_same_draws():
    """The residual of a ``step:0=1,30=4`` DVL is today's residual before 30 s (bit for bit) and 4x
    it after (to rounding); its per-segment std ratio is 4 within 4 sampling sigmas; true_std says
    0.02 then 0.08 m/s."""
    base, step = spec_with(), spec_with(("dvl", "noise_schedule", "step:0=1,30=4"))
    clean = channels(base, clean=True)["dvl"]
    a, b = channels(base)["dvl"], channels(step)["dvl"]
    ra, rb = a.z - clean.z, b.z - clean.z
    first, second = a.t < 30 - 1e-9, a.t >= 30 - 1e-9
    assert first.sum() >= 20 and second.sum() >= 20
    assert np.array_equal(ra[:, first], rb[:, first])
    # after 30 s: ra = n + c, rb = 4 n + c with c the run's bias (same draw): c = ra - (rb - ra) / 3
    c = ra[:, second] - (rb[:, second] - ra[:, second]) / 3
    assert np.ptp(c, axis=1).max() < 1e-12 and np.abs(c).max() > 1e-3  # one bias per run and axis
    c = c[:, :1]
    ratio = (rb[:, second] - c).std() / (rb[:, first] - c).std()
    n1, n2 = rb[:, first].size, rb[:, second].size
    tol = 4 * 4 * np.sqrt(1 / (2 * n1) + 1 / (2 * n2))  # 4 sigma of the ratio of two sample stds
    assert abs(ratio - 4) < tol, (ratio, tol)
    std = dvl_of(step).true_std(a.t, step.seed, 5, RUNS)
    assert std.shape == (len(RUNS), len(a.t))
    assert np.allclose(std[:, first], 0.02) and np.allclose(std[:, second], 0.08)


def test_dynamic_schedule_per_run_and_standardised_residuals():
    """``dynamic:20:1:6``: each run its own factors in [1, 6], constant on 20 s segments; the
    residuals divided by true_std are N(0, 1) (std within 4 sampling sigmas)."""
    spec = validate(dataclasses.replace(spec_with(), sensor_options=(("dvl", "noise_schedule", "dynamic:20:1:6"),)))
    clean, z = channels(spec, clean=True)["dvl"], channels(spec)["dvl"]
    std = dvl_of(spec).true_std(z.t, spec.seed, 5, RUNS)
    f = std / 0.02
    assert f.min() >= 1 and f.max() <= 6 and not np.allclose(f[0], f[1])
    seg = np.floor(z.t / 20 + 1e-9).astype(int)
    for s in np.unique(seg):
        assert np.ptp(f[:, seg == s], axis=1).max() == 0
    u = (z.z - clean.z) / std[..., None]
    assert abs(u.std() - 1) < 4 / np.sqrt(2 * u.size), u.std()


def test_a_schedule_and_outliers_move_no_other_draw():
    """IMU, initial solution and the depth channel are bit-identical with a DVL schedule and outliers."""
    opts = (("dvl", "noise_schedule", "ramp:0=1,60=5"), ("dvl", "outliers", "t:3:0.1:3:burst=2"))
    base = spec_with(sensors=("dvl", "depth"), state="15")
    more = spec_with(*opts, sensors=("dvl", "depth"), state="15")
    _, _, _, f1, w1, nav1, ch1 = realization_inputs(base, 5, RUNS)
    _, _, _, f2, w2, nav2, ch2 = realization_inputs(more, 5, RUNS)
    assert np.array_equal(f1, f2) and np.array_equal(w1, w2)
    assert np.array_equal(nav1.v_n, nav2.v_n) and np.array_equal(nav1.C_bn, nav2.C_bn)
    assert np.array_equal(ch1[1].z, ch2[1].z) and ch1[1].sensor.name == "depth"
    assert not np.array_equal(ch1[0].z, ch2[0].z)


def test_outlier_fraction_bursts_and_size():
    """``0.1:10:burst=3``: the share of outlier samples is 0.1 within 4 binomial sigmas (bursts
    counted as their number of events), outliers come in runs of >= 3 samples, their extra error has
    std 10 x 0.02 m/s; the records are the outlier-free ones plus exactly those errors."""
    runs = np.arange(64)  # 64 x 60 samples: the fraction to +-0.034 (4 sigma)
    spec = spec_with(("dvl", "outliers", "0.1:10:burst=3"))
    free = channels(spec_with(), runs=runs)["dvl"]
    z = channels(spec, runs=runs)["dvl"]
    dvl = dvl_of(spec)
    errors, mask = dvl.outlier_draws(z.t, spec.seed, 5, runs)
    assert np.allclose(z.z, free.z + errors, atol=1e-15, rtol=0)
    assert np.array_equal(z.z[~mask], free.z[~mask])
    n = mask.size
    sigma = np.sqrt(0.1 * 0.9 / (n / 3))  # about n / 3 independent burst positions
    assert abs(mask.mean() - 0.1) < 4 * sigma, (mask.mean(), sigma)
    for row in mask.astype(int):  # every burst is at least 3 long (except one cut by the end)
        edges = np.flatnonzero(np.diff(np.r_[0, row, 0]))
        lengths = edges[1::2] - edges[::2]
        assert lengths[:-1].min() >= 3 if len(lengths) > 1 else True
    e = errors[mask]
    assert abs(e.std() / 0.2 - 1) < 4 / np.sqrt(2 * e.size), e.std()


@pytest.mark.parametrize("text,scale", [("0.05:10", 10.0), ("t:5:0.05:2", 2.0 * np.sqrt(5 / 3))])
def test_outlier_models_on_many_samples(text, scale):
    """The pure generator on 4 x 50 000 samples: fraction 0.05 within 4 binomial sigmas, the extra
    error's std ``SCALE x std`` (Student-t: x sqrt(NU / (NU - 2))) within 5 %."""
    model = parse_outliers(text, "x")
    gens = [np.random.default_rng(i) for i in range(4)]
    errors, mask = outlier_errors(model, 50_000, 3, 0.5, gens)
    assert abs(mask.mean() - 0.05) < 4 * np.sqrt(0.05 * 0.95 / mask.size), mask.mean()
    assert not errors[~mask].any()
    assert abs(errors[mask].std() / (0.5 * scale) - 1) < 0.05, errors[mask].std() / (0.5 * scale)


def test_jobs_and_chunks_do_not_change_a_number(tmp_path):
    argv = ["--tracks", "5", "--runs", "4", "--filters", "ekf", "--window", "0:60", "--dvl", "synthetic",
            "--sensor-option", "dvl.noise_schedule=dynamic:15:1:6", "--sensor-option", "dvl.outliers=t:3:0.05:5",
            "--no-progress"]
    rc1, _, err1 = nespm("mc", *argv, "--out", tmp_path / "a", "--jobs", "1", "--chunk-size", "4")
    rc2, _, err2 = nespm("mc", *argv, "--out", tmp_path / "b", "--jobs", "2", "--chunk-size", "1")
    assert rc1 == 0 and rc2 == 0, (err1, err2)
    a, b = (pd.read_parquet(tmp_path / x / "metrics.parquet").sort_values("run") for x in "ab")
    for col in ("vrmse", "nees", "nis_dvl"):
        assert np.array_equal(a[col].to_numpy(), b[col].to_numpy()), col
    sensors = json.loads((tmp_path / "a" / "manifest.json").read_text())["sensors"]
    dvl = next(iter(sensors.values()))["dvl"]
    assert dvl["noise_schedule"] == "dynamic:15:1:6" and dvl["outliers"] == "t:3:0.05:5"
    rc, _, _ = nespm("mc", *argv[:-5], "--no-progress", "--out", tmp_path / "c", "--jobs", "1")
    c = pd.read_parquet(tmp_path / "c" / "metrics.parquet").sort_values("run")
    assert (c["nis_dvl"].to_numpy() < a["nis_dvl"].to_numpy()).all()  # the scenario reaches the filter


@pytest.mark.parametrize("option,needle", [
    ("dvl.noise_schedule=step:0=1,30=-4", "factors must be > 0"),
    ("dvl.noise_schedule=ramp:30=1,10=2", "increasing"),
    ("dvl.noise_schedule=sine:1", "unknown schedule"),
    ("dvl.noise_schedule=dynamic:20:0:6", "0 < LO <= HI"),
    ("dvl.noise_schedule=dynamic:0:1:6", "SEG must be > 0"),
    ("dvl.noise_schedule=step:x=1", "must be a number"),
    ("dvl.outliers=1.5:10", "probability in [0, 1]"),
    ("dvl.outliers=cauchy:0.1", "unknown outlier model"),
    ("dvl.outliers=0.1:-10", "SCALE must be > 0"),
    ("dvl.outliers=t:0:0.1", "dof NU must be > 0"),
    ("dvl.outliers=0.1:10:burst=0", "burst"),
    ("dvl.outliers=0.1", "FRACTION:SCALE"),
])
def test_bad_values_are_one_line(tmp_path, option, needle):
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--dvl", "synthetic", "--sensor-option", option,
                         "--out", tmp_path / "x", "--no-progress")
    line = assert_one_error_line(rc, out, err, needle, option.split("=")[0])
    assert "--sensor-option" in line
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("args,needle", [
    (["--sensor-option", "dvl.outliers=0.1:3"], "synthetic dvl only"),  # the recorded DVL
    (["--state", "15", "--sensors", "dvl,heading", "--dvl", "synthetic", "--sensor-option",
      "heading.noise_schedule=step:0=2"], "does not apply noise scenarios"),
])
def test_scenarios_that_would_be_ignored_are_refused(tmp_path, args, needle):
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--out", tmp_path / "x", "--no-progress", *args)
    assert_one_error_line(rc, out, err, needle)
    assert not (tmp_path / "x").exists()


def test_config_tables_take_the_scenarios(tmp_path):
    """``[sensors.dvl]`` keys are the command line's; the manifest records them."""
    cfg = tmp_path / "c.toml"
    cfg.write_text('[sensors.dvl]\nsource = "synthetic"\nnoise_schedule = "step:0=1,30=4"\noutliers = "0.05:10:burst=2"\n')
    rc, _, err = nespm("mc", "--config", cfg, "--tracks", "5", "--runs", "1", "--filters", "ekf", "--window", "0:60",
                       "--out", tmp_path / "o", "--no-progress", "--jobs", "1")
    assert rc == 0, err
    dvl = next(iter(json.loads((tmp_path / "o" / "manifest.json").read_text())["sensors"].values()))["dvl"]
    assert (dvl["source"], dvl["noise_schedule"], dvl["outliers"]) == ("synthetic", "step:0=1,30=4", "0.05:10:burst=2")


def test_run_line_names_the_scenario():
    """The report's Run line names a sensor's noise scenario as given; none when unset."""
    from nespm_cli.reports.markdown import sensors_text

    cells = {"all": {"dvl": {"source": "synthetic", "noise_schedule": "step:0=1,120=4", "outliers": "0.05:10"},
                     "depth": {"source": "synthetic", "noise_schedule": "", "outliers": ""}}}
    text = sensors_text({"options": {"sensors": ["dvl", "depth"]}, "sensors": cells})
    assert text == "dvl (noise_schedule step:0=1,120=4, outliers 0.05:10, synthetic), depth (synthetic)"
