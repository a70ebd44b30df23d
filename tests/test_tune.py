"""``nespm tune``: per-filter noise scales, the seeded Optuna studies (reproducible, resumable), the
tuned config that ``mc`` takes unchanged, and the one-line refusals (docs/tuning.md).

Every study here is small: embedded track 5 cut to its first 60 s (``--window 0:60``), 4 runs per
trial, the synthetic DVL; a trial of one filter costs ~0.1 s.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from nespm_cli.cli import main
from nespm_cli.errors import NespmError
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.tuning.run import run_tune
from nespm_cli.tuning.spec import TuneSpec, training_seed
from nespm_cli.tuning.study import storage
from nespm_cli.tuning.study_file import JOURNAL_FILE
from nespm_cli.tuning.space import parse_range

SMALL = dict(tracks=(5,), runs=4, filters=("ekf",), dvl="synthetic", window="0:60")
CLI = ["tune", "--tracks", "5", "--runs", "4", "--filters", "ekf", "--dvl", "synthetic", "--window", "0:60",
       "--refine-trials", "0", "--no-progress"]  # the global search alone (the refinement: tests/test_tune_refine.py)


def params(folder) -> pd.DataFrame:
    d = pd.read_parquet(folder / "trials.parquet")
    return d[["filter", "trial", "score"] + [c for c in d.columns if c.startswith("p_")]]


def test_noise_scales_per_filter():
    """A noise scale changes only the filter it names; a scale of 1 is bit-identical to none; the
    R scale acts like the sensor's r_std (DVL r_std 0.02 x 0.5 = r_std 0.01, to round-off)."""
    base = validate(Spec(**{**SMALL, "filters": ("ekf", "ukf")}))
    runs = np.arange(2)

    def vel(spec, name):
        return simulate(spec, 5, runs, (name,))[0][name][0].v_n

    ref_ekf, ref_ukf = vel(base, "ekf"), vel(base, "ukf")
    one = validate(dataclasses.replace(base, filter_options=(("ekf", "acc_noise_scale", "1"),
                                                             ("ekf", "r_scale_dvl", "1.0"))))
    assert np.array_equal(vel(one, "ekf"), ref_ekf)
    half = validate(dataclasses.replace(base, filter_options=(("ekf", "r_scale_dvl", "0.5"),)))
    assert np.array_equal(vel(half, "ukf"), ref_ukf)  # the other filter unchanged
    got = vel(half, "ekf")
    assert not np.array_equal(got, ref_ekf)
    rstd = validate(dataclasses.replace(base, sensor_options=(("dvl", "r_std", "0.01"),)))
    np.testing.assert_allclose(got, vel(rstd, "ekf"), rtol=0, atol=1e-12)
    q = validate(dataclasses.replace(base, filter_options=(("ekf", "acc_noise_scale", "3"),)))
    from nespm_cli.experiments.spec import filter_config_of

    assert filter_config_of(q, "ekf").acc_noise == pytest.approx(3 * filter_config_of(base, "ekf").acc_noise)
    assert filter_config_of(q, "ukf").acc_noise == filter_config_of(base, "ukf").acc_noise


@pytest.mark.parametrize("option, words", [
    ("ekf.r_scale_depth=2", "names no sensor of --sensors"),
    ("ekf.acc_noise_scale=0", "a noise scale is a factor > 0"),
    ("ins.acc_noise_scale=2", "ins takes no options"),
    ("ekf.lever_arm_w_dvl=1", "unknown option"),  # a lever-arm coordinate (tests/test_tune_lever.py)
    ("ekf.lever_arm_x_depth=1", "no sensor of --sensors whose model has a lever arm (dvl)"),
    ("ekf.lever_arm_x_dvl=200", "within +-100 m"),
    ("ekf.lever_arm_x_dvl=nan", "expected a float"),
    ("ins.lever_arm_x_dvl=1", "ins takes no options"),
])
def test_bad_noise_scale_in_one_line(capsys, option, words):
    rc = main(["mc", "--filters", "ekf,ins", "--tracks", "5", "--runs", "1", "--filter-option", option,
               "--out", "/nonexistent/never"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and words in err and len(err.splitlines()) == 1


def test_reproducible_and_mc_takes_tuned_config(tmp_path, capsys):
    """The same seed and trials give bit-identical trials (one worker); the tuned config runs in
    ``mc`` unchanged and gives the held-out tuned folder's numbers; the first trial is the default."""
    t = TuneSpec(Spec(**SMALL), trials=12, profile=False)
    a = run_tune(t, tmp_path / "a")
    b = run_tune(t, tmp_path / "b")
    pa, pb = params(tmp_path / "a"), params(tmp_path / "b")
    pd.testing.assert_frame_equal(pa, pb)
    assert a["best"] == b["best"]
    phase = pd.read_parquet(tmp_path / "a" / "trials.parquet")["phase"]
    assert (phase == "search").sum() == 12 and pa["score"].notna().all()
    assert (phase == "refine").sum() > 0  # the refinement ran after the global search (tests/test_tune_refine.py)
    assert (pa.iloc[0][[c for c in pa.columns if c.startswith("p_")]] == 1.0).all()  # trial 0: the defaults
    assert pa["score"].nunique() > 6  # the sampler moved
    assert a["tuned_on"]["seed"] == training_seed(0) != 0
    # mc with tuned.toml = the study's filters with the tuned options
    toml = (tmp_path / "a" / "tuned.toml").read_text()
    assert "[filters.ekf]" in toml
    rc = main(["mc", "--config", str(tmp_path / "a" / "tuned.toml"), "--tracks", "5", "--runs", "2", "--dvl",
               "synthetic", "--window", "0:60", "--jobs", "1", "--no-progress", "--out", str(tmp_path / "mc")])
    assert rc == 0, capsys.readouterr().err
    import json

    man = json.loads((tmp_path / "mc" / "manifest.json").read_text())
    got = {k: v for _, k, v in man["options"]["filter_options"]}
    assert got.pop("tuned_on") == f"seed={training_seed(0)};tracks=5;runs=0-3"
    assert got == a["best"]["ekf"]["values"]  # exact round trip through the TOML text


def test_resume_after_a_kill_continues_to_the_same_values(tmp_path):
    """A run killed mid-trial (its trial left RUNNING in the study file) and rerun ends with the values of an
    uninterrupted run; a smaller first budget extended later does too."""
    whole = TuneSpec(Spec(**SMALL), trials=11, profile=False, refine_trials=0)
    run_tune(whole, tmp_path / "whole")
    part = tmp_path / "part"
    run_tune(dataclasses.replace(whole, trials=4), part)
    import optuna

    study = optuna.load_study(study_name="ekf", storage=storage(part))
    study.ask()  # a trial the killed process had started: RUNNING forever
    assert (part / JOURNAL_FILE).exists()
    run_tune(whole, part)
    pw, pp = params(tmp_path / "whole"), params(part)
    pp = pp[pp["score"].notna()].reset_index(drop=True)
    pw = pw.reset_index(drop=True)
    cols = [c for c in pw.columns if c.startswith("p_")] + ["score"]
    pd.testing.assert_frame_equal(pw[cols], pp[cols])
    states = pd.read_parquet(part / "trials.parquet")["state"]
    assert (states == "FAIL").sum() == 1 and (states == "COMPLETE").sum() == 11


@pytest.mark.parametrize("extra, words", [
    (["--trials", "0"], "--trials must be at least 1"),
    (["--tune-range", "ekf.bogus_scale=1:2"], "unknown parameter"),
    (["--tune-range", "ekf.acc_noise_scale=2:1"], "empty or inverted range"),
    (["--tune-range", "ekf.acc_noise_scale=1:1"], "empty or inverted range"),
    (["--tune-range", "ekf.acc_noise_scale=0:1"], "LOW > 0"),
    (["--tune-range", "ukf.alpha=0.1:1"], "ukf is not in --filters"),
    (["--test-tracks", "5"], "also tuning tracks"),
    (["--objective", "best"], "--objective: choose"),
    (["--pick", "worst"], "--pick: choose"),
])
def test_bad_tune_input_in_one_line(tmp_path, capsys, extra, words):
    rc = main(CLI + extra + ["--out", str(tmp_path / "t")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "t").exists()  # nothing written


def test_study_from_another_configuration_refused(tmp_path, capsys):
    out = str(tmp_path / "t")
    assert main(CLI + ["--trials", "2", "--out", out]) == 0
    capsys.readouterr()
    rc = main(CLI[:4] + ["3"] + CLI[5:] + ["--trials", "2", "--out", out])  # --runs 3 instead of 4
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "comes from another configuration" in err and len(err.splitlines()) == 1
    # overlap allowed when asked, and recorded
    rc = main(CLI + ["--trials", "2", "--test-tracks", "5", "--test-runs", "2", "--allow-overlap", "--out", out])
    assert rc == 0


def test_tune_table_in_config(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text('trials = 2\n[tune]\n"*.acc_noise_scale" = [0.5, 2]\n"ekf.p0_att_scale" = "off"\n')
    rc = main(CLI + ["--config", str(cfg), "--out", str(tmp_path / "t")])
    assert rc == 0, capsys.readouterr().err
    import json

    space = {p["key"]: p for p in json.loads((tmp_path / "t" / "tune.json").read_text())["space"]["ekf"]}
    assert (space["acc_noise_scale"]["low"], space["acc_noise_scale"]["high"]) == (0.5, 2.0)
    assert "p0_att_scale" not in space and "r_scale_dvl" in space
    with pytest.raises(NespmError, match="expected NAME.KEY=LOW:HIGH"):
        parse_range("acc_noise_scale=1:2")


def test_kill_9_during_tune_then_rerun(tmp_path):
    """``kill -9`` of a real ``nespm tune`` process after a few trials; the rerun ends with the trials of an
    uninterrupted run (one worker).

    The kill does not race the study: every poll stops the process (SIGSTOP), counts its finished
    trials in the study file and kills it (SIGKILL) once there are 3, so the count is the one at the
    kill; otherwise it continues it (SIGCONT). The killed process runs the NumPy loop
    (NESPM_KERNELS=numpy): a trial lasts ~1 s, many polls long, on any machine."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from optuna.trial import TrialState

    out = tmp_path / "killed"
    args = [sys.executable, "-m", "nespm_cli.cli"] + CLI + ["--trials", "8", "--out", str(out)]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONPATH": os.getcwd(), "NESPM_KERNELS": "numpy"})

    def finished_trials() -> int:  # read from the journal's lines: no lock taken, nothing written
        try:
            lines = (out / JOURNAL_FILE).read_bytes().splitlines()
        except OSError:
            return 0
        ops = [json.loads(x) for x in lines if x.endswith(b"}")]
        return sum(op.get("state") == TrialState.COMPLETE.value and "trial_id" in op for op in ops)

    done, give_up = 0, time.monotonic() + 600  # a hang-guard, not a speed verdict
    try:
        while proc.poll() is None and time.monotonic() < give_up:
            time.sleep(0.02)
            proc.send_signal(signal.SIGSTOP)
            done = finished_trials()
            if done >= 3:
                break
            proc.send_signal(signal.SIGCONT)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert 3 <= done < 8, done  # killed mid-study
    t = TuneSpec(Spec(**SMALL), trials=8, profile=False, refine_trials=0)
    run_tune(t, out)  # the compiled loop from here: the same scores to round-off (rtol below)
    run_tune(t, tmp_path / "whole")
    pk, pw = params(out), params(tmp_path / "whole")
    cols = [c for c in pw.columns if c.startswith("p_")] + ["score"]
    pk = pk[pk["score"].notna()].reset_index(drop=True)
    pd.testing.assert_frame_equal(pk[cols], pw[cols].reset_index(drop=True))


def test_adaptive_filters_search_their_window_or_forgetting(tmp_path, capsys):
    """iae-ekf's window (log), sh-ekf's forgetting and vb-ekf's rho (linear) are in their default
    space beside the noise factors; a range end a track cannot take (a 120 s window on a 59 s
    track) is refused in one line before any trial, and a narrowed range runs and writes the option."""
    from nespm_cli.tuning.space import default_space
    from nespm_cli.filters.registry import get_filter
    from nespm_cli.nav.state import LAYOUT_12

    got = {f: {p.key: p for p in default_space(f, get_filter(f), LAYOUT_12, ("dvl",), 1e-3)}
           for f in ("iae-ekf", "sh-ekf", "vb-ekf")}
    w, b, r = got["iae-ekf"]["window"], got["sh-ekf"]["forgetting"], got["vb-ekf"]["rho"]
    assert (w.low, w.high, w.log, w.default, w.kind) == (5.0, 120.0, True, 30.0, "plugin")
    assert (b.low, b.high, b.log, b.default) == (0.9, 0.999, False, 0.97)
    assert (r.low, r.high, r.log, r.default) == (0.9, 0.999, False, 0.97)
    assert all("r_scale_dvl" in g and "acc_noise_scale" in g for g in got.values())

    cli = ["tune", "--tracks", "5", "--runs", "2", "--filters", "iae-ekf,sh-ekf", "--dvl", "synthetic",
           "--window", "0:60", "--no-progress", "--no-profile", "--level-runs", "2", "--trials", "3", "--refine-trials", "0"]
    rc = main(cli + ["--out", str(tmp_path / "a")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert "iae-ekf.window = 5..120: at 120" in err and "--tune-range iae-ekf.window=LOW:HIGH" in err
    assert not (tmp_path / "a").exists()
    rc = main(cli + ["--tune-range", "iae-ekf.window=5:40", "--out", str(tmp_path / "b")])
    assert rc == 0, capsys.readouterr().err
    trials = pd.read_parquet(tmp_path / "b" / "trials.parquet")
    trials = trials[trials["phase"] == "search"]
    iae, sh = trials[trials["filter"] == "iae-ekf"], trials[trials["filter"] == "sh-ekf"]
    assert iae["p_window"].between(5, 40).all() and iae["p_window"].nunique() == 3
    assert sh["p_forgetting"].between(0.9, 0.999).all() and sh["p_forgetting"].nunique() == 3
    toml = (tmp_path / "b" / "tuned.toml").read_text()
    assert "window = " in toml and "forgetting = " in toml
