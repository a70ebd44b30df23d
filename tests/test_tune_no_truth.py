"""Tuning and running without ground truth: a track spec without ``[gt]`` (docs/data.md, "Recorded data
without ground truth"; docs/tuning.md, "Tuning without ground truth").

The mis-set world of tests/test_tune_recovery.py (embedded tracks, their first 90 s) exported as recorded
files: per track the world's clean 100 Hz IMU and one realization's synthetic DVL (noise 0.02 m/s) as CSV
files, an ``[init]`` table holding the truth's first epoch, and no GT file. Each run of the tuning adds the
corruption protocol's IMU errors to the recorded IMU (as ``--imu recorded`` always does: white noise 0.03
m/s² and 7.3e-6 rad/s per sample, biases) and its initial errors; the EKF is told that noise x10 and the DVL
std x0.2. ``nespm tune --objective innovation``, 12 runs of track 5, 30 trials and the refinement, gets the
DVL std and the accelerometer noise back from the innovations. Measured (data seeds 0-3, ~20 s each): acc
1.13 / 1.42 / 1.66 / 1.21 of the truth, DVL 1.00 / 0.96 / 1.00 / 1.05 (the gyro flat, as with the truth).
"""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import assert_one_error_line, cli
from nespm_cli.data.tracks import load_track, track_files
from nespm_cli.errors import NespmError
from nespm_cli.experiments.spec import NO_TRUTH, track_inputs, validate
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.reports.dispatch import write_report
from nespm_cli.reports.innovation import write_innovation_report
from nespm_cli.sensors.channels import build_channel
from nespm_cli.tuning.heldout import DEFAULT_DIR, TUNED_DIR, run_heldout
from nespm_cli.tuning.run import run_tune
from nespm_cli.tuning.spec import TuneSpec

from test_tune_recovery import RANGES, TOLD_DVL_STD, TRUE_DVL_STD, mis_set_world

SPEC_HEAD = """[dvl]
file = "run{N}/dvl.csv"
time = "t"
x = "vx"
y = "vy"
z = "vz"

[imu]
file = "run{N}/imu.csv"
time = "t"
acc_x = "ax"
acc_y = "ay"
acc_z = "az"
gyro_x = "gx"
gyro_y = "gy"
gyro_z = "gz"

[init]
angle_unit = "deg"
"""


def export_world(folder: Path, numbers=(5, 6), run: int = 0) -> Path:
    """Write the mis-set world's tracks ``numbers`` as a truth-free track-spec folder: ``run{N}/imu.csv`` (the
    clean IMU, sample i the reading of the step ending at it), ``run{N}/dvl.csv`` (realization ``run``'s
    synthetic DVL at the epochs) and ``nespm-data.toml`` with ``[init.N]`` (the truth at the first epoch)."""
    folder = Path(folder)
    spec = validate(mis_set_world(tracks=tuple(numbers), runs=1))
    text = SPEC_HEAD
    for n in numbers:
        track, truth = track_inputs(spec, n)
        (folder / f"run{n}").mkdir(parents=True, exist_ok=True)
        imu = np.column_stack([truth.t, np.vstack([truth.f_b[:1], truth.f_b]), np.vstack([truth.w_ib_b[:1], truth.w_ib_b])])
        pd.DataFrame(imu, columns=["t", "ax", "ay", "az", "gx", "gy", "gz"]).to_csv(
            folder / f"run{n}" / "imu.csv", index=False, float_format="%.17g")
        dvl = next(s for s in sensor_suite(spec) if s.name == "dvl")
        ch = build_channel(dvl, track, truth, spec.seed, n, np.array([run]))
        pd.DataFrame(np.column_stack([truth.t[truth.epoch_index], ch.z[0]]), columns=["t", "vx", "vy", "vz"]).to_csv(
            folder / f"run{n}" / "dvl.csv", index=False, float_format="%.17g")
        lat, lon, alt = (float(x) for x in track.pos[0])
        state = {"lat": np.degrees(lat), "lon": np.degrees(lon), "alt": alt,
                 **dict(zip(("v_north", "v_east", "v_down"), map(float, track.v_n[0]))),
                 **dict(zip(("roll", "pitch", "yaw"), map(float, np.degrees(track.euler[0]))))}
        text += f"\n[init.{n}]\n" + "".join(f"{k} = {float(v)!r}\n" for k, v in state.items())
    (folder / "nespm-data.toml").write_text(text, encoding="utf-8")
    return folder


def no_truth_spec(folder: Path, **kw):
    """The mis-set world's study on the exported folder: the recorded IMU and DVL, no window (the files hold it)."""
    return dataclasses.replace(mis_set_world(**kw), window=None, imu="recorded", dvl="recorded", data_dir=str(folder))


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    return export_world(tmp_path_factory.mktemp("no-truth"))


def test_the_folder_has_no_truth(world):
    files = sorted(p.relative_to(world).as_posix() for p in world.rglob("*") if p.is_file())
    assert files == ["nespm-data.toml", "run5/dvl.csv", "run5/imu.csv", "run6/dvl.csv", "run6/imu.csv"], files
    track = load_track(5, world)
    assert not track.truth and track.imu is not None
    assert np.isfinite(track.pos[0]).all() and np.isnan(track.pos[1:]).all() and np.isnan(track.v_n[1:]).all()
    assert len(track.t) == 90 and track.t[0] == 0.0  # the DVL's epochs from the initial state's
    assert [p.name for p in track_files(5, world)] == ["nespm-data.toml", "dvl.csv", "imu.csv"]
    # the initial state read back from degrees: the truth's first epoch to round-off
    truth = load_track(5, None)
    np.testing.assert_allclose(track.pos[0, :2], truth.pos[0, :2], rtol=0, atol=1e-15)
    np.testing.assert_allclose(track.euler[0], truth.euler[0], rtol=0, atol=1e-15)


def test_innovation_tuning_without_truth_file(world):
    out = world.parent / "tune"
    spec = no_truth_spec(world, tracks=(5,), runs=12)
    rec = run_tune(TuneSpec(spec, trials=30, objective="innovation", ranges=RANGES, test_tracks=(6,), test_runs=4), out)
    assert rec["ground_truth"] is False
    v = rec["best"]["ekf"]["values"]
    acc = v["acc_noise_scale"] * 10  # tuned / true (seed 0: 1.13)
    dvl = v["r_scale_dvl"] * TOLD_DVL_STD / TRUE_DVL_STD  # (seed 0: 1.00)
    assert 1 / 1.5 <= dvl <= 1.5, dvl
    assert 1 / 2 <= acc <= 2, acc
    assert np.log(rec["best"]["ekf"]["default_score"] / rec["best"]["ekf"]["score"]) > 0.1  # the default: far less likely
    trials = pd.read_parquet(out / "trials.parquet")
    assert not {"rmse", "anees", "consistency", "band_distance"} & set(trials.columns)  # no truth statistic, not NaN
    assert trials["innovation_nll"].notna().all() and "nis_dvl" in trials
    # the held-out folders: innovation statistics only; the report says so
    run_heldout(spec, rec, out)
    for d in (DEFAULT_DIR, TUNED_DIR):
        m = pd.read_parquet(out / d / "metrics.parquet")
        assert not {"vrmse", "nees", "hpe_rms", "sse_vel"} & set(m.columns) and m["nll_dvl"].notna().all()
        e = pd.read_parquet(out / d / "epochs.parquet")
        assert not [c for c in e.columns if c.startswith(("vel_err", "nees", "hpe", "pcrb_", "north_"))]
    tuned = pd.read_parquet(out / TUNED_DIR / "metrics.parquet")
    default = pd.read_parquet(out / DEFAULT_DIR / "metrics.parquet")
    assert tuned["innovation_nll"].mean() < default["innovation_nll"].mean()  # held out: the tuned is more likely
    text = write_report(out).read_text(encoding="utf-8")
    assert "No ground truth: innovation statistics only" in text
    assert not [w for w in ("| ANEES", "ANEES default", "RMSE default", "VRMSE", "CEP", "PCRB") if w in text]
    trials_ekf = trials[(trials["filter"] == "ekf") & (trials["state"] == "COMPLETE")]
    counts = trials_ekf["phase"].value_counts()
    assert (f"trials: {counts.get('search', 0)} search + {counts.get('refine', 0)} refine + "
            f"{counts.get('check', 0)} check = {len(trials_ekf)}") in text
    assert counts.get("search", 0) == 30
    mc_text = write_innovation_report(out / TUNED_DIR).read_text(encoding="utf-8")  # nespm report of such a folder
    assert NO_TRUTH[1:] in mc_text and "| ekf | 4 | 0 |" in mc_text and "VRMSE" not in mc_text


def test_truth_free_refusals(world, capsys, tmp_path):
    base = ["--data-dir", world, "--imu", "recorded", "--no-progress"]
    rc, out, err = cli(capsys, "tune", *base, "--tracks", "5", "--runs", "2", "--trials", "1", "--objective", "rmse",
                       "--out", tmp_path / "t")
    assert_one_error_line(rc, out, err, "--objective rmse", "no [gt]", "--objective innovation")
    assert not (tmp_path / "t").exists()
    rc, out, err = cli(capsys, "run", *base, "--track", "5", "--filter", "ekf", "--dvl", "synthetic")
    assert_one_error_line(rc, out, err, "--dvl synthetic", "ground truth")
    rc, out, err = cli(capsys, "run", "--data-dir", world, "--track", "5", "--filter", "ekf", "--no-progress")
    assert_one_error_line(rc, out, err, "--imu synthetic", "--imu recorded")
    with pytest.raises(NespmError, match="--objective consistency"):
        run_tune(TuneSpec(no_truth_spec(world, tracks=(5,), runs=2), trials=1, objective="consistency"),
                 tmp_path / "t2")


def test_run_prints_innovation_statistics_only(world, capsys):
    rc, out, err = cli(capsys, "run", "--data-dir", world, "--imu", "recorded", "--track", "5", "--filter", "ekf",
                       "--no-progress", "--sensor-option", "dvl.r_std=0.02")
    assert rc == 0, err
    summary = dict(line.split(": ", 1) for line in (x.strip() for x in out.splitlines()) if ": " in line)
    assert summary["note"] == NO_TRUTH
    assert 2.0 < float(summary["nis_dvl"]) < 4.5  # the DVL std told right: NIS near its expectation 3 (2.90)
    assert np.isfinite(float(summary["nll_dvl"])) and summary["diverged"] == "False"
    for k in ("vrmse", "mrmse", "nees", "hpe_rms", "hpe_final", "sse_vel", "max_vel_err"):
        assert k not in summary, k


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace("[init]\n", "[initial]\n", 1).split("\n[init.")[0], ("unknown key 'initial'",)),
    (lambda t: t.split("\n[init]")[0], ("no [gt] table and no [init] table",)),
    (lambda t: t.split("[imu]")[0] + "[init]" + t.split("[init]")[1], ("no [gt] table and no [imu] table",)),
    (lambda t: t.replace("yaw = ", "yaw_ = ", 1), ("unknown key 'init.5.yaw_'",)),
    (lambda t: "\n".join(x for x in t.splitlines() if not x.startswith("yaw = ")) + "\n", ("'init.5.yaw' is missing",)),
    (lambda t: re.sub(r"pitch = .*", "pitch = 95.0", t, count=1), ("key 'init.5.pitch': 95.0 deg is beyond ±90",)),
    (lambda t: t.replace("alt = ", "depth = 3.0\nalt = ", 1), ("'init.5.alt' and 'init.5.depth' are both given",)),
    (lambda t: t + '\n[gt]\nfile = "x.csv"\n', ("key 'init': applies only without [gt]",)),
])
def test_spec_without_truth_refusals(world, tmp_path, capsys, edit, words):
    """A truth-free spec's mistakes: one line naming the table or key, exit 2."""
    import shutil

    for n in (5, 6):
        shutil.copytree(world / f"run{n}", tmp_path / f"run{n}")
    (tmp_path / "nespm-data.toml").write_text(edit((world / "nespm-data.toml").read_text(encoding="utf-8")))
    rc, out, err = cli(capsys, "run", "--data-dir", tmp_path, "--imu", "recorded", "--track", "5", "--filter", "ekf",
                       "--no-progress")
    assert_one_error_line(rc, out, err, "nespm-data.toml", *words)
