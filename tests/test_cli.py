"""End-to-end tests of the ``nespm`` command line (nespm_cli.cli.main), in-process.

Every bad input must end in exit code 2 and exactly one stderr line ``nespm: error: ...``
naming the offending option / file, never a traceback. Good commands are checked on their
output: JSON summaries, time series files, track listings, realizations.

Cost: a filter over a full 400 s track is ~6-10 s, so only one full-track filter pass runs
here (a clean ``ins`` run of the embedded default through the console script); the other
runs use ``short_data_dir`` (conftest: embedded tracks 5 and 6 cut to 80 epochs) or a 30 s cut
of an embedded track. Only ``test_tracks_real_data_dir`` needs the real Snapir data (skipped
without it).
"""
from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import (SHORT_EPOCHS, WAIT_BOUND, assert_one_error_line, cli, console_script, env_without_data_dir,
                      short_track, slow_env, wait_until)
from nespm_cli.data.corruption import CorruptionConfig, draw, n_segments
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.tracks import load_track, write_akit

# The default (no --data-dir) must mean the embedded tracks whatever the caller's shell has.
pytestmark = pytest.mark.usefixtures("no_env_data_dir")

SUMMARY_KEYS = {"track", "filter", "vrmse", "mrmse", "max_vel_err", "max_att_err", "seconds"}
REALIZATION_COLUMNS = [
    "track", "run", "seed", "schedule", "segment_s", "dynamic_bias",
    "dv0_n", "dv0_e", "dv0_d", "dpsi0_x", "dpsi0_y", "dpsi0_z",
    "ba_x", "ba_y", "ba_z", "bg_x", "bg_y", "bg_z", "dp0_n", "dp0_e", "dp0_d", "acc_factors", "gyro_factors",
]


# --------------------------------------------------------------------------- bad input


@pytest.fixture(scope="module")
def bad_gt_dir(tmp_path_factory) -> Path:
    """A data dir whose Trajectory1/GT_trajectory1.csv has 'abc' in data row 5, column 'V North [m/s]'."""
    d = tmp_path_factory.mktemp("bad_gt")
    gt = write_akit(embedded_track(1), d) / "GT_trajectory1.csv"
    lines = gt.read_text().splitlines()
    header = lines[0].split(",")
    fields = lines[5].split(",")
    fields[header.index("V North [m/s]")] = "abc"
    lines[5] = ",".join(fields)
    gt.write_text("\n".join(lines) + "\n")
    return d


BAD = [  # (id, argv after the subcommand, strings the one error line must contain)
    ("mc-unknown-filter", ["mc", "--tracks", "5", "--filters", "ins,kalman"], ["--filters", "kalman"]),
    ("run-unknown-filter", ["run", "--track", "5", "--filter", "kalman"], ["--filter", "kalman"]),
    ("mc-unknown-track", ["mc", "--tracks", "5", "9"], ["--tracks", "9"]),
    ("run-unknown-track", ["run", "--track", "9"], ["--track", "9"]),
    ("mc-bad-track-text", ["mc", "--tracks", "five"], ["--tracks", "five"]),
    ("mc-unknown-scenario", ["mc", "--tracks", "5", "--scenario", "storm"], ["--scenario", "storm"]),
    ("mc-unknown-schedule", ["mc", "--tracks", "5", "--schedule", "weekly"], ["--schedule", "weekly"]),
    ("corrupt-unknown-schedule", ["corrupt", "--schedule", "weekly"], ["--schedule", "weekly"]),
    ("mc-runs-0", ["mc", "--tracks", "5", "--runs", "0"], ["--runs"]),
    ("corrupt-runs-0", ["corrupt", "--runs", "0"], ["--runs"]),
    ("mc-chunk-size-0", ["mc", "--tracks", "5", "--chunk-size", "0"], ["--chunk-size"]),
    ("mc-jobs-0", ["mc", "--tracks", "5", "--jobs", "0"], ["--jobs"]),
    ("run-negative-run", ["run", "--track", "5", "--run", "-1"], ["--run"]),
    ("mc-outage-past-end", ["mc", "--tracks", "5", "--scenario", "outage", "--outage-start", "390"],
     ["--outage-start", "390"]),
    ("run-outage-past-end", ["run", "--track", "5", "--scenario", "outage", "--outage-start", "390"],
     ["--outage-start"]),
    ("mc-unknown-option", ["mc", "--tracks", "5", "--bogus"], ["--bogus"]),
    ("run-unknown-option", ["run", "--track", "5", "--bogus"], ["--bogus"]),
    ("mc-runs-not-int", ["mc", "--runs", "many"], ["--runs"]),
    ("run-missing-track", ["run"], ["--track"]),
    ("unknown-command", ["frobnicate"], ["frobnicate"]),
]


@pytest.mark.parametrize("argv,must", [pytest.param(a, m, id=i) for i, a, m in BAD])
def test_bad_option_one_line_exit_2(capsys, tmp_path, argv, must):
    if argv[0] in ("mc", "corrupt"):
        argv = argv + ["--out", str(tmp_path / "out")]
    if argv[0] == "mc":
        argv = argv + ["--no-progress"]
    rc, out, err = cli(capsys, *argv)
    assert_one_error_line(rc, out, err, *must)
    assert not (tmp_path / "out").exists(), "a rejected command must not create its output folder"


@pytest.mark.parametrize("cmd", [["tracks"], ["run", "--track", "5"], ["mc", "--tracks", "5", "--no-progress"],
                                 ["corrupt", "--tracks", "5"]])
def test_missing_data_dir(capsys, tmp_path, cmd):
    missing = tmp_path / "no-such-folder"
    extra = ["--out", str(tmp_path / "out")] if cmd[0] in ("mc", "corrupt") else []
    rc, out, err = cli(capsys, *cmd, "--data-dir", missing, *extra)
    assert_one_error_line(rc, out, err, str(missing), "not found")


@pytest.mark.parametrize("cmd", [["tracks"], ["run", "--track", "1"], ["corrupt", "--tracks", "1"]])
def test_malformed_gt_file(capsys, tmp_path, bad_gt_dir, cmd):
    extra = ["--out", str(tmp_path / "out")] if cmd[0] == "corrupt" else []
    rc, out, err = cli(capsys, *cmd, "--data-dir", bad_gt_dir, *extra)
    assert_one_error_line(rc, out, err, "GT_trajectory1.csv", "data row 5", "V North [m/s]", "abc")


def test_malformed_gt_file_mc(capsys, tmp_path, bad_gt_dir):
    """mc reports the bad file (from inside its worker) as one line too."""
    rc, out, err = cli(capsys, "mc", "--tracks", "1", "--runs", "1", "--filters", "ins", "--jobs", "1",
                       "--no-progress", "--data-dir", bad_gt_dir, "--out", tmp_path / "out")
    assert_one_error_line(rc, out, err, "GT_trajectory1.csv", "data row 5", "V North [m/s]", "abc")


def test_malformed_gt_file_mc_creates_nothing(capsys, tmp_path, bad_gt_dir):
    cli(capsys, "mc", "--tracks", "1", "--runs", "1", "--filters", "ins", "--jobs", "1",
        "--no-progress", "--data-dir", bad_gt_dir, "--out", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_report_without_metrics(capsys, tmp_path):
    (tmp_path / "empty").mkdir()
    rc, out, err = cli(capsys, "report", tmp_path / "empty")
    assert_one_error_line(rc, out, err, "metrics.parquet")
    rc, out, err = cli(capsys, "report", tmp_path / "missing")
    assert_one_error_line(rc, out, err, str(tmp_path / "missing"))


# --------------------------------------------------------------------------- help

HELP = {
    "mc": ["--tracks", "--runs", "--filters", "--jobs", "--chunk-size", "--out", "--scenario", "--schedule",
           "--seed", "--data-dir", "--outage-start", "--outage-length"],
    "run": ["--track", "--filter", "--run", "--clean", "--json", "--out", "--data-dir", "--seed"],
    "corrupt": ["--tracks", "--runs", "--seed", "--schedule", "--out", "--data-dir"],
    "report": ["--baseline", "--n-boot"],
    "tracks": ["--data-dir"],
}


@pytest.mark.parametrize("cmd", sorted(HELP))
def test_subcommand_help(capsys, cmd):
    rc, out, err = cli(capsys, cmd, "--help")
    assert rc == 0, err
    assert "Traceback" not in out + err
    assert f"nespm {cmd}" in out
    for opt in HELP[cmd]:
        assert re.search(rf"(^|\s){re.escape(opt)}\b", out), f"{cmd} --help does not mention {opt}"


def test_top_level_help(capsys):
    rc, out, err = cli(capsys, "--help")
    assert rc == 0
    for cmd in HELP:
        assert cmd in out


def test_no_arguments_shows_commands(capsys):
    rc, out, err = cli(capsys)
    for cmd in HELP:
        assert cmd in out + err


# --------------------------------------------------------------------------- nespm run


def test_run_clean_json_short_track(capsys, short_data_dir):
    """Clean case (exact initial state, clean IMU from the inverse strapdown): INS reproduces GT
    (read from an A-KIT folder: the short track 5)."""
    rc, out, err = cli(capsys, "run", "--track", "5", "--filter", "ins", "--clean", "--json",
                       "--data-dir", short_data_dir)
    assert rc == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1, lines
    s = json.loads(lines[0])
    assert SUMMARY_KEYS <= set(s)
    assert s["track"] == 5 and s["filter"] == "ins" and s["clean"] is True
    assert s["max_vel_err"] < 1e-6
    assert s["max_att_err"] < 1e-8
    assert s["vrmse"] <= s["max_vel_err"] and s["mrmse"] <= s["max_att_err"]
    assert s["n_samples"] == SHORT_EPOCHS and s["diverged"] is False
    assert s["seconds"] > 0


def test_run_time_series_parquet(capsys, tmp_path, short_data_dir):
    out_file = tmp_path / "sub" / "x.parquet"
    rc, out, err = cli(capsys, "run", "--track", "5", "--filter", "ekf", "--run", "3", "--out", out_file,
                       "--data-dir", short_data_dir)
    assert rc == 0, err
    assert "vrmse" in out
    ts = pd.read_parquet(out_file)
    assert len(ts) == SHORT_EPOCHS
    for c in ("t", "vel_err", "vN_true", "vN_est", "sigma_dvN", "att_err", "dvl_used", "roll_true", "yaw_est"):
        assert c in ts.columns, c
    assert ts["t"].iloc[0] == 0.0 and np.all(np.diff(ts["t"]) > 0)
    assert ts["t"].iloc[-1] == pytest.approx(load_track(5, short_data_dir).duration)
    # the error column is the norm of the estimated minus true velocity
    dv = np.stack([ts[f"v{c}_est"] - ts[f"v{c}_true"] for c in "NED"], axis=1)
    np.testing.assert_allclose(ts["vel_err"], np.linalg.norm(dv, axis=1), rtol=1e-9, atol=1e-12)
    assert np.all(np.isfinite(ts["sigma_dvN"])) and np.all(ts["sigma_dvN"] > 0)
    # a corrupted run starts with the realization's initial velocity error
    assert ts["vel_err"].iloc[0] > 0


def test_run_time_series_csv(capsys, tmp_path):
    """The same run written as CSV (name ends in .csv) and as Parquet holds the same table."""
    d = tmp_path / "data"
    write_akit(short_track(1, 31), d)
    common = ["run", "--track", "1", "--filter", "ekf", "--run", "3", "--data-dir", d]
    rc, out, err = cli(capsys, *common, "--out", tmp_path / "x.csv")
    assert rc == 0, err
    rc, out, err = cli(capsys, *common, "--out", tmp_path / "x.parquet")
    assert rc == 0, err
    assert (tmp_path / "x.csv").read_text().startswith("t,")
    csv = pd.read_csv(tmp_path / "x.csv")
    pq = pd.read_parquet(tmp_path / "x.parquet")
    assert len(csv) == 31
    assert list(csv.columns) == list(pq.columns)
    for c in ("t", "vel_err", "vN_true", "vN_est", "sigma_dvN"):
        np.testing.assert_array_equal(csv[c].to_numpy(float), pq[c].to_numpy(float), err_msg=c)


# --------------------------------------------------------------------------- nespm tracks


def _listed_tracks(out: str) -> list[int]:
    """Track numbers in the first column of the rich table."""
    return [int(m.group(1)) for m in re.finditer(r"^[│|]\s*(\d+)\s*[│|]", out, flags=re.M)]


def test_tracks_embedded(capsys):
    rc, out, err = cli(capsys, "tracks")
    assert rc == 0, err
    assert "embedded" in out
    assert _listed_tracks(out) == [1, 2, 3, 4, 5, 6]


def test_tracks_data_dir(capsys, short_data_dir):
    rc, out, err = cli(capsys, "tracks", "--data-dir", short_data_dir)
    assert rc == 0, err
    assert _listed_tracks(out) == [5, 6]


def test_tracks_real_data_dir(capsys, real_data_dir):
    rc, out, err = cli(capsys, "tracks", "--data-dir", real_data_dir)
    assert rc == 0, err
    assert _listed_tracks(out) == list(range(1, 14))


# --------------------------------------------------------------------------- nespm corrupt


def test_corrupt_constant(capsys, tmp_path):
    rc, out, err = cli(capsys, "corrupt", "--tracks", "5", "6", "--runs", "3", "--seed", "7", "--out", tmp_path)
    assert rc == 0, err
    assert "realizations.parquet" in out
    df = pd.read_parquet(tmp_path / "realizations.parquet")
    assert len(df) == 6
    assert sorted(df.columns) == sorted(REALIZATION_COLUMNS)
    assert sorted(zip(df["track"], df["run"])) == [(t, r) for t in (5, 6) for r in range(3)]
    assert (df["seed"] == 7).all() and (df["schedule"] == "constant").all()
    for col in ("track", "run", "seed"):
        assert df[col].dtype == np.int64, col
    duration = load_track(5).duration
    real = draw(7, 5, [0, 1, 2], duration, CorruptionConfig())
    rows = df[df["track"] == 5].sort_values("run")
    for name, arr, comps in (("dv0", real.dv0, "ned"), ("dpsi0", real.dpsi0, "xyz"),
                             ("ba", real.b_a, "xyz"), ("bg", real.b_g, "xyz")):
        for j, c in enumerate(comps):
            np.testing.assert_array_equal(rows[f"{name}_{c}"].to_numpy(), arr[:, j], err_msg=f"{name}_{c}")
    for f in rows["acc_factors"]:
        assert np.all(np.asarray(f) == 1.0)
    # another track's runs are other draws
    assert not np.array_equal(df[df["track"] == 6].sort_values("run")["dv0_n"].to_numpy(), real.dv0[:, 0])


def test_corrupt_dynamic(capsys, tmp_path):
    rc, out, err = cli(capsys, "corrupt", "--tracks", "5", "6", "--runs", "3", "--seed", "7",
                       "--schedule", "dynamic", "--out", tmp_path)
    assert rc == 0, err
    df = pd.read_parquet(tmp_path / "realizations.parquet")
    assert len(df) == 6 and (df["schedule"] == "dynamic").all() and (df["segment_s"] == 20.0).all()
    duration = load_track(5).duration
    S = math.ceil(duration / 20.0)
    assert S == n_segments(duration, 20.0) == 20
    for col in ("acc_factors", "gyro_factors"):
        for f in df[col]:
            f = np.asarray(f, dtype=float)
            assert f.shape == (S,)
            assert np.all((f >= 1.0) & (f <= 6.0))
            assert len(np.unique(f)) > 1
    real = draw(7, 5, [0, 1, 2], duration, CorruptionConfig(schedule="dynamic"))
    rows = df[df["track"] == 5].sort_values("run")
    np.testing.assert_array_equal(np.stack(rows["acc_factors"].map(np.asarray)), real.acc_factors)
    np.testing.assert_array_equal(np.stack(rows["gyro_factors"].map(np.asarray)), real.gyro_factors)
    np.testing.assert_array_equal(rows["ba_x"].to_numpy(), real.b_a[:, 0])


def test_corrupt_segment_length(capsys, tmp_path):
    rc, out, err = cli(capsys, "corrupt", "--tracks", "5", "--runs", "2", "--schedule", "dynamic",
                       "--segment-length", "30", "--out", tmp_path)
    assert rc == 0, err
    df = pd.read_parquet(tmp_path / "realizations.parquet")
    assert all(len(f) == math.ceil(400.0 / 30.0) for f in df["acc_factors"])


# --------------------------------------------------------------------------- the real console script


def test_console_script(tmp_path):
    """The installed ``nespm`` entry point: exit codes 0 and 2, JSON on stdout, one error line on stderr."""
    env = env_without_data_dir()
    ok = subprocess.run(console_script() + ["run", "--track", "1", "--filter", "ins", "--clean", "--json"],
                        capture_output=True, text=True, env=env, timeout=WAIT_BOUND)
    assert ok.returncode == 0, ok.stderr
    s = json.loads(ok.stdout)
    assert SUMMARY_KEYS <= set(s)
    assert s["track"] == 1 and s["max_vel_err"] < 1e-6 and s["max_att_err"] < 1e-8

    bad = subprocess.run(console_script() + ["mc", "--tracks", "9", "--out", str(tmp_path / "o")],
                         capture_output=True, text=True, env=env, timeout=WAIT_BOUND)
    assert bad.returncode == 2
    assert bad.stdout == ""
    assert_one_error_line(bad.returncode, bad.stdout, bad.stderr, "--tracks", "9")


def test_ctrl_c_during_mc_prints_the_resume_hint(tmp_path):
    """SIGINT while chunks run: exit 130 and one stderr line saying how to resume. (The chunk is
    UKF-NESPM on the NumPy loop, about 10 s of work, so the signal lands mid-chunk on a busy
    machine too. The child gets the default SIGINT disposition: a suite started in the
    background of a non-interactive shell ignores SIGINT, and a child would inherit that.)"""
    import signal

    out = tmp_path / "mc"
    p = subprocess.Popen([sys.executable, "-m", "nespm_cli.cli", "mc", "--tracks", "5", "--runs", "2",
                          "--filters", "ukf-nespm", "--no-progress", "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=slow_env(), preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    # the manifest is written before the first chunk starts
    wait_until(lambda: (out / "manifest.json").exists(), "the manifest was written", proc=p)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=WAIT_BOUND)
    assert p.returncode == 130
    assert err.splitlines() == ["nespm: interrupted; finished chunks are kept, re-run the same command to resume"]


def test_cli_defaults_are_the_library_defaults():
    """One source of defaults: the options' defaults build exactly the library's default Spec."""
    from nespm_cli import cli as cli_mod
    from nespm_cli.data.corruption import CorruptionConfig
    from nespm_cli.experiments.spec import Spec, couple_filter
    from nespm_cli.filters import FilterConfig

    kw = {name: d for name, _, d, _, _ in cli_mod._COMMON}
    spec = cli_mod._spec(tracks=(5, 6), runs=100, filters=("ekf", "ukf", "ukf-nespm"), chunk_size=None, **kw)
    assert spec == Spec()
    # the filters are told the corruption by the library, for the API as for the CLI
    from nespm_cli.experiments.spec import validate
    assert validate(spec).filter_config == validate(Spec()).filter_config
    assert validate(Spec()).filter_config.p0_vel == couple_filter(FilterConfig(), CorruptionConfig()).p0_vel
    runner = {name: d for name, _, d, _, _ in cli_mod._RUNNER}
    assert runner["tracks_"] == "5 6" and runner["filters_"] == "ekf,ukf,ukf-nespm"
    assert runner["runs"] == Spec().runs and runner["chunk_size"] == Spec().chunk_size
